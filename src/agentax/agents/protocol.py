"""The agent protocol: what every algorithm offers, whatever runner drives it.

An algorithm module (each of the registry :data:`agentax.agents.ALGORITHMS`) is a namespace of pure
functions over pytrees. Its contract, written once here:

- a frozen config dataclass with ``total_steps`` and ``validate()``, named in the registry
  (``agentax.agents.ALGORITHMS``), its tuned presets (``"default"`` among them) in
  ``agentax.agents.presets``;
- ``make_agent(spec: EnvSpec, cfg, *, loop=jax.lax.scan, conv="xla", precision="f32") -> Agent``: the
  four pure functions below, closed over the env's spec and the config, and the experience they
  learn from (``conv``: the convolution backend the entry point chose, :mod:`agentax.kernel_choice`;
  ``precision``: its networks' products, ``f32`` or ``bf16``, for acting and learning alike).
  Every runner drives this one object; the compiled runner builds its program from it
  (:mod:`agentax.runners.rollout`).

An :class:`Agent` is TF-Agents' agent in JAX terms:

=====================  ===========================================================================
``init(key)``          a fresh agent state: parameters, optimizer state, counters
``act(state, obs,      the collect policy, batched over envs: ``obs [E, *obs_shape]`` → ``(action
key, progress)``       [E], info)``; ``info`` holds per-env arrays learning needs (PPO's
                       log-probabilities and values); ``progress`` counts env steps (or episodes)
                       for exploration schedules
``greedy_policy(st)``  the evaluation policy ``(obs, key) -> action`` on one observation (with
                       memory: a :class:`~agentax.envs.core.RecurrentPolicy`)
``learn(state, exp,    one learning step on ``experience``: a trajectory (a
key)``                 :class:`~agentax.replay.Transition` ``[T, E]``, its ``info`` from ``act``)
                       for on-policy agents, a :class:`~agentax.replay.ReplaySample` for off-policy
=====================  ===========================================================================

``experience`` says which: :class:`OnPolicy` (rollouts of ``num_steps`` steps from ``num_envs``
envs, collected with the current parameters), :class:`Episodes` (whole episodes from fresh resets,
REINFORCE) or :class:`OffPolicy` (a replay buffer, its sample size and the learning schedule).
What runners rely on, and nothing more: ``act``'s ``info`` entries that are scalars (DQN's
``epsilon``) and every scalar metric of ``learn`` become columns of metrics.csv (per-sample arrays
are not logged); an off-policy ``learn`` on prioritized replay returns the new priorities
``[batch]`` as ``metrics[PRIORITY]``; ``OffPolicy.importance_exponent`` is traceable.
Runners (``agentax.runners``) own the loop; an agent never imports a runner, the CLI or the run
folder. This module is a leaf: both sides import it, it imports neither.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp

from agentax.envs.core import Box
from agentax.envs.spaces import Layout, is_plain, layout_of
from agentax.errors import UsageError
from agentax.policies import Policy

PRIORITY = "priority"
"""The metric of an off-policy ``learn`` that holds each sampled transition's new priority ``[batch]``
(DQN: ``|TD error|``, or C51's cross-entropy); runners write it back into prioritized replay."""
AgentState = Any
Experience = Any
Loop = Callable[[Callable, Any, Any], tuple[Any, Any]]
"""How a learning phase runs its steps: ``loop(f, carry, xs) -> (carry, ys)``, ``jax.lax.scan``'s
signature. The runner chooses it for its platform (:func:`agentax.kernels.learning_loop`) and hands it
to ``make_agent(spec, cfg, loop=..., conv=..., precision=...)`` with the convolution backend and the
networks' precision; an agent never asks which backend it is on."""


@dataclass(frozen=True)
class EnvSpec:
    """What an agent needs to know of an env: one observation's shape and dtype, the action space,
    and how the observation is laid out where it is not a plain vector or frames."""

    obs_shape: tuple[int, ...]
    action_space: Any
    """Discrete, Box, MultiDiscrete or MultiBinary"""
    obs_dtype: Any = jnp.float32
    image_shape: tuple[int, ...] | None = None
    """``[H, W, C]`` when the flat observation is an image flattened (MinAtar's channels, the env's
    ``image_shape``): a network that wants the image reshapes the vector back; None otherwise"""
    layout: Layout | None = None
    """where the observation is composite, an image ``[H, W, C]``, Discrete or masked: how its leaves
    are packed into the flat vector ``[layout.size]`` the env gives (:mod:`agentax.envs.spaces`)"""

    @classmethod
    def of(cls, env: Any, env_params: Any = None) -> EnvSpec:
        """The spec of a JAX env (with its default params) or a host env (``GymnasiumEnv``)."""
        if hasattr(env, "default_params"):
            params = env.default_params() if env_params is None else env_params
            obs_space, action_space = env.observation_space(params), env.action_space(params)
        else:
            obs_space, action_space = env.observation_space(), env.action_space()
        image_shape = getattr(env, "image_shape", None)
        layout = getattr(env, "layout", None)
        if layout is None:
            check_observations(obs_space, getattr(env, "id", None))
        check_actions(action_space, getattr(env, "id", None))
        return cls(tuple(obs_space.shape), action_space, jnp.dtype(obs_space.dtype), image_shape, layout)

    def with_encoders(self, overrides: dict[str, str] | None, env_id: str | None = None) -> EnvSpec:
        """This spec with the leaves' encoders ``overrides`` chooses (key → choice, see
        :meth:`agentax.envs.spaces.Layout.with_encoders`); itself without any. A one-line
        ``UsageError`` where the observations are plain: there are no leaves to choose for."""
        if not overrides:
            return self
        if self.layout is None:
            flags = " ".join(f"{key}={choice}" for key, choice in overrides.items())
            raise UsageError(
                f"--encoder {flags}: {env_id or 'the env'}'s observations are plain "
                f"{list(self.obs_shape)}, not Dict, Tuple, Discrete or small images; encoders are chosen "
                "per key of those only"
            )
        return dataclasses.replace(self, layout=self.layout.with_encoders(overrides))

    def legal(self, obs: jax.Array) -> jax.Array | None:
        """The legal actions ``bool [..., n]`` of observations ``[..., *obs_shape]`` (None: all)."""
        return None if self.layout is None else self.layout.legal(obs)


def action_nvec(space: Any) -> tuple[int, ...] | None:
    """The entries' sizes of a MultiDiscrete or MultiBinary action space; None for one Discrete choice."""
    name = type(space).__name__
    if name == "MultiBinary":
        return (2,) * int(space.n)
    if name == "MultiDiscrete":
        return tuple(int(n) for n in space.nvec)
    return None


def num_logits(space: Any) -> int:
    """The logits of a categorical policy over ``space``: ``n``, or ``Σ nvec`` for several choices."""
    nvec = action_nvec(space)
    return int(space.n) if nvec is None else sum(nvec)


def check_actions(space: Any, env_id: str | None = None) -> None:
    """A ``UsageError`` naming an action space agentax does not take."""
    if type(space).__name__ not in ("Discrete", "Box", "MultiDiscrete", "MultiBinary"):
        raise UsageError(
            f"{env_id or 'the env'} has actions {space}, which agentax does not take; it takes Discrete, "
            "Box, MultiDiscrete and MultiBinary actions"
        )


def discrete_actions(spec: EnvSpec, algorithm: str, multi: bool = False) -> int:
    """The number of actions of a Discrete space (with ``multi``, the logits of a MultiDiscrete or
    MultiBinary one too); a ``UsageError`` naming what fits for any other space."""
    name = type(spec.action_space).__name__
    if name == "Discrete" or (multi and name in ("MultiDiscrete", "MultiBinary")):
        return num_logits(spec.action_space)
    takes = "Discrete, MultiDiscrete and MultiBinary" if multi else "Discrete"
    fits = "ppo and reinforce take MultiDiscrete and MultiBinary actions, sac and td3 Box ones"
    raise UsageError(
        f"{algorithm} takes {takes} actions, but this env's actions are {spec.action_space}; {fits}"
    )


def check_observations(space: Any, env_id: str | None = None) -> None:
    """A ``UsageError`` for an env whose observations are not plain (:func:`agentax.envs.spaces.is_plain`)
    and come unpacked: naming the space where no encoder takes it, else how to pack them."""
    if is_plain(space):
        return
    layout_of(space, env_id)  # a space agentax cannot take at all is its own one-line error
    raise UsageError(
        f"{env_id or 'the env'} gives observations {space} unpacked; make it with agentax.envs.make "
        "(or wrap it: agentax.envs.spaces.packed(env)), which packs them for the agents"
    )


@dataclass(frozen=True)
class OnPolicy:
    """Rollouts of ``num_steps`` steps from each of ``num_envs`` envs, with the current parameters."""

    num_envs: int
    num_steps: int


@dataclass(frozen=True)
class Episodes:
    """``num_envs`` whole episodes from fresh resets, at most ``max_steps`` steps each; the
    trajectory ``[max_steps, num_envs]`` marks the steps inside an episode in ``info["valid"]``."""

    num_envs: int
    max_steps: int


@dataclass(frozen=True)
class OffPolicy:
    """A replay buffer and the learning schedule.

    Collect ``train_frequency`` steps per env (or ``train_frequency`` episodes with ``by_episode``)
    between learning phases of ``gradient_steps`` learning steps on batches of ``batch_size``,
    once ``learning_starts`` env steps (episodes) are in. Transitions are ``n_step``-step returns.
    """

    num_envs: int
    capacity: int
    batch_size: int
    learning_starts: int
    train_frequency: int
    gradient_steps: int
    n_step: int = 1
    discount_factor: float = 0.99
    prioritized: bool = False
    priority_exponent: float = 0.6
    importance_exponent: Callable[[jax.Array], jax.Array] = field(
        default=lambda env_steps: jnp.float32(1.0), compare=False
    )
    """β of prioritized replay's importance weights after ``env_steps`` (traceable: a compiled loop
    calls it on a traced count, the host runner on an int, taking ``float`` of the result)"""
    by_episode: bool = False
    max_episodes: int = 0
    """stop collecting after this many episodes (0: no limit)"""

    @property
    def learning_steps_per_env_step(self) -> float:
        """The ratio a runner keeps between learning and collection (steps schedule)."""
        return self.gradient_steps / (self.train_frequency * self.num_envs)


Memory = Any
"""A recurrent agent's memory of each env: its core's carry, leaves ``[num_envs, ...]``."""


@dataclass(frozen=True)
class Recurrent:
    """How an agent with memory acts (its ``Agent.recurrent``): the runner carries each env's memory
    beside the observation from step to step, and marks the observations that start an episode.

    ``initial(num_envs)``: the memory at the start, zeros ``[num_envs, ...]``.
    ``act(state, memory, obs, first, key, progress) -> (memory, action, info)``: the collect policy,
    ``memory`` reset where ``first`` (bool ``[num_envs]``) marks an episode's start before the step;
    its ``info`` keeps the ``memory`` it received and ``first``, so that ``learn`` replays the
    rollout's sequences through the core (backpropagation through time).
    The agent's ``greedy_policy`` gives a :class:`~agentax.envs.core.RecurrentPolicy`. The runners
    that carry memory say so (``carries_memory``); :func:`agentax.runners.launch.prepare` refuses the
    others."""

    initial: Callable[[int], Memory]
    act: Callable[..., tuple[Memory, jax.Array, dict[str, jax.Array]]]


@dataclass(frozen=True)
class Agent:
    """One algorithm's pure functions for one env spec and config (see the module docstring)."""

    name: str
    init: Callable[[jax.Array], AgentState]
    act: Callable[[AgentState, jax.Array, jax.Array, jax.Array], tuple[jax.Array, dict[str, jax.Array]]]
    greedy_policy: Callable[[AgentState], Policy]
    learn: Callable[[AgentState, Experience, jax.Array], tuple[AgentState, dict[str, jax.Array]]]
    experience: OnPolicy | Episodes | OffPolicy
    total_steps: int
    env_action: Callable[[jax.Array], jax.Array] = field(default=lambda action: action, compare=False)
    """what the env receives for a sampled action (PPO clips continuous actions to the bounds)"""
    learning_steps: Callable[[AgentState], jax.Array] | None = field(default=None, compare=False)
    """the learning steps a state has taken, for the runners' ``learning_steps`` column (None: not logged)"""
    recurrent: Recurrent | None = field(default=None, compare=False)
    """how the agent acts with memory (None: feed-forward; then ``act`` is all there is). A recurrent
    agent's ``act`` is its policy at an episode's first step (the memory fresh)"""


ACTING_UNUSED = ("opt_state", "target_params")
"""Fields of an agent state that ``act`` never reads (every agent's ``act`` reads ``params`` and
static fields only; ``tests/test_architecture.py`` checks it)."""


def acting_view(state: AgentState) -> AgentState:
    """What actors in other processes need of an agent state: ``state`` without its optimizer state
    and target parameters (a Nature-CNN DQN's state shrinks 4x, to its parameters)."""
    return state.replace(**{name: None for name in ACTING_UNUSED if hasattr(state, name)})


def check_fields(
    cfg: Any,
    positive: tuple[str, ...] = (),
    unit_interval: tuple[str, ...] = (),
    non_negative: tuple[str, ...] = (),
    activation: str | None = "activation",
) -> None:
    """A ``UsageError`` naming the first field of ``cfg`` outside its range: ``positive`` (> 0),
    ``unit_interval`` ([0, 1]), ``non_negative`` (≥ 0); ``activation`` names a field that must be
    one of the activations of :mod:`agentax.nets`."""
    from agentax.nets import ACTIVATIONS

    def concrete(names: tuple[str, ...]) -> tuple[str, ...]:  # a sweep's traced values are checked before
        return tuple(n for n in names if not isinstance(getattr(cfg, n), jax.core.Tracer))

    positive, unit_interval, non_negative = (
        concrete(positive),
        concrete(unit_interval),
        concrete(non_negative),
    )
    for name in positive:
        if getattr(cfg, name) <= 0:
            raise UsageError(f"{name} must be positive, got {getattr(cfg, name)}")
    for name in unit_interval:
        if not 0.0 <= getattr(cfg, name) <= 1.0:
            raise UsageError(f"{name} must lie in [0, 1], got {getattr(cfg, name)}")
    for name in non_negative:
        if getattr(cfg, name) < 0:
            raise UsageError(f"{name} must not be negative, got {getattr(cfg, name)}")
    if activation is not None and getattr(cfg, activation) not in ACTIVATIONS:
        choices = ", ".join(ACTIVATIONS)
        raise UsageError(f"unknown {activation} {getattr(cfg, activation)!r}; choose from {choices}")


def continuous_action_dim(spec: EnvSpec, algorithm: str) -> int:
    """The length of a flat Box action; a ``UsageError`` naming what fits for any other space."""
    space = spec.action_space
    if not isinstance(space, Box) and type(space).__name__ != "Box":
        raise UsageError(
            f"{algorithm} needs continuous (Box) actions, but this env's actions are {space}; "
            "use dqn, pqn or ppo on discrete actions, or a Box env (Pendulum-v1, HalfCheetah-v5)"
        )
    if len(space.shape) != 1:
        raise UsageError(f"{algorithm} needs flat Box actions, got shape {tuple(space.shape)}")
    return int(space.shape[0])


def flat_observations(spec: EnvSpec, algorithm: str) -> int:
    """The length of a flat observation; a ``UsageError`` for frames, which only the agents with a
    convolutional torso take."""
    if len(spec.obs_shape) != 1:
        raise UsageError(
            f"{algorithm} takes flat observations [n], not frames {list(spec.obs_shape)}; ppo, dqn and pqn "
            "take stacked frames"
        )
    return spec.obs_shape[0]


def scale_action(action: jax.Array, space: Box) -> jax.Array:
    """An action in ``[-1, 1]^d`` mapped affinely onto the space's bounds ``[low, high]``."""
    low, high = jnp.asarray(space.low, jnp.float32), jnp.asarray(space.high, jnp.float32)
    return low + (jnp.clip(action, -1.0, 1.0) + 1.0) * 0.5 * (high - low)


def image_shape_for(conv_torso: bool, spec: EnvSpec) -> tuple[int, ...] | None:
    """The ``[H, W, C]`` a conv torso reshapes flat observations to (``spec.image_shape``) when the
    config asks for one, else None; a ``UsageError`` when it asks on an env without an image."""
    if not conv_torso:
        return None
    if spec.image_shape is None or len(spec.obs_shape) != 1:
        raise UsageError(
            f"conv_torso needs flat observations of an image (a gymnax MinAtar game), not {spec.obs_shape}"
        )
    return tuple(spec.image_shape)
