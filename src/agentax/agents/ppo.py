"""Proximal policy optimisation (Schulman et al., 2017): the clipped objective with GAE(λ).

Each iteration collects ``num_steps`` steps from each of ``num_envs`` envs with the current policy,
computes advantages with GAE (bootstrapping through time-limit truncations from the value of the
observation really reached), then takes ``update_epochs`` passes of minibatch SGD on::

    ratio  = π(a|s) / π_old(a|s)
    L_clip = −mean(min(ratio · A, clip(ratio, 1 − ε, 1 + ε) · A))
    loss   = L_clip + vf_coef · mean((V(s) − G^λ)²) − ent_coef · mean(entropy)

with the learning rate (and optionally ε) annealed linearly to 0 and gradients clipped by global
norm. Discrete actions use a categorical policy, continuous ones a diagonal Gaussian (actions
clipped to the space's bounds when stepping the env, the unclipped sample kept for the ratio).

A runner may mark steps that are no transitions of the game in ``info["valid"]`` (bool ``[T, E]``:
EnvPool's reset step, see :mod:`agentax.envs.envpool_xla`): every mean above, and the advantages'
normalisation, then runs over the valid steps only; the runner marks the step before such a step
done, so GAE does not cross it.

**Normalisation** (``normalize_observations``, ``normalize_rewards``; CleanRL's MuJoCo PPO wraps its
env in Gymnasium's ``NormalizeObservation`` and ``NormalizeReward``) is state of the agent, not of an
env wrapper (:mod:`agentax.normalize`): the observations' running mean and variance, and for rewards
the running discounted return of each env and its variance. So the compiled program carries them,
checkpoints save them, and ``act`` and the greedy policy (evaluation, export, video) standardise raw
observations with the state's statistics without any runner knowing. The order, in ``learn``: the
statistics first take in the rollout (its observations; its rewards' discounted returns, the per-env
return carried from the previous rollout), then the iteration trains on the rollout seen through the
updated statistics: observations standardised and clipped, rewards divided by the return's standard
deviation and clipped. Acting in rollout ``k`` thus uses the statistics after rollout ``k − 1``
(Brax's PPO keeps the same order; CleanRL's wrappers instead store each observation as normalised
when it was acted on): the behaviour log-probabilities were taken under the older statistics, so an
iteration's first ratios also carry the statistics' change, large in the first iteration and small
once they settle. They are no parameters: gradients never reach them.

**Memory** (``core``: ``"lstm"`` or ``"gru"``; the last section): a recurrent core between the torso
and the heads (:class:`~agentax.nets.RecurrentActorCritic`). The agent then acts through
``Agent.recurrent``: each env's carry travels with the rollout, reset to zeros where an episode
starts, and every step's ``info`` keeps the carry it received and its ``first`` flag. ``learn``
recomputes the values through the whole rollout with the learner's parameters, then takes its
minibatches as whole env sequences (``bptt`` steps, or the rollout), each run through the core from
its stored carry, resetting where ``first`` says: backpropagation through time, as PureJaxRL's
``ppo_rnn`` (whole rollouts) and R2D2's stored state (shorter sequences). Every runner carries
the memory.

Pure functions: ``init``, ``act`` and ``learn`` serve every runner through ``make_agent``; the
compiled runner builds its rollout program from them (:mod:`agentax.runners.rollout`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from agentax import normalize as running
from agentax.agents.protocol import (
    Agent,
    EnvSpec,
    Loop,
    OnPolicy,
    Recurrent,
    action_nvec,
    check_fields,
    discrete_actions,
    image_shape_for,
)
from agentax.agents.sequences import (
    initial_memory,
    num_sequences,
    recurrent_net_fields,
    sequence_length,
    time_major,
    validate_core,
    whole_sequences,
)
from agentax.envs.core import Box, RecurrentPolicy
from agentax.errors import UsageError
from agentax.nets import (
    ActorCritic,
    Memory,
    RecurrentActorCritic,
    entropy,
    gaussian_entropy,
    gaussian_log_prob,
    greedy_action,
    is_image,
    log_prob,
    masked,
    sample_action,
    with_encoder,
)
from agentax.policies import Policy
from agentax.replay import Transition
from agentax.returns import gae, masked_mean, normalize


@dataclass(frozen=True)
class PPOConfig:
    """Hyperparameters of PPO (defaults: CleanRL's classic-control settings)."""

    total_steps: int = 500_000
    """env steps of the whole training (across envs)"""
    num_envs: int = 4
    """envs stepped side by side"""
    num_steps: int = 128
    """steps per env per iteration (rollout length)"""
    learning_rate: float = 2.5e-4
    """Adam's learning rate at the start"""
    anneal_lr: bool = True
    """anneal the learning rate linearly to 0 over the training"""
    discount_factor: float = 0.99
    """γ, the discount factor"""
    gae_lambda: float = 0.95
    """λ of GAE (1: Monte-Carlo returns, 0: one-step TD)"""
    num_minibatches: int = 4
    """minibatches per epoch (the rollout of num_envs × num_steps is split into these)"""
    update_epochs: int = 4
    """passes over each rollout"""
    clip_eps: float = 0.2
    """ε of the clipped objective"""
    anneal_clip: bool = False
    """anneal ε linearly to 0 with the learning rate (RL-Zoo's CartPole setting)"""
    ent_coef: float = 0.01
    """weight of the entropy bonus"""
    vf_coef: float = 0.5
    """weight of the value loss"""
    max_grad_norm: float = 0.5
    """clip gradients to this global norm"""
    normalize_advantages: bool = True
    """normalise advantages per minibatch"""
    hidden: tuple[int, ...] = (64, 64)
    """widths of the actor's and the critic's hidden layers"""
    activation: str = "tanh"
    """activation of the hidden layers: elu, relu, tanh, gelu or swish"""
    conv_torso: bool = False
    """MinAtar's conv torso (conv 16 3×3, dense 128) shared by actor and critic instead of the MLPs
    (``hidden`` unused), on an env whose flat observations are an image (``EnvSpec.image_shape``)"""
    normalize_observations: bool = False
    """standardise observations by their running mean and variance, kept in the agent state
    (Gymnasium's NormalizeObservation; flat observations only)"""
    observation_clip: float = 10.0
    """clip standardised observations to [−this, this]"""
    normalize_rewards: bool = False
    """divide rewards by the running standard deviation of the discounted return (γ the discount
    factor; Gymnasium's NormalizeReward, SB3's VecNormalize), kept in the agent state"""
    reward_clip: float = 10.0
    """clip normalised rewards to [−this, this]"""
    core: str = "none"
    """a recurrent core after the torso: lstm, gru, or none (feed-forward); its memory of each env is
    reset where an episode starts and learned by backpropagation through time (compiled runner)"""
    core_size: int = 128
    """units of the recurrent core (and of the actor's and the critic's hidden layer after it)"""
    bptt: int = 0
    """steps of the sequences the core is learned on, each from the memory stored where it starts
    (0: the whole rollout of num_steps); num_steps must split into them"""

    def validate(self) -> PPOConfig:
        """Raise a UsageError naming the first bad value (run by ``make_agent`` and the CLI)."""
        check_fields(
            self,
            positive=(
                "total_steps",
                "num_envs",
                "num_steps",
                "learning_rate",
                "num_minibatches",
                "update_epochs",
                "observation_clip",
                "reward_clip",
            ),
            unit_interval=("discount_factor", "gae_lambda"),
            non_negative=("clip_eps", "ent_coef", "vf_coef", "max_grad_norm"),
        )
        if (self.num_envs * self.num_steps) % self.num_minibatches:
            raise UsageError(
                f"num_envs × num_steps = {self.num_envs * self.num_steps} does not split into "
                f"{self.num_minibatches} minibatches"
            )
        if self.core != "none":
            self.validate_core()
        return self

    def validate_core(self) -> None:
        """The recurrent core's settings (:func:`agentax.agents.sequences.validate_core`)."""
        validate_core(self)

    @property
    def sequence_length(self) -> int:
        """Steps of each sequence the core learns on (``bptt``, or the whole rollout)."""
        return sequence_length(self)

    @property
    def num_sequences(self) -> int:
        return num_sequences(self)

    @property
    def steps_per_update(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def num_updates(self) -> int:
        return max(1, self.total_steps // self.steps_per_update)


@struct.dataclass
class PPOAgent:
    """The learner's state: network parameters, optimizer state and the number of iterations done;
    with normalisation on, its statistics (None when off, so such a state is as it always was)."""

    params: Any
    opt_state: Any
    updates: jax.Array  # int32 []
    obs_stats: running.RunningMeanStd | None = None  # [*obs_shape]: read by act
    return_stats: running.RunningMeanStd | None = None  # []: the discounted return's
    discounted_return: jax.Array | None = None  # float32 [num_envs]: each env's, carried across rollouts


def is_continuous(spec: EnvSpec) -> bool:
    return isinstance(spec.action_space, Box)


def action_dim(spec: EnvSpec) -> int:
    """The number of logits (Discrete: one per action; MultiDiscrete and MultiBinary: one per choice
    of each entry) or the action vector's length (continuous, flat Box only)."""
    if not is_continuous(spec):
        return discrete_actions(spec, "ppo", multi=True)
    if len(spec.action_space.shape) != 1:
        raise UsageError(f"PPO needs flat Box actions, got shape {spec.action_space.shape}")
    return spec.action_space.shape[0]


def network(cfg: PPOConfig, spec: EnvSpec, conv: str = "xla", precision: str = "f32") -> ActorCritic:
    """PPO's actor-critic for ``spec`` (on stacked frames the Nature CNN, its convolutions on ``conv``),
    its products in ``precision``."""
    cnn = is_image(spec.obs_shape)
    image_shape = image_shape_for(cfg.conv_torso, spec)
    net = ActorCritic(
        action_dim(spec),
        is_continuous(spec),
        tuple(cfg.hidden),
        cfg.activation,
        cnn,
        image_shape,
        conv,
        precision,
    )
    return with_encoder(net, spec.layout, precision)


def optimizer(cfg: PPOConfig) -> optax.GradientTransformation:
    sgd_steps = cfg.num_updates * cfg.update_epochs * cfg.num_minibatches
    learning_rate = (
        optax.linear_schedule(cfg.learning_rate, 0.0, sgd_steps) if cfg.anneal_lr else cfg.learning_rate
    )
    return optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.adam(learning_rate, eps=1e-5))


def init(key: jax.Array, spec: EnvSpec, cfg: PPOConfig) -> PPOAgent:
    obs = jnp.zeros(spec.obs_shape, spec.obs_dtype)
    if cfg.core == "none":
        params = network(cfg, spec).init(key, obs)
    else:
        params = recurrent_network(cfg, spec).init(key, obs, initial_memory(cfg), jnp.bool_(True))
    agent = PPOAgent(params, optimizer(cfg).init(params), jnp.int32(0))
    if cfg.normalize_observations:
        agent = agent.replace(obs_stats=running.init(spec.obs_shape))
    if cfg.normalize_rewards:
        agent = agent.replace(
            return_stats=running.init(), discounted_return=jnp.zeros(cfg.num_envs, jnp.float32)
        )
    return agent


def observe(obs_stats: running.RunningMeanStd | None, obs: jax.Array, cfg: PPOConfig) -> jax.Array:
    """What the network sees of raw observations: standardised and clipped by ``obs_stats``, or
    ``obs`` itself when observations are not normalised (``obs_stats`` None)."""
    if obs_stats is None:
        return obs
    return running.normalize(obs_stats, obs, cfg.observation_clip)


def take_in(agent: PPOAgent, rollout: Transition, cfg: PPOConfig) -> tuple[PPOAgent, Transition]:
    """The normalisers' step of ``learn``: the statistics updated from ``rollout`` (raw, ``[T, E]``;
    its ``info["valid"]`` steps only, if marked), and the rollout as the network learns from it,
    through the updated statistics. Without normalisation both come back unchanged."""
    valid = rollout.info.get("valid")
    valid = None if valid is None else valid.reshape(-1)  # (T·E,)
    if agent.obs_stats is not None:
        obs_stats = running.update(agent.obs_stats, rollout.obs.reshape(-1, *rollout.obs.shape[2:]), valid)
        agent = agent.replace(obs_stats=obs_stats)
        rollout = rollout.replace(
            obs=observe(obs_stats, rollout.obs, cfg), next_obs=observe(obs_stats, rollout.next_obs, cfg)
        )
    if agent.return_stats is not None:
        done = rollout.terminated | rollout.truncated
        last_return, returns = running.discounted_returns(
            agent.discounted_return, rollout.reward, done, cfg.discount_factor
        )  # (E,), (T, E)
        return_stats = running.update(agent.return_stats, returns.reshape(-1), valid)
        agent = agent.replace(return_stats=return_stats, discounted_return=last_return)
        rollout = rollout.replace(reward=running.scale(return_stats, rollout.reward, cfg.reward_clip))
    return agent, rollout


def _log_prob_entropy(actor_out: Any, action: jax.Array, spec: EnvSpec) -> tuple[jax.Array, jax.Array]:
    """``(log π(action), entropy)`` ``[...]`` of the policy's output (logits already masked)."""
    if is_continuous(spec):
        mean, log_std = actor_out
        return gaussian_log_prob(mean, log_std, action), gaussian_entropy(log_std)
    nvec = action_nvec(spec.action_space)
    return log_prob(actor_out, action, nvec), entropy(actor_out, nvec)


def policy_output(net: Any, params: Any, obs: jax.Array, spec: EnvSpec) -> tuple[Any, jax.Array]:
    """The network's ``(actor_out, value)`` on ``obs``, with the illegal actions' logits masked
    where the observations carry a mask (:meth:`EnvSpec.legal`)."""
    actor_out, value = net.apply(params, obs)
    legal = spec.legal(obs)
    return masked(actor_out, legal), value


def act(
    params: Any,
    obs: jax.Array,
    key: jax.Array,
    spec: EnvSpec,
    cfg: PPOConfig,
    conv: str = "xla",
    precision: str = "f32",
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Sample actions for observations ``[E, *obs_shape]``: ``(action, log_prob [E], value [E])``."""
    actor_out, value = policy_output(network(cfg, spec, conv, precision), params, obs, spec)
    action = sample(actor_out, key, spec)
    return action, _log_prob_entropy(actor_out, action, spec)[0], value


def sample(actor_out: Any, key: jax.Array, spec: EnvSpec) -> jax.Array:
    """Actions drawn from the policy's output (logits already masked, or the Gaussian's)."""
    if is_continuous(spec):
        mean, log_std = actor_out
        return mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape)
    return sample_action(key, actor_out, action_nvec(spec.action_space))


def most_probable(actor_out: Any, spec: EnvSpec) -> jax.Array:
    """The greedy action of the policy's output: the most probable one, or the Gaussian's mean clipped."""
    if is_continuous(spec):
        return env_action(actor_out[0], spec)
    return greedy_action(actor_out, action_nvec(spec.action_space)).astype(jnp.int32)


def env_action(action: jax.Array, spec: EnvSpec) -> jax.Array:
    """What the env receives: continuous actions clipped to the space's bounds."""
    if is_continuous(spec):
        return jnp.clip(action, spec.action_space.low, spec.action_space.high)
    return action


def greedy_policy(
    params: Any,
    spec: EnvSpec,
    cfg: PPOConfig,
    obs_stats: running.RunningMeanStd | None = None,
    conv: str = "xla",
    precision: str = "f32",
) -> Policy:
    """The deterministic policy for evaluation: the most probable action (the Gaussian's mean), on
    raw observations standardised by ``obs_stats`` where given."""
    net = network(cfg, spec, conv, precision)

    def policy(obs: jax.Array, key: jax.Array) -> jax.Array:
        actor_out, _ = policy_output(net, params, observe(obs_stats, obs, cfg), spec)
        return most_probable(actor_out, spec)

    return policy


def clipped_surrogate_loss(
    log_prob_t: jax.Array,
    old_log_prob_t: jax.Array,
    advantage_t: jax.Array,
    clip_eps: float | jax.Array,
    valid_t: jax.Array | None = None,
) -> jax.Array:
    """PPO's clipped policy loss ``−mean(min(ρ·A, clip(ρ, 1−ε, 1+ε)·A))``, ``ρ = exp(log π − log π_old)``;
    the mean over the ``valid_t`` entries only, if given."""
    ratio = jnp.exp(log_prob_t - old_log_prob_t)
    clipped = jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps)
    return -masked_mean(jnp.minimum(ratio * advantage_t, clipped * advantage_t), valid_t)


def loss_fn(
    params: Any,
    batch: dict[str, jax.Array],
    clip_eps: jax.Array,
    spec: EnvSpec,
    cfg: PPOConfig,
    conv: str = "xla",
    precision: str = "f32",
):
    """The PPO loss of one minibatch (flat ``[B, ...]`` arrays); returns ``(loss, metrics)``."""
    actor_out, value = policy_output(network(cfg, spec, conv, precision), params, batch["obs"], spec)
    return ppo_loss(actor_out, value, batch, clip_eps, spec, cfg)


def ppo_loss(
    actor_out: Any,
    value: jax.Array,
    batch: dict[str, jax.Array],
    clip_eps: jax.Array,
    spec: EnvSpec,
    cfg: PPOConfig,
):
    """The PPO loss of the network's outputs on a minibatch, ``(loss, metrics)``: arrays of any leading
    shape (flat steps ``[B]``, or sequences ``[L, B]``). With ``batch["valid"]`` (bool, the same
    shape) every mean runs over the valid entries only."""
    valid = batch.get("valid")
    new_log_prob, entropies = _log_prob_entropy(actor_out, batch["action"], spec)
    advantage = normalize(batch["advantage"], valid) if cfg.normalize_advantages else batch["advantage"]
    policy_loss = clipped_surrogate_loss(new_log_prob, batch["log_prob"], advantage, clip_eps, valid)
    value_loss = 0.5 * masked_mean((value - batch["target"]) ** 2, valid)
    mean_entropy = masked_mean(entropies, valid)
    loss = policy_loss + cfg.vf_coef * value_loss - cfg.ent_coef * mean_entropy
    log_ratio = new_log_prob - batch["log_prob"]
    approx_kl = masked_mean((jnp.exp(log_ratio) - 1) - log_ratio, valid)
    return loss, {
        "policy_loss": policy_loss,
        "value_loss": value_loss,
        "entropy": mean_entropy,
        "approx_kl": approx_kl,
    }


def learn(
    agent: PPOAgent,
    rollout: Transition,
    key: jax.Array,
    spec: EnvSpec,
    cfg: PPOConfig,
    loop: Loop = jax.lax.scan,
    conv: str = "xla",
    precision: str = "f32",
) -> tuple[PPOAgent, dict[str, jax.Array]]:
    """One PPO iteration on a rollout ``[T, E, ...]`` (``info["log_prob"]`` from :func:`act`, the
    behaviour policy's; ``info["valid"]``, if there, the steps to learn from): the normalisers take
    the rollout in (:func:`take_in`), then GAE, then epochs of minibatch SGD, each run by ``loop``
    (``lax.scan``'s signature; the runner chooses it); ``conv``: the Nature CNN's convolution backend;
    ``precision``: the products' (the statistics, targets and losses stay float32)."""
    net, tx = network(cfg, spec, conv, precision), optimizer(cfg)
    agent, rollout = take_in(agent, rollout, cfg)
    # Both values from the learner's parameters: a rollout collected with older ones (a parallel
    # runner's policy lag) would otherwise feed each change of V into the targets again.
    _, values = net.apply(agent.params, rollout.obs)  # (T, E)
    _, next_values = net.apply(agent.params, rollout.next_obs)  # (T, E): V of the observation reached
    steps = learning_batch(rollout, values, next_values, cfg)
    flat = jax.tree.map(lambda x: x.reshape(values.size, *x.shape[2:]), steps)
    loss = functools.partial(loss_fn, spec=spec, cfg=cfg, conv=conv, precision=precision)
    (params, opt_state), metrics = sgd_epochs(loss, flat, agent, key, cfg, tx, loop)
    agent = agent.replace(params=params, opt_state=opt_state, updates=agent.updates + 1)
    return agent, jax.tree.map(jnp.mean, metrics)


def learning_batch(
    rollout: Transition, values: jax.Array, next_values: jax.Array, cfg: PPOConfig
) -> dict[str, jax.Array]:
    """What the loss reads of each step ``[T, E]``: the rollout's observations, actions and
    log-probabilities, GAE's advantages and value targets from ``values`` and ``next_values``
    ``[T, E]``, and ``valid`` where the rollout marks it."""
    advantages, targets = gae(
        rollout.reward,
        values,
        next_values,
        rollout.terminated,
        rollout.terminated | rollout.truncated,
        cfg.discount_factor,
        cfg.gae_lambda,
    )
    steps = {
        "obs": rollout.obs,
        "action": rollout.action,
        "log_prob": rollout.info["log_prob"],
        "advantage": advantages,
        "target": targets,
    }
    if "valid" in rollout.info:
        steps["valid"] = rollout.info["valid"]
    return steps


def sgd_epochs(
    loss: Any, data: dict[str, Any], agent: PPOAgent, key: jax.Array, cfg: PPOConfig, tx: Any, loop: Loop
) -> tuple[tuple[Any, Any], dict[str, jax.Array]]:
    """``update_epochs`` passes of minibatch SGD from the agent's parameters: ``data``'s leaves
    ``[N, ...]`` (N steps, or N sequences) shuffled each epoch and split into ``num_minibatches``;
    ``loss(params, minibatch, clip_eps) -> (loss, metrics)``. Returns ``((params, opt_state), metrics)``."""
    size = jax.tree.leaves(data)[0].shape[0]
    progress = agent.updates.astype(jnp.float32) / cfg.num_updates
    clip_eps = cfg.clip_eps * (1.0 - progress) if cfg.anneal_clip else jnp.float32(cfg.clip_eps)
    grad_fn = jax.grad(loss, has_aux=True)

    def sgd_step(carry, minibatch):
        params, opt_state = carry
        grads, metrics = grad_fn(params, minibatch, clip_eps)
        updates, opt_state = tx.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), metrics

    def epoch(carry, epoch_key):
        if cfg.num_minibatches == 1:
            minibatches = jax.tree.map(lambda x: x[None], data)
        else:
            order = jax.random.permutation(epoch_key, size)
            minibatches = jax.tree.map(
                lambda x: x[order].reshape(cfg.num_minibatches, -1, *x.shape[1:]), data
            )
        return loop(sgd_step, carry, minibatches)

    return loop(epoch, (agent.params, agent.opt_state), jax.random.split(key, cfg.update_epochs))


