"""REINFORCE (Williams, 1992) as the lecture teaches it, and with a learned baseline.

Each iteration the neural policy plays ``episodes_per_update`` episodes (at most ``max_steps``
steps each), sampling its actions. Every action's advantage is its discounted return, normalised
with the mean and std over all the episodes together; the loss is::

    loss = −mean_t(log π(a_t | s_t) · advantage_t)

minimised with Adam. With ``baseline=True`` a value network ``V(s)`` learns the returns by
regression and the advantage becomes ``G_t − V(s_t)`` (then normalised): the same expected
gradient, less variance.

The lecture's network is ``PolicyNet(2, hidden=(5,), activation="elu", sigmoid_head=True)``:
one sigmoid output giving P(left). Its per-step loss, the cross-entropy between the sampled action
and P weighted by the advantage, is exactly ``−log π(a|s) · advantage``. On a Box action space the
policy is PPO's diagonal Gaussian head (:class:`~agentax.nets.GaussianPolicyNet`: a mean network and
a state-independent ``log_std``; ``sigmoid_head`` does not apply); the env gets the sampled action
clipped to its bounds, the greedy policy the mean. With other than two discrete actions the head is a
softmax over one logit per action, whatever ``sigmoid_head`` says (Acrobot's three); MultiDiscrete
and MultiBinary actions are independent categoricals, one per entry, their log-probabilities summed.
Packed observations (:mod:`agentax.envs.spaces`) go through an encoder per leaf before the MLPs;
where they carry a legal-action mask, illegal actions get no probability.

On the compiled runner the episodes of an iteration run side by side for ``max_steps`` steps;
steps after an episode's end are masked out.

**Memory** (``core``: ``"lstm"`` or ``"gru"``): the policy becomes :class:`~agentax.nets.RecurrentActorCritic`
(torso, core, a head of one hidden layer), acting through ``Agent.recurrent``, its memory zeros at
each episode's start; ``learn`` runs the core through each whole episode from there
(backpropagation through time over the episode). With ``baseline`` its critic head, which reads the
core's output, is the baseline ``V(h_t)``. Only the compiled runner carries the memory.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from agentax.agents.protocol import (
    Agent,
    EnvSpec,
    Episodes,
    Loop,
    Recurrent,
    action_nvec,
    check_fields,
    discrete_actions,
    flat_observations,
    num_logits,
)
from agentax.agents.sequences import initial_memory, validate_core_kind
from agentax.envs.core import Box, RecurrentPolicy
from agentax.envs.spaces import Layout
from agentax.errors import UsageError
from agentax.nets import (
    MLP,
    GaussianPolicyNet,
    Memory,
    PolicyNet,
    RecurrentActorCritic,
    gaussian_log_prob,
    greedy_action,
    legal_actions,
    log_prob,
    masked,
    sample_action,
    with_encoder,
)
from agentax.policies import Policy
from agentax.replay import Transition
from agentax.returns import discounted_returns, normalize


@dataclass(frozen=True)
class ReinforceConfig:
    """Hyperparameters of REINFORCE (defaults: the lecture's)."""

    total_steps: int = 300_000
    """env-step budget; iterations = total_steps // (episodes_per_update × max_steps)"""
    episodes_per_update: int = 10
    """episodes played per policy update"""
    max_steps: int = 200
    """steps per episode at most"""
    discount_factor: float = 0.95
    """γ, the discount factor"""
    learning_rate: float = 0.01
    """Adam's learning rate"""
    hidden: tuple[int, ...] = (5,)
    """widths of the policy's hidden layers"""
    activation: str = "elu"
    """activation of the hidden layers: elu, relu, tanh, gelu or swish"""
    sigmoid_head: bool = True
    """the lecture's single sigmoid output where the env has two actions; else (and on any other
    number of discrete actions) a softmax over one logit per action"""
    baseline: bool = False
    """learn a value network V(s) and use G_t − V(s_t) as the advantage"""
    baseline_hidden: tuple[int, ...] = (32,)
    """widths of the baseline's hidden layers"""
    core: str = "none"
    """a recurrent core after the policy's torso: lstm, gru, or none (feed-forward); its memory is
    zeros at each episode's start and learned by backpropagation through the whole episode (compiled
    runner)"""
    core_size: int = 128
    """units of the recurrent core (and of the hidden layer of its head)"""

    def validate(self) -> ReinforceConfig:
        """Raise a UsageError naming the first bad value."""
        positive = ("total_steps", "episodes_per_update", "max_steps", "learning_rate")
        check_fields(self, positive, unit_interval=("discount_factor",))
        if self.core != "none":
            validate_core_kind(self)
        return self

    @property
    def steps_per_update(self) -> int:
        return self.episodes_per_update * self.max_steps

    @property
    def num_updates(self) -> int:
        return max(1, self.total_steps // self.steps_per_update)


@struct.dataclass
class ReinforceAgent:
    params: Any  # {"policy": ..., "value": ...} (value only with a baseline)
    opt_state: Any


Actions = Any
"""What the policy chooses among: the number of discrete actions, a MultiDiscrete or MultiBinary
space (one choice per entry), or the Box of continuous ones."""


def policy_network(
    cfg: ReinforceConfig, actions: Actions, layout: Layout | None = None, precision: str = "f32"
) -> Any:
    """The policy ``obs -> logits [..., n]`` (or a Gaussian's ``(mean, log_std)``), behind an
    encoder where observations are packed by ``layout``; its products in ``precision``."""
    if isinstance(actions, Box):
        net = GaussianPolicyNet(actions.shape[0], tuple(cfg.hidden), cfg.activation, precision)
    else:
        n = actions if isinstance(actions, int) else num_logits(actions)
        sigmoid = cfg.sigmoid_head and n == 2 and action_nvec(actions) is None
        net = PolicyNet(n, tuple(cfg.hidden), cfg.activation, sigmoid, precision)
    return with_encoder(net, layout, precision)


def policy_output(net: Any, params: Any, obs: jax.Array) -> Any:
    """The policy network's output on ``obs``, the illegal actions' logits masked where the
    observations carry a mask."""
    out, legal = net.apply(params, obs), legal_actions(net, obs)
    return masked(out, legal)


def action_log_prob(out: Any, action: jax.Array, actions: Actions) -> jax.Array:
    """``log π(a|s)`` ``[...]`` from the policy network's output."""
    if isinstance(actions, Box):
        return gaussian_log_prob(*out, action)
    return log_prob(out, action, action_nvec(actions))


def sample(out: Any, key: jax.Array, actions: Actions) -> jax.Array:
    if isinstance(actions, Box):
        mean, log_std = out
        return mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape)
    return sample_action(key, out, action_nvec(actions))


def env_action(action: jax.Array, actions: Actions) -> jax.Array:
    """What the env receives: continuous actions clipped to the Box's bounds."""
    return jnp.clip(action, actions.low, actions.high) if isinstance(actions, Box) else action


def value_network(cfg: ReinforceConfig, layout: Layout | None = None, precision: str = "f32") -> Any:
    mlp = MLP(tuple(cfg.baseline_hidden), cfg.activation, out=1, precision=precision)
    return with_encoder(mlp, layout, precision)


def init(
    key: jax.Array,
    obs_shape: tuple[int, ...],
    actions: Actions,
    cfg: ReinforceConfig,
    layout: Layout | None = None,
    precision: str = "f32",
) -> ReinforceAgent:
    policy_key, value_key = jax.random.split(key)
    obs = jnp.zeros(obs_shape, jnp.float32)
    params = {"policy": policy_network(cfg, actions, layout, precision).init(policy_key, obs)}
    if cfg.baseline:
        params["value"] = value_network(cfg, layout, precision).init(value_key, obs)
    return ReinforceAgent(params, optax.adam(cfg.learning_rate).init(params))


def loss_fn(
    params: Any,
    batch: dict[str, jax.Array],
    actions: Actions,
    cfg: ReinforceConfig,
    layout: Layout | None = None,
    precision: str = "f32",
):
    """REINFORCE's loss over the valid steps of ``[T, N]`` arrays; returns ``(loss, metrics)``."""
    out = policy_output(policy_network(cfg, actions, layout, precision), params["policy"], batch["obs"])
    values = None
    if cfg.baseline:
        values = value_network(cfg, layout, precision).apply(params["value"], batch["obs"])[..., 0]
    return reinforce_loss(action_log_prob(out, batch["action"], actions), values, batch)


def reinforce_loss(log_probs: jax.Array, values: jax.Array | None, batch: dict[str, jax.Array]):
    """``−mean(log π(a_t|s_t) · advantage_t)`` over ``batch["valid"]`` steps ``[T, N]``, the advantage
    the normalised return less the baseline's ``values`` (None: no baseline), plus the baseline's
    squared error; ``(loss, metrics)``."""
    valid = batch["valid"].astype(jnp.float32)
    count = jnp.maximum(valid.sum(), 1.0)
    returns = batch["returns"]
    metrics = {}
    if values is not None:
        advantage = normalize(returns - jax.lax.stop_gradient(values), valid)
        value_loss = (((values - returns) ** 2) * valid).sum() / count
        metrics["value_loss"] = value_loss
    else:
        advantage = normalize(returns, valid)
        value_loss = 0.0
    policy_loss = -(log_probs * advantage * valid).sum() / count
    metrics["policy_loss"] = policy_loss
    return policy_loss + value_loss, metrics


def learn(
    agent: ReinforceAgent,
    batch: dict[str, jax.Array],
    actions: Actions,
    cfg: ReinforceConfig,
    layout: Layout | None = None,
    precision: str = "f32",
):
    grads, metrics = jax.grad(loss_fn, has_aux=True)(agent.params, batch, actions, cfg, layout, precision)
    return apply_gradients(agent, grads, cfg), metrics


def apply_gradients(agent: ReinforceAgent, grads: Any, cfg: ReinforceConfig) -> ReinforceAgent:
    """One Adam step of ``grads``."""
    updates, opt_state = optax.adam(cfg.learning_rate).update(grads, agent.opt_state, agent.params)
    return ReinforceAgent(optax.apply_updates(agent.params, updates), opt_state)


def greedy_policy(
    params: Any, actions: Actions, cfg: ReinforceConfig, layout: Layout | None = None, precision: str = "f32"
) -> Policy:
    """The most probable (legal) action, one per entry of a MultiDiscrete or MultiBinary space, or
    the Gaussian's mean clipped to the bounds."""
    net = policy_network(cfg, actions, layout, precision)

    def policy(obs: jax.Array, key: jax.Array) -> jax.Array:
        out = policy_output(net, params["policy"], obs)
        if isinstance(actions, Box):
            return env_action(out[0], actions)
        return greedy_action(out, action_nvec(actions)).astype(jnp.int32)

    return policy


def actions_of(spec: EnvSpec) -> Actions:
    """The number of discrete actions, the MultiDiscrete or MultiBinary space, or the flat Box; a
    ``UsageError`` for what this REINFORCE cannot take."""
    space = spec.action_space
    if isinstance(space, Box):
        if len(space.shape) != 1:
            raise UsageError(f"REINFORCE needs flat Box actions, got shape {space.shape}")
        return space
    n = discrete_actions(spec, "reinforce", multi=True)
    return space if action_nvec(space) is not None else n


def returns_to_go(reward: jax.Array, ended: jax.Array, discount_factor: float) -> jax.Array:
    """Discounted returns ``[T, N]`` of episodes that end where ``ended`` (no bootstrapping)."""
    discounts = discount_factor * (1.0 - ended.astype(jnp.float32))
    return discounted_returns(reward, discounts, jnp.zeros(reward.shape[1:]))


def make_agent(
    spec: EnvSpec,
    cfg: ReinforceConfig,
    *,
    loop: Loop = jax.lax.scan,
    conv: str = "xla",
    precision: str = "f32",
) -> Agent:
    """REINFORCE's pure functions for every runner (see ``agentax.agents.protocol``).

    It learns from whole episodes: ``Episodes(episodes_per_update, max_steps)``, the steps after an
    episode's end masked out by ``info["valid"]``. ``learn`` is one gradient step (``loop`` unused;
    ``conv`` too: no convolutions); ``precision``: the networks' products'.
    """
    cfg.validate()
    actions = actions_of(spec)
    flat_observations(spec, "reinforce")
    if cfg.core != "none":
        if precision != "f32":
            raise UsageError(f"a recurrent core learns in f32 only, not --precision {precision}")
        return recurrent_agent(spec, cfg, actions)
    net = policy_network(cfg, actions, spec.layout, precision)

    def act(state: ReinforceAgent, obs: jax.Array, key: jax.Array, progress: jax.Array):
        return sample(policy_output(net, state.params["policy"], obs), key, actions), {}

    def learn_episodes(state: ReinforceAgent, trajectory: Transition, key: jax.Array):
        return learn(state, episode_batch(trajectory, cfg), actions, cfg, spec.layout, precision)

    return Agent(
        name="reinforce",
        init=lambda key: init(key, spec.obs_shape, actions, cfg, spec.layout, precision),
        act=act,
        greedy_policy=lambda state: greedy_policy(state.params, actions, cfg, spec.layout, precision),
        learn=learn_episodes,
        experience=Episodes(cfg.episodes_per_update, cfg.max_steps),
        total_steps=cfg.total_steps,
        env_action=lambda action: env_action(action, actions),
    )


def episode_batch(trajectory: Transition, cfg: ReinforceConfig) -> dict[str, jax.Array]:
    """What the loss reads of episodes ``[T, N]``: observations, actions, the valid steps and the
    discounted returns to go (each episode ended at its last valid step, or at ``max_steps``)."""
    valid = trajectory.info["valid"]
    ended = (trajectory.terminated | trajectory.truncated).at[-1].set(True)
    return {
        "obs": trajectory.obs.astype(jnp.float32),
        "action": trajectory.action,
        "valid": valid,
        "returns": returns_to_go(trajectory.reward * valid, ended, cfg.discount_factor),
    }


# ---------------------------------------------------------------- with a recurrent core (cfg.core)


def recurrent_policy_network(cfg: ReinforceConfig, actions: Actions, layout: Layout | None = None) -> Any:
    """The policy with the core ``cfg.core`` (:class:`RecurrentActorCritic`: its actor the policy, its
    critic the baseline), one step ``(obs, memory, first) -> (memory, (out, value))``."""
    if isinstance(actions, Box):
        net = RecurrentActorCritic(
            actions.shape[0], True, tuple(cfg.hidden), cfg.activation, cfg.core, cfg.core_size
        )
    else:
        n = actions if isinstance(actions, int) else num_logits(actions)
        net = RecurrentActorCritic(n, False, tuple(cfg.hidden), cfg.activation, cfg.core, cfg.core_size)
    return with_encoder(net, layout)


def recurrent_agent(spec: EnvSpec, cfg: ReinforceConfig, actions: Actions) -> Agent:
    """REINFORCE with the core ``cfg.core``: sampling with memory (:class:`Recurrent`), learning by
    backpropagation through each whole episode from the memory at its start."""
    net = recurrent_policy_network(cfg, actions, spec.layout)

    def output(params, obs, memory, first, over_time=False):  # (memory, (masked out, value))
        memory, (out, value) = net.apply(params, obs, memory, first, over_time)
        return memory, (masked(out, legal_actions(net, obs)), value)

    def init_agent(key: jax.Array) -> ReinforceAgent:
        obs = jnp.zeros(spec.obs_shape, jnp.float32)
        params = {"policy": net.init(key, obs, initial_memory(cfg), jnp.bool_(True))}
        return ReinforceAgent(params, optax.adam(cfg.learning_rate).init(params))

    def act_with_memory(state: ReinforceAgent, memory, obs, first, key, progress):
        new_memory, (out, _) = output(state.params["policy"], obs, memory, first)
        return new_memory, sample(out, key, actions), {"memory": memory, "first": first}

    def act_fresh(state: ReinforceAgent, obs: jax.Array, key: jax.Array, progress: jax.Array):
        batch = obs.shape[: obs.ndim - len(spec.obs_shape)]
        _, action, info = act_with_memory(
            state, initial_memory(cfg, batch), obs, jnp.ones(batch, bool), key, progress
        )
        return action, info

    def loss(params, batch, first, start):  # the core run through the episodes [T, N] from start
        _, (out, values) = output(params["policy"], batch["obs"], start, first, over_time=True)
        log_probs = action_log_prob(out, batch["action"], actions)
        return reinforce_loss(log_probs, values if cfg.baseline else None, batch)

    def learn_episodes(state: ReinforceAgent, trajectory: Transition, key: jax.Array):
        start = jax.tree.map(lambda m: m[0], trajectory.info["memory"])
        batch, first = episode_batch(trajectory, cfg), trajectory.info["first"]
        grads, metrics = jax.grad(loss, has_aux=True)(state.params, batch, first, start)
        return apply_gradients(state, grads, cfg), metrics

    def greedy(state: ReinforceAgent) -> RecurrentPolicy:
        def step(memory: Memory, obs: jax.Array, key: jax.Array) -> tuple[Memory, jax.Array]:
            memory, (out, _) = output(state.params["policy"], obs, memory, jnp.bool_(False))
            if isinstance(actions, Box):
                return memory, env_action(out[0], actions)
            return memory, greedy_action(out, action_nvec(actions)).astype(jnp.int32)

        return RecurrentPolicy(lambda: initial_memory(cfg), step)

    return Agent(
        name="reinforce",
        init=init_agent,
        act=act_fresh,
        greedy_policy=greedy,
        learn=learn_episodes,
        experience=Episodes(cfg.episodes_per_update, cfg.max_steps),
        total_steps=cfg.total_steps,
        env_action=lambda action: env_action(action, actions),
        recurrent=Recurrent(lambda num_envs: initial_memory(cfg, (num_envs,)), act_with_memory),
    )
