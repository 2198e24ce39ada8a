"""PQN: deep Q-learning from vectorized rollouts, without replay or target network.

Gallici et al., "Simplifying Deep Temporal Difference Learning" (ICLR 2025). PQN collects a
rollout of ``num_steps`` steps from ``num_envs`` envs with ε-greedy actions of the current
Q-network (ε annealed linearly), computes Peng's Q(λ) targets over it
(:func:`agentax.returns.q_lambda_returns`), and fits ``Q(s_t, a_t)`` to them in ``update_epochs``
epochs of ``num_minibatches`` minibatches, like PPO's SGD. What makes this stable without a target
network is LayerNorm in the Q-network; what makes it sample-efficient enough without replay is
the number of envs stepped side by side.

    G_t = r_t + γ (1 − terminated_t) [max_a Q(s'_t, a) + λ (1 − done_t) (G_{t+1} − max_a Q(s'_t, a))]
    loss = ½ E[(Q(s_t, a_t) − stop_gradient(G_t))²]

The targets use the parameters of the learner at the start of the update (as purejaxql's and
CleanRL's ``pqn.py``); a truncated step bootstraps from its final observation. Where observations
carry a legal-action mask (:meth:`~agentax.agents.protocol.EnvSpec.legal`), ε-greedy acts among the
legal actions and ``max_a`` runs over those of ``s'_t``. PQN is on-policy in agentax's terms
(``OnPolicy`` experience), so every runner that trains PPO trains it unchanged.

On stacked frames (Atari) the Q-network is the Nature CNN with LayerNorm before every ReLU
(purejaxql's ``pqn_atari``). A runner may mark steps that are no transitions of the game in
``info["valid"]`` (EnvPool's reset step, :mod:`agentax.envs.envpool_xla`): the loss leaves them out,
and the step before such a step is done, so no target is carried across it. Such a rollout's
``next_obs[t]`` is ``obs[t + 1]`` (EnvPool returns an ending step's last observation, then resets in
a step of its own), and the compiled Atari runner learns with the parameters that acted: there the
targets reuse ``act``'s ``max_a Q(s_{t+1}, a)`` (``info["max_q"]``) and only the last step's next
observations go through the network again — one forward pass of the rollout fewer, of the ~8 an
update makes (act, the targets' pass, 2 epochs of forward and backward).

**Memory** (``core``: ``"lstm"`` or ``"gru"``; the last section): a recurrent core between the torso
and the Q head (:class:`~agentax.nets.RecurrentQNetwork`), acting ε-greedily through
``Agent.recurrent`` as PPO does: each env's carry travels with the rollout, reset to zeros where an
episode starts, and every step's ``info`` keeps the carry it received and its ``first`` flag. ``learn``
runs the core through the whole rollout with the learner's parameters for the targets' ``max_a Q``
(each observation reached read from the memory after its step), then takes its minibatches as whole
env sequences (``bptt`` steps, or the rollout), each run through the core from its stored carry:
backpropagation through time from a stored state, as R2D2. Only the compiled runner carries the memory.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from agentax.agents.protocol import (
    Agent,
    EnvSpec,
    Loop,
    OnPolicy,
    Recurrent,
    check_fields,
    discrete_actions,
    image_shape_for,
)
from agentax.agents.sequences import (
    initial_memory,
    recurrent_net_fields,
    sequence_length,
    time_major,
    validate_core,
    whole_sequences,
)
from agentax.envs.core import RecurrentPolicy
from agentax.errors import UsageError
from agentax.nets import (
    MLP,
    Memory,
    MinAtarCNN,
    NatureCNN,
    RecurrentQNetwork,
    dense_layer,
    is_image,
    legal_max,
    masked,
    with_encoder,
)
from agentax.policies import Policy, epsilon_greedy, linear_schedule
from agentax.replay import Transition
from agentax.returns import masked_mean, q_lambda_returns


@dataclass(frozen=True)
class PQNConfig:
    """PQN's settings (defaults: CartPole-v1; 8 of 8 seeds at 500 after 200k env steps, measured)."""

    num_envs: int = 16
    """environments stepped side by side; their rollouts replace a replay buffer"""
    num_steps: int = 32
    """steps per env in each rollout"""
    total_steps: int = 200_000
    """env steps of the whole run (summed over envs)"""
    learning_rate: float = 1e-3
    anneal_lr: bool = True
    """decay the learning rate linearly to 0 over the run"""
    discount_factor: float = 0.99
    q_lambda: float = 0.65
    """λ of the Q(λ) targets (0: one-step Q-learning, 1: Monte-Carlo returns)"""
    update_epochs: int = 4
    num_minibatches: int = 8
    max_grad_norm: float = 10.0
    epsilon_start: float = 1.0
    epsilon_end: float = 0.05
    exploration_fraction: float = 0.1
    """fraction of total_steps over which ε falls from epsilon_start to epsilon_end"""
    hidden: tuple[int, ...] = (128, 128)
    activation: str = "relu"
    conv_torso: bool = False
    """MinAtar's conv torso (conv 16 3×3, dense 128, LayerNorm) instead of the MLP (``hidden``
    unused), on an env whose flat observations are an image (``EnvSpec.image_shape``)"""
    core: str = "none"
    """a recurrent core after the torso: lstm, gru, or none (feed-forward); its memory of each env is
    reset where an episode starts and learned by backpropagation through time (compiled runner)"""
    core_size: int = 128
    """units of the recurrent core (and of the hidden layer before the Q head)"""
    bptt: int = 0
    """steps of the sequences the core is learned on, each from the memory stored where it starts
    (0: the whole rollout of num_steps); num_steps must split into them"""

    @property
    def sequence_length(self) -> int:
        """Steps of each sequence the core learns on (``bptt``, or the whole rollout)."""
        return sequence_length(self)

    @property
    def steps_per_update(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def num_updates(self) -> int:
        return max(1, self.total_steps // self.steps_per_update)

    def validate(self) -> PQNConfig:
        """Raise a UsageError naming the first bad value."""
        check_fields(
            self,
            positive=(
                "total_steps",
                "num_envs",
                "num_steps",
                "learning_rate",
                "num_minibatches",
                "update_epochs",
            ),
            unit_interval=(
                "discount_factor",
                "q_lambda",
                "epsilon_start",
                "epsilon_end",
                "exploration_fraction",
            ),
            non_negative=("max_grad_norm",),
        )
        if self.steps_per_update % self.num_minibatches:
            raise UsageError(
                f"num_envs × num_steps ({self.steps_per_update}) must split into num_minibatches "
                f"({self.num_minibatches}) equal minibatches"
            )
        if self.core != "none":
            validate_core(self)
        return self


@struct.dataclass
class PQNState:
    params: Any
    opt_state: Any
    updates: jax.Array  # int32 []: learning iterations so far


def q_network(cfg: PQNConfig, spec: EnvSpec, conv: str = "xla", precision: str = "f32") -> nn.Module:
    """``obs [..., *obs_shape] -> Q [..., num_actions]`` with LayerNorm after every hidden layer: an
    MLP of ``hidden`` on flat observations (packed ones through their encoder first), the Nature CNN
    on stacked frames (its convolutions on backend ``conv``), MinAtar's conv torso with ``conv_torso``;
    the products in ``precision``."""
    num_actions = discrete_actions(spec, "pqn")
    head = dense_layer(num_actions, precision)
    if is_image(spec.obs_shape):
        return nn.Sequential([NatureCNN(layer_norm=True, conv=conv, precision=precision), head])
    image_shape = image_shape_for(cfg.conv_torso, spec)
    if image_shape is not None:
        return nn.Sequential([MinAtarCNN(image_shape, layer_norm=True, precision=precision), head])
    mlp = MLP(cfg.hidden, cfg.activation, out=num_actions, layer_norm=True, precision=precision)
    return with_encoder(mlp, spec.layout, precision)


QValues = Callable[[Any, jax.Array], jax.Array]
"""``q_values(params, obs [..., *obs_shape]) -> [..., num_actions]``"""


def q_values_of(net: nn.Module, spec: EnvSpec) -> QValues:
    """The network's Q-values; flat observations as float32 first (a host env may give float64),
    frames left uint8 (the CNN scales them)."""
    if is_image(spec.obs_shape):
        return net.apply
    return lambda params, obs: net.apply(params, obs.astype(jnp.float32))


def optimizer(cfg: PQNConfig) -> optax.GradientTransformation:
    learning_rate = (
        optax.linear_schedule(
            cfg.learning_rate, 0.0, cfg.num_updates * cfg.update_epochs * cfg.num_minibatches
        )
        if cfg.anneal_lr
        else cfg.learning_rate
    )
    return optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.radam(learning_rate))


def epsilon_at(cfg: PQNConfig, env_steps: jax.Array) -> jax.Array:
    duration = max(cfg.exploration_fraction * cfg.total_steps, 1.0)
    return linear_schedule(cfg.epsilon_start, cfg.epsilon_end, duration)(env_steps)


def loss_fn(params: Any, q_values: QValues, minibatch: dict[str, jax.Array]) -> tuple[jax.Array, dict]:
    """½ mean squared TD error of ``minibatch`` (``obs``, ``action``, ``target`` ``[B]``; ``valid``
    ``[B]``, if there, the entries the means run over)."""
    return td_loss(q_values(params, minibatch["obs"]), minibatch)


def td_loss(q: jax.Array, batch: dict[str, jax.Array]) -> tuple[jax.Array, dict]:
    """½ mean squared TD error of the Q-values ``q [..., num_actions]`` of ``batch``'s steps
    (``action``, ``target`` ``[...]``; ``valid``, if there, the entries the means run over)."""
    q_taken = jnp.take_along_axis(q, batch["action"][..., None], axis=-1)[..., 0]
    td = q_taken - batch["target"]
    valid = batch.get("valid")
    return 0.5 * masked_mean(td**2, valid), {"q_mean": masked_mean(q_taken, valid)}


def q_lambda_targets(rollout: Transition, next_q: jax.Array, cfg: PQNConfig) -> jax.Array:
    """Peng's Q(λ) targets ``[T, E]`` of a rollout from ``max_a Q(s'_t, a)`` ``[T, E]``."""
    done = rollout.terminated | rollout.truncated
    return q_lambda_returns(
        rollout.reward, next_q, rollout.terminated, done, cfg.discount_factor, cfg.q_lambda
    )


def sgd_epochs(
    loss: Callable[[Any, dict[str, Any]], tuple[jax.Array, dict]],
    data: dict[str, Any],
    state: PQNState,
    key: jax.Array,
    cfg: PQNConfig,
    loop: Loop,
) -> tuple[PQNState, dict[str, jax.Array]]:
    """``update_epochs`` passes of minibatch SGD from ``state``'s parameters: ``data``'s leaves
    ``[N, ...]`` (N steps, or N whole sequences) shuffled each epoch and split into
    ``num_minibatches``; ``loss(params, minibatch) -> (loss, metrics)``. Returns the next state and
    the metrics' means."""
    tx, size = optimizer(cfg), jax.tree.leaves(data)[0].shape[0]
    grad_fn = jax.value_and_grad(loss, has_aux=True)

    def sgd_step(carry, minibatch):
        params, opt_state = carry
        (loss_value, metrics), grads = grad_fn(params, minibatch)
        updates, opt_state = tx.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), {"loss": loss_value, **metrics}

    def epoch(carry, epoch_key):
        order = jax.random.permutation(epoch_key, size)
        minibatches = jax.tree.map(lambda x: x[order].reshape(cfg.num_minibatches, -1, *x.shape[1:]), data)
        return loop(sgd_step, carry, minibatches)

    (params, opt_state), metrics = loop(
        epoch, (state.params, state.opt_state), jax.random.split(key, cfg.update_epochs)
    )
    return PQNState(params, opt_state, state.updates + 1), jax.tree.map(jnp.mean, metrics)