# ---------------------------------------------------------------- with a recurrent core (cfg.core)


def recurrent_network(cfg: PPOConfig, spec: EnvSpec, conv: str = "xla") -> Any:
    """PPO's actor-critic with the core ``cfg.core`` after its torso (:class:`RecurrentActorCritic`),
    one step ``(obs, memory, first) -> (memory, (actor_out, value))``."""
    net = RecurrentActorCritic(action_dim(spec), is_continuous(spec), **recurrent_net_fields(cfg, spec, conv))
    return with_encoder(net, spec.layout)


def recurrent_output(
    net: Any,
    params: Any,
    obs: jax.Array,
    memory: Memory,
    first: jax.Array,
    spec: EnvSpec,
    over_time: bool = False,
):
    """One step of the recurrent network, ``(memory, (actor_out, value))``, its illegal actions'
    logits masked as :func:`policy_output`'s; ``over_time``: a sequence ``[T, B, ...]`` from ``memory``
    ``[B, ...]``, the memory after each step returned (:class:`~agentax.nets.RecurrentActorCritic`)."""
    memory, (actor_out, value) = net.apply(params, obs, memory, first, over_time)
    return memory, (masked(actor_out, spec.legal(obs)), value)


def act_with_memory(
    state: PPOAgent,
    memory: Memory,
    obs: jax.Array,
    first: jax.Array,
    key: jax.Array,
    spec: EnvSpec,
    cfg: PPOConfig,
    conv: str = "xla",
) -> tuple[Memory, jax.Array, dict[str, Any]]:
    """Sample actions for observations ``[E, *obs_shape]`` with the core's ``memory`` ``[E, ...]``,
    reset where ``first`` (bool ``[E]``): ``(memory after the step, action [E], info)``, ``info``
    holding the log-probabilities and, for :func:`learn_sequences`, the memory received and ``first``."""
    net = recurrent_network(cfg, spec, conv)
    seen = observe(state.obs_stats, obs, cfg)
    new_memory, (actor_out, _) = recurrent_output(net, state.params, seen, memory, first, spec)
    action = sample(actor_out, key, spec)
    info = {"log_prob": _log_prob_entropy(actor_out, action, spec)[0], "memory": memory, "first": first}
    return new_memory, action, info


