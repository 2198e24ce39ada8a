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
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

Array = jax.Array
EnvState = Any
EnvParams = Any


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