def learn(
    state: PQNState,
    rollout: Transition,
    key: jax.Array,
    q_values: QValues,
    cfg: PQNConfig,
    loop: Loop = jax.lax.scan,
    legal: Callable[[jax.Array], jax.Array | None] = lambda obs: None,
) -> tuple[PQNState, dict[str, jax.Array]]:
    """One PQN iteration on a rollout ``[T, E]``: Q(λ) targets, then epochs of minibatch SGD, run by
    ``loop`` (``lax.scan``'s signature; the runner chooses it). ``legal``: the legal actions of
    observations (:meth:`EnvSpec.legal`), the targets' maxima running over those of ``next_obs``."""

    def max_q(obs: jax.Array) -> jax.Array:  # (...,): max_a Q(obs, a) over the legal actions
        return legal_max(q_values(state.params, obs), legal(obs))

    if "valid" in rollout.info:  # next_obs[t] is obs[t + 1]: act's Q-values, and the last step's
        next_q = jnp.concatenate([rollout.info["max_q"][1:], max_q(rollout.next_obs[-1])[None]])  # (T, E)
    else:
        next_q = max_q(rollout.next_obs)  # (T, E)
    flat = {"obs": rollout.obs, "action": rollout.action, "target": q_lambda_targets(rollout, next_q, cfg)}
    if "valid" in rollout.info:
        flat["valid"] = rollout.info["valid"]
    flat = jax.tree.map(lambda x: x.reshape(cfg.steps_per_update, *x.shape[2:]), flat)
    state, metrics = sgd_epochs(
        lambda params, minibatch: loss_fn(params, q_values, minibatch), flat, state, key, cfg, loop
    )
    return state, {**metrics, "epsilon": rollout.info["epsilon"].mean()}