def recurrent_greedy_policy(
    params: Any,
    spec: EnvSpec,
    cfg: PPOConfig,
    obs_stats: running.RunningMeanStd | None = None,
    conv: str = "xla",
) -> RecurrentPolicy:
    """The deterministic policy with memory for evaluation: the most probable action given the
    episode so far, the core's memory carried by whoever plays it."""
    net = recurrent_network(cfg, spec, conv)

    def step(memory: Memory, obs: jax.Array, key: jax.Array) -> tuple[Memory, jax.Array]:
        seen = observe(obs_stats, obs, cfg)
        memory, (actor_out, _) = recurrent_output(net, params, seen, memory, jnp.bool_(False), spec)
        return memory, most_probable(actor_out, spec)

    return RecurrentPolicy(lambda: initial_memory(cfg), step)


def sequence_loss(
    params: Any, batch: dict[str, Any], clip_eps: jax.Array, net: Any, spec: EnvSpec, cfg: PPOConfig
):
    """The PPO loss of a minibatch of sequences (``[B, L, ...]``, ``batch["memory"]`` ``[B, ...]``
    the memory each starts from): the core run through each sequence with ``params``, reset where
    ``batch["first"]`` marks an episode's start, then :func:`ppo_loss` on every step."""
    steps = time_major(batch)  # (L, B, ...)
    _, (actor_out, value) = recurrent_output(
        net, params, steps["obs"], batch["memory"], steps["first"], spec, over_time=True
    )
    return ppo_loss(actor_out, value, steps, clip_eps, spec, cfg)


