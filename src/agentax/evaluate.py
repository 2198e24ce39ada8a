"""Evaluating a policy: episode returns of any env -- JAX envs batched under ``jit``, Gymnasium's on the host.

JAX envs play with :func:`agentax.envs.core.episode_returns` (pure and jittable, beside the env
protocol); ``host_episode_returns`` steps a Gymnasium vector env. ``evaluate`` picks the right one
and summarises the returns.

Policies are JAX functions ``policy(obs, key) -> action`` on one observation, or, for host envs
only, a :class:`HostPolicy` in NumPy acting on the whole batch.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agentax.envs import Discrete, Environment, GymnasiumEnv, make
from agentax.envs.core import EnvParams, RecurrentPolicy, batched_policy, episode_returns
from agentax.errors import UsageError
from agentax.policies import Policy


@dataclass(frozen=True)
class EvalStats:
    """Statistics of episode returns over ``episodes`` episodes."""

    mean_return: float
    std_return: float
    min_return: float
    max_return: float
    episodes: int
    mean_length: float

    @classmethod
    def from_returns(cls, returns, lengths) -> EvalStats:
        returns, lengths = np.asarray(returns, np.float64), np.asarray(lengths)
        return cls(
            mean_return=float(returns.mean()),
            std_return=float(returns.std()),
            min_return=float(returns.min()),
            max_return=float(returns.max()),
            episodes=int(returns.size),
            mean_length=float(lengths.mean()),
        )

    def to_json(self) -> str:
        return json.dumps(asdict(self))


@dataclass(frozen=True)
class HostPolicy:
    """A NumPy policy for host (Gymnasium) envs, acting on the whole batch of sub-envs.

    ``act(obs [num_envs, *obs_shape], rng) -> actions [num_envs, ...]``, where ``rng`` is a
    ``numpy.random.Generator`` seeded with the evaluation's seed.
    """

    act: Callable[[np.ndarray, np.random.Generator], np.ndarray]


@partial(jax.jit, static_argnums=(0, 1, 3))
def _episode_returns_jit(env, policy, key, num_episodes, env_params):
    return episode_returns(env, policy, key, num_episodes, env_params)


@partial(jax.jit, static_argnums=0)
def _act_batch(policy: Policy, obs: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``policy`` on each observation ``obs: [num_envs, ...]``; returns the actions and the next key."""
    key, act_key = jax.random.split(key)
    return jax.vmap(policy)(obs, jax.random.split(act_key, obs.shape[0])), key


@partial(jax.jit, static_argnums=0)
def _act_recurrent(
    policy: RecurrentPolicy, memory: Any, obs: jax.Array, first: jax.Array, key: jax.Array
) -> tuple[Any, jax.Array, jax.Array]:
    """:func:`_act_batch` for a policy with memory: ``(memory, actions, next key)``, each env's
    memory started afresh where ``first`` marks an episode's start."""
    key, act_key = jax.random.split(key)
    _, act = batched_policy(policy, obs.shape[0])
    memory, actions = act(memory, obs, jax.random.split(act_key, obs.shape[0]), first)
    return memory, actions, key


def host_actor(policy: Policy | RecurrentPolicy | HostPolicy, seed: int) -> Callable[..., np.ndarray]:
    """A stateful ``act(obs [num_envs, ...], first=None) -> actions`` for a host env, its randomness
    from ``seed``; ``first`` (bool ``[num_envs]``) marks the observations that start an episode, where
    a :class:`RecurrentPolicy` starts its memory afresh (it starts fresh at the first call anyway).

    A JAX policy draws step ``t``'s keys as ``key_t, act_key = split(key_{t-1})`` from
    ``key_0 = jax.random.key(seed)``, then ``split(act_key, num_envs)``.
    """
    if isinstance(policy, HostPolicy):
        rng = np.random.default_rng(seed)
        return lambda obs, first=None: np.asarray(policy.act(obs, rng))
    key, memory = jax.random.key(seed), None

    def act(obs: np.ndarray, first: np.ndarray | None = None) -> np.ndarray:
        nonlocal key, memory
        if not isinstance(policy, RecurrentPolicy):
            actions, key = _act_batch(policy, jnp.asarray(obs), key)
            return np.asarray(actions)
        if memory is None:  # fresh: each env's memory at an episode's start
            memory = batched_policy(policy, len(obs))[0]
        first = np.zeros(len(obs), bool) if first is None else np.asarray(first, bool)
        memory, actions, key = _act_recurrent(policy, memory, jnp.asarray(obs), jnp.asarray(first), key)
        return np.asarray(actions)

    return act


MAX_EPISODE_STEPS = 10_000
"""Where an episode of a host env is cut in evaluation: envs without a time limit of their own
(CliffWalking-v1) would otherwise never end under a policy that never reaches the goal."""