def explore(q: jax.Array, legal: jax.Array | None, key: jax.Array, epsilon: jax.Array):
    """ε-greedy actions ``[E]`` of the Q-values ``q [E, num_actions]`` among the ``legal`` actions
    (None: all), and the ``info`` a rollout keeps (ε, and ``max_a Q`` for the targets)."""
    keys = jax.random.split(key, q.shape[0])
    action = jax.vmap(epsilon_greedy, in_axes=(0, 0, None, 0))(keys, q, epsilon, legal)
    return action, {"epsilon": jnp.full(q.shape[0], epsilon, jnp.float32), "max_q": legal_max(q, legal)}


def make_agent(
    spec: EnvSpec, cfg: PQNConfig, *, loop: Loop = jax.lax.scan, conv: str = "xla", precision: str = "f32"
) -> Agent:
    """PQN's pure functions for every runner (see ``agentax.agents.protocol``); ``act``'s ``progress``
    is the env steps that set ε; ``conv``: the Nature CNN's convolution backend; ``precision``: the
    network's products' (acting and learning alike)."""
    cfg.validate()
    if len(spec.obs_shape) != 1 and not is_image(spec.obs_shape):
        raise UsageError(f"PQN takes flat observations or stacked frames [C, H, W], not {spec.obs_shape}")
    if cfg.core != "none":
        if precision != "f32":
            raise UsageError(f"a recurrent core learns in f32 only, not --precision {precision}")
        return recurrent_agent(spec, cfg, loop, conv)
    net = q_network(cfg, spec, conv, precision)
    q_values = q_values_of(net, spec)

    def init(key: jax.Array) -> PQNState:
        params = net.init(key, jnp.zeros(spec.obs_shape, spec.obs_dtype))
        return PQNState(params, optimizer(cfg).init(params), jnp.int32(0))

    def act(state: PQNState, obs: jax.Array, key: jax.Array, progress: jax.Array):
        q = q_values(state.params, obs)  # (E, num_actions)
        return explore(q, spec.legal(obs), key, epsilon_at(cfg, progress))

    def greedy_policy(state: PQNState) -> Policy:
        def policy(obs: jax.Array, key: jax.Array) -> jax.Array:
            return jnp.argmax(masked(q_values(state.params, obs), spec.legal(obs))).astype(jnp.int32)

        return policy

    return Agent(
        name="pqn",
        init=init,
        act=act,
        greedy_policy=greedy_policy,
        learn=lambda state, rollout, key: learn(state, rollout, key, q_values, cfg, loop, spec.legal),
        experience=OnPolicy(cfg.num_envs, cfg.num_steps),
        total_steps=cfg.total_steps,
        learning_steps=lambda state: state.updates,
    )