def learn_sequences(
    agent: PPOAgent,
    rollout: Transition,
    key: jax.Array,
    spec: EnvSpec,
    cfg: PPOConfig,
    loop: Loop = jax.lax.scan,
    conv: str = "xla",
) -> tuple[PPOAgent, dict[str, jax.Array]]:
    """One PPO iteration of a recurrent agent on a rollout ``[T, E, ...]`` from :func:`act_with_memory`
    (``info["memory"]``, ``info["first"]``): the values for GAE from the core run through the
    whole rollout with the learner's parameters (the value of each observation reached from the
    memory after its step), then SGD on minibatches of whole sequences of ``cfg.sequence_length``
    steps, each from the memory stored where it starts (backpropagation through time)."""
    net, tx = recurrent_network(cfg, spec, conv), optimizer(cfg)
    agent, rollout = take_in(agent, rollout, cfg)
    first, stored = rollout.info["first"], rollout.info["memory"]  # (T, E), (T, E, ...)
    start = jax.tree.map(lambda m: m[0], stored)
    memories, (_, values) = net.apply(agent.params, rollout.obs, start, first, True)  # (T, E, ...), (T, E)
    _, (_, next_values) = net.apply(agent.params, rollout.next_obs, memories, jnp.zeros_like(first))
    length = cfg.sequence_length
    steps = {**learning_batch(rollout, values, next_values, cfg), "first": first}
    data = whole_sequences(steps, stored, length)  # (N, L, ...), memory (N, ...)
    loss = functools.partial(sequence_loss, net=net, spec=spec, cfg=cfg)
    (params, opt_state), metrics = sgd_epochs(loss, data, agent, key, cfg, tx, loop)
    agent = agent.replace(params=params, opt_state=opt_state, updates=agent.updates + 1)
    return agent, jax.tree.map(jnp.mean, metrics)