def host_episode_returns(
    env: GymnasiumEnv,
    policy: Policy | HostPolicy,
    num_episodes: int,
    seed: int = 0,
    max_steps: int = MAX_EPISODE_STEPS,
) -> tuple[np.ndarray, np.ndarray]:
    """Returns and lengths ``[num_episodes]`` of the first ``num_episodes`` episodes started in ``env``.

    Each sub-env plays episodes one after another (sub-env ``i`` seeded ``seed + i``); an episode
    counts if it is among the first ``num_episodes`` to start (ties in slot order), whatever its
    length, so short episodes are not over-represented. Episodes are listed in order of start. An
    episode still going after ``max_steps`` steps ends there, and its sub-env plays no more (a vector
    env resets sub-envs only as they end): fewer than ``num_episodes`` may then be returned.
    """
    act = host_actor(policy, seed)
    obs = env.reset(seed=seed)
    slots = np.arange(env.num_envs)
    episode = np.where(slots < num_episodes, slots, -1)  # the counted episode each sub-env plays, or -1
    started = min(env.num_envs, num_episodes)
    returns, lengths = np.zeros(num_episodes), np.zeros(num_episodes, np.int64)
    first = np.ones(env.num_envs, bool)
    while (episode >= 0).any():
        ts = env.step(act(obs, first))
        first = np.asarray(ts.terminated | ts.truncated)
        counted = episode >= 0
        returns[episode[counted]] += ts.reward[counted]
        lengths[episode[counted]] += 1
        for i in np.flatnonzero(counted & (ts.terminated | ts.truncated)):
            episode[i], started = (started, started + 1) if started < num_episodes else (-1, started)
        episode[counted & (episode >= 0) & (lengths[np.maximum(episode, 0)] >= max_steps)] = -1  # cut
        obs = ts.obs
    return returns[:started], lengths[:started]


def check_policy_fits(env: Environment | GymnasiumEnv, policy: Policy | HostPolicy, env_id: str = "") -> None:
    """Raise ``UsageError`` unless the JAX ``policy`` reads ``env``'s observations and returns its actions.

    Traced once with abstract values (``jax.eval_shape``), so nothing runs.
    """
    if isinstance(policy, HostPolicy):
        return
    env_id = env_id or getattr(env, "id", type(env).__name__)
    obs_space, action_space = env.observation_space(), env.action_space()
    obs = jax.ShapeDtypeStruct(obs_space.shape, jnp.int32 if isinstance(obs_space, Discrete) else jnp.float32)
    try:
        if isinstance(policy, RecurrentPolicy):
            action = jax.eval_shape(
                lambda o, k: policy.step(policy.initial(), o, k)[1], obs, jax.random.key(0)
            )
        else:
            action = jax.eval_shape(policy, obs, jax.random.key(0))
    except (TypeError, ValueError, IndexError) as error:
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise UsageError(f"the policy cannot read {env_id}'s observations {obs_space}: {reason}") from error
    integer = jnp.issubdtype(action.dtype, jnp.integer)
    fits = (
        integer and action.shape == ()
        if isinstance(action_space, Discrete)
        else action.shape == action_space.shape
    )
    if not fits:
        raise UsageError(
            f"the policy returns actions of shape {action.shape} and dtype {action.dtype}, "
            f"but {env_id} takes {action_space}"
        )


def evaluate(
    env: Environment | GymnasiumEnv | str,
    policy: Policy | HostPolicy,
    num_episodes: int = 100,
    seed: int = 0,
    env_params: EnvParams | None = None,
) -> EvalStats:
    """Mean, std, min and max of the returns of ``num_episodes`` episodes of ``policy`` in ``env``.

    ``env`` is a JAX env (all episodes side by side in one compiled call), a host
    :class:`~agentax.envs.GymnasiumEnv`, or an id for :func:`agentax.envs.make` (a Gymnasium env
    then gets up to 16 sub-envs).
    """
    if num_episodes <= 0:
        raise UsageError(f"the number of episodes must be at least 1, not {num_episodes}")
    if isinstance(env, str):
        env = make(env, num_envs=min(num_episodes, 16))
    if isinstance(env, GymnasiumEnv):
        returns, lengths = host_episode_returns(env, policy, num_episodes, seed)
        return EvalStats.from_returns(returns, lengths)
    if isinstance(policy, HostPolicy):
        raise UsageError(f"{env.id} is a JAX env: give a JAX policy (obs, key) -> action, not a HostPolicy")
    params = env.default_params() if env_params is None else env_params
    returns, lengths = _episode_returns_jit(env, policy, jax.random.key(seed), num_episodes, params)
    return EvalStats.from_returns(returns, lengths)