# ---------------------------------------------------------------- with a recurrent core (cfg.core)


def recurrent_q_network(cfg: PQNConfig, spec: EnvSpec, conv: str = "xla") -> nn.Module:
    """PQN's Q-network with the core ``cfg.core`` after its torso (:class:`RecurrentQNetwork`), one
    step ``(obs, memory, first) -> (memory, Q)``."""
    net = RecurrentQNetwork(discrete_actions(spec, "pqn"), **recurrent_net_fields(cfg, spec, conv))
    return with_encoder(net, spec.layout)


def learn_sequences(
    state: PQNState,
    rollout: Transition,
    key: jax.Array,
    net: nn.Module,
    cfg: PQNConfig,
    loop: Loop = jax.lax.scan,
    legal: Callable[[jax.Array], jax.Array | None] = lambda obs: None,
) -> tuple[PQNState, dict[str, jax.Array]]:
    """One PQN iteration of a recurrent agent on a rollout ``[T, E, ...]`` whose ``info`` keeps the
    memory each step received and its ``first`` flag: the Q(λ) targets from the core run through the
    whole rollout with the learner's parameters (``max_a Q`` of each observation reached, from the
    memory after its step), then SGD on minibatches of whole sequences of ``cfg.sequence_length``
    steps, each from the memory stored where it starts (backpropagation through time)."""
    first, stored = rollout.info["first"], rollout.info["memory"]  # (T, E), (T, E, ...)

    start = jax.tree.map(lambda m: m[0], stored)
    memories, _ = net.apply(state.params, rollout.obs, start, first, True)  # (T, E, ...)
    _, next_q = net.apply(state.params, rollout.next_obs, memories, jnp.zeros_like(first))  # (T, E, A)
    next_q = legal_max(next_q, legal(rollout.next_obs))  # (T, E)
    steps = {
        "obs": rollout.obs,
        "action": rollout.action,
        "target": q_lambda_targets(rollout, next_q, cfg),
        "first": first,
    }
    if "valid" in rollout.info:
        steps["valid"] = rollout.info["valid"]
    data = whole_sequences(steps, stored, cfg.sequence_length)  # (N, L, ...), memory (N, ...)

    def loss(params, batch):  # the core run through each sequence from its stored memory
        seq = time_major(batch)  # (L, B, ...)
        _, q = net.apply(params, seq["obs"], batch["memory"], seq["first"], True)
        return td_loss(q, seq)

    state, metrics = sgd_epochs(loss, data, state, key, cfg, loop)
    return state, {**metrics, "epsilon": rollout.info["epsilon"].mean()}