def make_agent(
    spec: EnvSpec, cfg: PPOConfig, *, loop: Loop = jax.lax.scan, conv: str = "xla", precision: str = "f32"
) -> Agent:
    """PPO's pure functions for every runner (see ``agentax.agents.protocol``);
    ``loop`` runs the learning steps (the runner's :func:`agentax.kernels.learning_loop`), ``conv``
    is the Nature CNN's convolution backend and ``precision`` the networks' products' (the entry
    point's choices; acting and learning alike)."""
    cfg.validate()
    action_dim(spec)  # a clear error for actions PPO cannot take
    if cfg.normalize_observations and (is_image(spec.obs_shape) or spec.layout is not None):
        what = f"frames {spec.obs_shape}" if spec.layout is None else f"packed observations ({spec.layout})"
        raise UsageError(f"normalize_observations standardises flat observations, not {what}")

    if cfg.core != "none":
        if precision != "f32":
            raise UsageError(f"a recurrent core learns in f32 only, not --precision {precision}")
        return recurrent_agent(spec, cfg, loop, conv)

    def act_with_info(state: PPOAgent, obs: jax.Array, key: jax.Array, progress: jax.Array):
        obs = observe(state.obs_stats, obs, cfg)
        action, action_log_prob, _ = act(state.params, obs, key, spec, cfg, conv, precision)
        return action, {"log_prob": action_log_prob}

    return Agent(
        name="ppo",
        init=lambda key: init(key, spec, cfg),
        act=act_with_info,
        greedy_policy=lambda state: greedy_policy(state.params, spec, cfg, state.obs_stats, conv, precision),
        learn=lambda state, rollout, key: learn(state, rollout, key, spec, cfg, loop, conv, precision),
        experience=OnPolicy(cfg.num_envs, cfg.num_steps),
        total_steps=cfg.total_steps,
        env_action=lambda action: env_action(action, spec),
    )


