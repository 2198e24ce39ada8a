"""The functional environment protocol: jittable ``reset`` / ``step`` with explicit params.

Shaped like gymnax's, so its environments adapt easily. An environment object holds no state:
the state is a pytree passed in and out, the physical constants live in an ``EnvParams`` pytree,
and randomness is an explicit key. Batches of environments come from ``jax.vmap``::

    env, params = CartPole(), CartPole().default_params()
    keys = jax.random.split(key, num_envs)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)      # obs: [num_envs, 4]
    ts, state = jax.vmap(env.step, in_axes=(0, 0, 0, None))(keys, state, actions, params)

``step`` auto-resets: when an episode ends, ``TimeStep.obs`` is already the first observation of
the next episode and ``TimeStep.final_obs`` the observation the step really reached.

Two pure, jittable ways to play a policy ``policy(obs, key) -> action``: :func:`rollout` keeps every
state of one episode (for drawing paths and frames); :func:`episode_returns` plays a batch of episodes
side by side and keeps only their returns and lengths (for evaluation inside training loops and inside
``vmap`` over policy parameters).
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

Array = jax.Array
EnvState = Any
EnvParams = Any
Policy = Callable[[Array, Array], Array]
"""A policy: ``(obs, key) -> action`` on one observation; callers batch it with ``jax.vmap``."""


@dataclass(frozen=True)
class RecurrentPolicy:
    """A policy with memory (a recurrent agent's greedy policy), on one observation:
    ``step(memory, obs, key) -> (memory, action)``, ``initial()`` the memory an episode starts from.
    Whoever plays it carries each env's memory from step to step and starts it afresh with each
    episode (:func:`episode_returns`, :func:`agentax.evaluate.host_actor`)."""

    initial: Callable[[], Any]
    step: Callable[[Any, Array, Array], tuple[Any, Array]]


def batched_policy(policy: Policy | RecurrentPolicy, num_envs: int) -> tuple[Any, Callable]:
    """``(memory, act)`` to play ``policy`` on ``num_envs`` envs side by side: ``act(memory, obs
    [num_envs, ...], keys [num_envs], first bool [num_envs]) -> (memory, actions)``, the memory of
    each env whose observation starts an episode (``first``) set back to ``initial()`` first. A
    memoryless policy carries ``()`` and is ``vmap(policy)`` itself."""
    if not isinstance(policy, RecurrentPolicy):
        return (), lambda memory, obs, keys, first: ((), jax.vmap(policy)(obs, keys))
    fresh = jax.tree.map(lambda m: jnp.broadcast_to(m, (num_envs, *jnp.shape(m))), policy.initial())

    def act(memory: Any, obs: Array, keys: Array, first: Array) -> tuple[Any, Array]:
        starts = lambda m: first.reshape(-1, *[1] * (m.ndim - 1))  # noqa: E731  [num_envs, 1, ...]
        reset = jax.tree.map(lambda f, m: jnp.where(starts(m), f, m), fresh, memory)
        return jax.vmap(policy.step)(reset, obs, keys)

    return fresh, act


@struct.dataclass
class TimeStep:
    """What one ``step`` returns (each field gains a leading axis per ``vmap``)."""

    obs: Array  # the observation to act on next (after auto-reset: the next episode's first)
    reward: Array  # float32 []
    terminated: Array  # bool []: the MDP ended; do not bootstrap
    truncated: Array  # bool []: cut by a time limit; bootstrap from final_obs
    final_obs: Array  # the observation the step really reached

    @property
    def done(self) -> Array:
        """The episode ended, for either reason."""
        return jnp.logical_or(self.terminated, self.truncated)


@dataclass(frozen=True)
class Discrete:
    """Actions or observations ``0 .. n-1``."""

    n: int
    shape: tuple[int, ...] = ()
    dtype: Any = jnp.int32

    def sample(self, key: Array) -> Array:
        return jax.random.randint(key, self.shape, 0, self.n, dtype=self.dtype)

    def contains(self, x: Any) -> bool:
        x = np.asarray(x)
        return bool(x.shape == self.shape and np.issubdtype(x.dtype, np.integer) and 0 <= x < self.n)

    def __str__(self) -> str:
        return f"Discrete({self.n})"


@dataclass(frozen=True)
class Box:
    """Real vectors bounded elementwise by ``low`` and ``high`` (which may be infinite)."""

    low: Any
    high: Any
    shape: tuple[int, ...]
    dtype: Any = jnp.float32

    def sample(self, key: Array) -> Array:
        low = jnp.broadcast_to(jnp.asarray(self.low, jnp.float32), self.shape)
        high = jnp.broadcast_to(jnp.asarray(self.high, jnp.float32), self.shape)
        low, high = jnp.maximum(low, -1e6), jnp.minimum(high, 1e6)  # sample unbounded dims finitely
        return jax.random.uniform(key, self.shape, jnp.float32, low, high).astype(self.dtype)

    def contains(self, x: Any) -> bool:
        x = np.asarray(x)
        return bool(x.shape == self.shape and np.all(x >= self.low) and np.all(x <= self.high))

    def __str__(self) -> str:
        low, high = _bounds_str(self.low, self.shape), _bounds_str(self.high, self.shape)
        return f"Box(shape={self.shape}, low={low}, high={high})"


def _bounds_str(bound: Any, shape: tuple[int, ...]) -> str:
    """One number where all entries agree, each entry for small boxes (CartPole's), else the range."""
    bound = np.broadcast_to(np.asarray(bound, np.float64), shape)
    if bound.size == 0 or np.all(bound == bound.flat[0]):
        return f"{bound.flat[0]:.3g}" if bound.size else "[]"
    if bound.size <= 8:
        return "[" + ", ".join(f"{value:.3g}" for value in bound.flat) + "]"
    return f"{np.min(bound):.3g}..{np.max(bound):.3g}"


# Random draws for resets that run on every batched step (the auto-reset computes a fresh start for
# every env, every step, so their cost shows in steps/s): CartPole's and the vacuum's.


def uniform4(key: jax.Array, low: float, high: float) -> jax.Array:
    """Four float32 values uniform in ``[low, high)`` ``[4]``, from two Threefry-2x32 hashes of ``key``.

    Exactly what ``jax.random.uniform(key, (4,), float32, low, high)`` draws with non-partitionable
    Threefry (``jax.threefry_partitionable(False)``): the hash of counters (0, 2) and (1, 3), 23
    random mantissa bits per value. Keys of other PRNG implementations go to ``jax.random.uniform``.
    """
    if jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        if str(jax.random.key_impl(key)) != "threefry2x32":
            return jax.random.uniform(key, (4,), jnp.float32, low, high)
        key = jax.random.key_data(key)
    elif key.shape != (2,):  # a raw key of another implementation
        return jax.random.uniform(key, (4,), jnp.float32, low, high)
    bits_0, bits_2 = threefry2x32(key[0], key[1], jnp.uint32(0), jnp.uint32(2))
    bits_1, bits_3 = threefry2x32(key[0], key[1], jnp.uint32(1), jnp.uint32(3))
    bits = jnp.stack([bits_0, bits_1, bits_2, bits_3])
    unit = jax.lax.bitcast_convert_type((bits >> 9) | jnp.uint32(0x3F800000), jnp.float32) - 1.0  # [0, 1)
    return jnp.maximum(low, unit * (high - low) + low)


_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


@jax.jit
def threefry2x32(
    key_0: jax.Array, key_1: jax.Array, x_0: jax.Array, x_1: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The Threefry-2x32 hash (Salmon et al. 2011, 20 rounds), unrolled with constant rotations.

    Bit for bit ``jax.extend.random.threefry_2x32``, whose CPU lowering loops over its five
    four-round blocks with the rotation amounts as loop data; unrolled, XLA fuses the 20 rounds into
    one elementwise kernel (CartPole's batched ``step`` ~1.4x faster at 8,192 envs, measured). Jitted,
    its ~120 operations are traced once a process and XLA inlines the call into each program (the
    same fused kernels): compiled programs on CartPole trace and lower ~25 % faster (medians of 9
    interleaved builds, AMD EPYC Zen 3: PPO 0.98 s, not 1.29 s; DQN 1.35 s, not 1.82 s).
    """
    key_2 = key_0 ^ key_1 ^ jnp.uint32(0x1BD11BDA)
    schedule = (key_0, key_1, key_2)
    x_0, x_1 = x_0 + key_0, x_1 + key_1
    for block in range(5):
        for rotation in _ROTATIONS[block % 2]:
            x_0 = x_0 + x_1
            x_1 = (x_1 << jnp.uint32(rotation)) | (x_1 >> jnp.uint32(32 - rotation))
            x_1 = x_1 ^ x_0
        x_0 = x_0 + schedule[(block + 1) % 3]
        x_1 = x_1 + schedule[(block + 2) % 3] + jnp.uint32(block + 1)
    return x_0, x_1


class Environment(abc.ABC):
    """Base of agentax's JAX environments: subclasses write ``reset_env`` and ``step_env``.

    ``step_env`` returns ``(TimeStep, state)`` with ``obs == final_obs``; ``step`` adds the
    auto-reset. ``params`` defaults to ``default_params()`` when left out.
    """

    id: str = "Environment"

    @abc.abstractmethod
    def default_params(self) -> EnvParams: ...

    @abc.abstractmethod
    def reset_env(self, key: Array, params: EnvParams) -> tuple[Array, EnvState]: ...

    @abc.abstractmethod
    def step_env(
        self, key: Array, state: EnvState, action: Array, params: EnvParams
    ) -> tuple[TimeStep, EnvState]: ...

    @abc.abstractmethod
    def observation_space(self, params: EnvParams | None = None) -> Discrete | Box: ...

    @abc.abstractmethod
    def action_space(self, params: EnvParams | None = None) -> Discrete | Box: ...

    def reset(self, key: Array, params: EnvParams | None = None) -> tuple[Array, EnvState]:
        return self.reset_env(key, self.default_params() if params is None else params)

    def step(
        self, key: Array, state: EnvState, action: Array, params: EnvParams | None = None
    ) -> tuple[TimeStep, EnvState]:
        params = self.default_params() if params is None else params
        step_key, reset_key = jax.random.split(key)
        ts, next_state = self.step_env(step_key, state, action, params)
        reset_obs, reset_state = self.reset_env(reset_key, params)
        done = ts.done
        state = jax.tree.map(lambda r, s: jnp.where(done, r, s), reset_state, next_state)
        obs = jax.tree.map(lambda r, s: jnp.where(done, r, s), reset_obs, ts.obs)
        return ts.replace(obs=obs, final_obs=ts.obs), state

    def render_frame(self, state: EnvState, params: EnvParams | None = None) -> np.ndarray:
        """An RGB image ``[H, W, 3]`` uint8 of ``state`` (for GIFs and Gymnasium's ``rgb_array``)."""
        raise TypeError(f"{self.id} has no renderer")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.id!r})"


@partial(jax.jit, static_argnums=(0, 1, 3))
def rollout(env: Environment, policy: Policy, key: Array, num_steps: int, params: EnvParams):
    """Play ``num_steps`` steps from a reset without auto-reset, keeping every state.

    Returns ``(states [num_steps + 1, ...], rewards [num_steps], done [num_steps])``; steps after
    the first ``done`` belong to no episode and are to be cut off.
    """
    reset_key, key = jax.random.split(key)
    obs, state = env.reset(reset_key, params)

    def body(carry, step_key):
        obs, state = carry
        act_key, env_key = jax.random.split(step_key)
        ts, next_state = env.step_env(env_key, state, policy(obs, act_key), params)
        return (ts.obs, next_state), (next_state, ts.reward, ts.done)

    _, (states, rewards, done) = jax.lax.scan(body, (obs, state), jax.random.split(key, num_steps))
    states = jax.tree.map(lambda first, rest: jnp.concatenate([first[None], rest]), state, states)
    return states, rewards, done


def episode_returns(
    env: Environment,
    policy: Policy | RecurrentPolicy,
    key: Array,
    num_episodes: int,
    env_params: EnvParams | None = None,
) -> tuple[Array, Array]:
    """Play ``num_episodes`` episodes side by side (with auto-reset) until each has ended once.

    Returns ``(returns, lengths)``, each ``[num_episodes]``. ``policy(obs, key) -> action`` acts on
    one observation, or is a :class:`RecurrentPolicy`, its memory carried through each episode from
    ``initial()``. Jittable (``env``, ``policy`` and ``num_episodes`` static).
    """
    params = env.default_params() if env_params is None else env_params
    reset_key, key = jax.random.split(key)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(reset_key, num_episodes), params)
    zeros = jnp.zeros(num_episodes, jnp.float32)
    alive = jnp.ones(num_episodes, bool)
    memory, act = batched_policy(policy, num_episodes)
    first = jnp.zeros(num_episodes, bool)  # each slot plays one counted episode: no reset inside it

    def body(carry):
        obs, state, returns, lengths, alive, key, memory = carry
        key, act_key, step_key = jax.random.split(key, 3)
        memory, actions = act(memory, obs, jax.random.split(act_key, num_episodes), first)
        ts, state = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
            jax.random.split(step_key, num_episodes), state, actions, params
        )
        returns = returns + ts.reward * alive
        lengths = lengths + alive
        alive = alive & ~ts.done
        return ts.obs, state, returns, lengths, alive, key, memory

    carry = (obs, state, zeros, zeros.astype(jnp.int32), alive, key, memory)
    _, _, returns, lengths, _, _, _ = jax.lax.while_loop(lambda c: c[4].any(), body, carry)
    return returns, lengths