def recurrent_greedy_policy(params: Any, net: nn.Module, spec: EnvSpec, cfg: PQNConfig) -> RecurrentPolicy:
    """The greedy policy with memory for evaluation: ``argmax_a Q`` given the episode so far, the
    core's memory carried by whoever plays it."""

    def step(memory: Memory, obs: jax.Array, key: jax.Array) -> tuple[Memory, jax.Array]:
        memory, q = net.apply(params, obs, memory, jnp.bool_(False))
        return memory, jnp.argmax(masked(q, spec.legal(obs))).astype(jnp.int32)

    return RecurrentPolicy(lambda: initial_memory(cfg), step)


def recurrent_agent(spec: EnvSpec, cfg: PQNConfig, loop: Loop = jax.lax.scan, conv: str = "xla") -> Agent:
    """PQN with the core ``cfg.core``: ε-greedy with memory (:class:`~agentax.agents.protocol.Recurrent`),
    learning on whole sequences (:func:`learn_sequences`); ``act`` alone acts from fresh memory."""
    net = recurrent_q_network(cfg, spec, conv)

    def init(key: jax.Array) -> PQNState:
        obs = jnp.zeros(spec.obs_shape, spec.obs_dtype)
        params = net.init(key, obs, initial_memory(cfg), jnp.bool_(True))
        return PQNState(params, optimizer(cfg).init(params), jnp.int32(0))

    def act_with_memory(state: PQNState, memory: Memory, obs: jax.Array, first: jax.Array, key, progress):
        new_memory, q = net.apply(state.params, obs, memory, first)  # (E, num_actions)
        action, info = explore(q, spec.legal(obs), key, epsilon_at(cfg, progress))
        return new_memory, action, {**info, "memory": memory, "first": first}

    def act_fresh(state: PQNState, obs: jax.Array, key: jax.Array, progress: jax.Array):
        batch = obs.shape[: obs.ndim - len(spec.obs_shape)]
        _, action, info = act_with_memory(
            state, initial_memory(cfg, batch), obs, jnp.ones(batch, bool), key, progress
        )
        return action, info

    return Agent(
        name="pqn",
        init=init,
        act=act_fresh,
        greedy_policy=lambda state: recurrent_greedy_policy(state.params, net, spec, cfg),
        learn=lambda state, rollout, key: learn_sequences(state, rollout, key, net, cfg, loop, spec.legal),
        experience=OnPolicy(cfg.num_envs, cfg.num_steps),
        total_steps=cfg.total_steps,
        learning_steps=lambda state: state.updates,
        recurrent=Recurrent(lambda num_envs: initial_memory(cfg, (num_envs,)), act_with_memory),
    )


__all__ = [
    "PQNConfig",
    "PQNState",
    "learn",
    "learn_sequences",
    "make_agent",
    "q_network",
    "recurrent_q_network",
]