def recurrent_agent(spec: EnvSpec, cfg: PPOConfig, loop: Loop = jax.lax.scan, conv: str = "xla") -> Agent:
    """PPO with the core ``cfg.core``: acting with memory (:class:`~agentax.agents.protocol.Recurrent`),
    learning on whole sequences (:func:`learn_sequences`); ``act`` alone acts from fresh memory."""

    def act_with_memory_of(state, memory, obs, first, key, progress):
        return act_with_memory(state, memory, obs, first, key, spec, cfg, conv)

    def act_fresh(state: PPOAgent, obs: jax.Array, key: jax.Array, progress: jax.Array):
        batch = obs.shape[: obs.ndim - len(spec.obs_shape)]
        _, action, info = act_with_memory_of(
            state, initial_memory(cfg, batch), obs, jnp.ones(batch, bool), key, progress
        )
        return action, info

    return Agent(
        name="ppo",
        init=lambda key: init(key, spec, cfg),
        act=act_fresh,
        greedy_policy=lambda state: recurrent_greedy_policy(state.params, spec, cfg, state.obs_stats, conv),
        learn=lambda state, rollout, key: learn_sequences(state, rollout, key, spec, cfg, loop, conv),
        experience=OnPolicy(cfg.num_envs, cfg.num_steps),
        total_steps=cfg.total_steps,
        env_action=lambda action: env_action(action, spec),
        recurrent=Recurrent(lambda num_envs: initial_memory(cfg, (num_envs,)), act_with_memory_of),
    )
