"""Gymnasium both ways: any Gymnasium env stepped on the host, and agentax's JAX envs in Gymnasium.

``GymnasiumEnv`` wraps a Gymnasium env id, env or vector env so that agentax's host runners see
the same ``TimeStep`` fields as from a JAX env (NumPy arrays with a leading ``num_envs`` axis).
It steps a vector env in Gymnasium's ``SAME_STEP`` autoreset mode: the step that ends an episode
already returns the next episode's first observation, and the observation really reached comes
from ``info["final_obs"]`` -- exactly agentax's ``obs`` / ``final_obs`` split. (Gymnasium's default
``NEXT_STEP`` mode would spend an extra, action-ignoring step on each reset instead.)

**MuJoCo** (``HalfCheetah-v5``, ``Hopper-v5`` and Gymnasium's other ``gymnasium.envs.mujoco`` ids)
needs the ``mujoco`` package (``pip install 'agentax[mujoco]'``); without it :func:`require_mujoco`
says so in one line. Their float64 observations reach agentax as float32 (JAX's default width).

``JaxToGymnasium`` is the other way: a ``gymnasium.Env`` around an agentax JAX env, with one
compiled reset and one compiled step per env id and NumPy values out. ``register_envs`` registers
every JAX env as ``agentax/ID``, which ``import agentax`` does, so
``gymnasium.make("agentax/CartPole-v1")`` works.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from collections.abc import Callable, Mapping
from functools import cache
from types import ModuleType
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.vector import AutoresetMode

from agentax.envs import spaces
from agentax.envs.core import Box, Discrete, Environment, EnvParams, TimeStep
from agentax.errors import UsageError

NAMESPACE = "agentax"

# Gymnasium envs that install with agentax (classic control, toy text) and fit agentax's spaces.
GYMNASIUM_SELECTION = (
    "Acrobot-v1",
    "MountainCar-v0",
    "MountainCarContinuous-v0",
    "Pendulum-v1",
    "FrozenLake-v1",
    "FrozenLake8x8-v1",
    "CliffWalking-v1",
    "Taxi-v4",
)


MUJOCO_EXTRA = "pip install 'agentax[mujoco]'"


def is_mujoco_id(env_id: str) -> bool:
    """Whether ``env_id`` is one of Gymnasium's MuJoCo tasks (``HalfCheetah-v5``, ``Hopper-v5``, ...)."""
    spec = gymnasium.registry.get(env_id)
    entry = spec.entry_point if spec is not None else None
    return isinstance(entry, str) and entry.startswith("gymnasium.envs.mujoco")


# MuJoCo 4 deprecates a compiler attribute that Gymnasium 1.4's model files still use; its warning
# would print once per env made (and each parallel actor makes several).
_HARMLESS_MUJOCO_WARNING = "compiler attribute 'settotalmass' is deprecated"


def _mujoco_warning(message: str) -> None:
    if _HARMLESS_MUJOCO_WARNING not in message:
        print(f"WARNING: {message}", file=sys.stderr)


def require_mujoco(env_id: str) -> ModuleType:
    """The ``mujoco`` module for a MuJoCo task, else a one-line ``UsageError`` naming the extra.

    Installs a warning handler that drops only the ``settotalmass`` deprecation (others print as
    MuJoCo prints them)."""
    try:
        import mujoco
    except ImportError:
        raise UsageError(f"{env_id} needs MuJoCo, which is not installed: {MUJOCO_EXTRA}") from None
    except Exception as error:  # mujoco loads MUJOCO_GL's OpenGL when imported; a missing one fails
        gl = os.environ.get("MUJOCO_GL")
        raise UsageError(
            f"cannot import mujoco with MUJOCO_GL={gl} ({type(error).__name__}: {error}); "
            "unset MUJOCO_GL or choose one that is installed (egl: libegl1, osmesa: libosmesa6)"
        ) from None
    mujoco.set_mju_user_warning(_mujoco_warning)
    return mujoco


BOX2D_EXTRA = "pip install 'agentax[box2d]'"
"""What installs Box2D for Gymnasium's LunarLander, BipedalWalker and CarRacing."""

ACTION_SPACES = (
    gymnasium.spaces.Discrete,
    gymnasium.spaces.Box,
    gymnasium.spaces.MultiDiscrete,
    gymnasium.spaces.MultiBinary,
)
"""The Gymnasium action spaces agentax's agents take."""


def from_gymnasium_space(space: gymnasium.Space) -> Any:
    """agentax's space for a Gymnasium one: ``Discrete``, ``Box``, ``MultiDiscrete``, ``MultiBinary``,
    and ``Dict`` / ``Tuple`` of them; others raise ``UsageError``."""
    if isinstance(space, gymnasium.spaces.Discrete):
        if int(space.start) != 0:
            raise UsageError(f"Discrete spaces must start at 0, this one starts at {space.start}")
        return Discrete(int(space.n))
    if isinstance(space, gymnasium.spaces.Box):
        return Box(space.low, space.high, tuple(space.shape), space.dtype)
    if isinstance(space, gymnasium.spaces.MultiDiscrete):
        if np.any(space.start != 0):
            raise UsageError(f"MultiDiscrete spaces must start at 0, this one starts at {space.start}")
        return spaces.MultiDiscrete(tuple(int(n) for n in space.nvec.reshape(-1)))
    if isinstance(space, gymnasium.spaces.MultiBinary):
        return spaces.MultiBinary(int(np.prod(space.shape)))
    if isinstance(space, gymnasium.spaces.Dict):
        return spaces.Dict(tuple((key, from_gymnasium_space(sub)) for key, sub in space.spaces.items()))
    if isinstance(space, gymnasium.spaces.Tuple):
        return spaces.Tuple(tuple(from_gymnasium_space(sub) for sub in space.spaces))
    raise UsageError(f"{space} is no space agentax takes; it takes {spaces.SUPPORTED}")


def to_gymnasium_space(space: Any) -> gymnasium.Space:
    """The Gymnasium space for an agentax space (:func:`from_gymnasium_space`'s inverse)."""
    if isinstance(space, Discrete):
        return gymnasium.spaces.Discrete(space.n)
    if isinstance(space, spaces.MultiDiscrete):
        return gymnasium.spaces.MultiDiscrete(np.asarray(space.nvec))
    if isinstance(space, spaces.MultiBinary):
        return gymnasium.spaces.MultiBinary(space.n)
    if isinstance(space, spaces.Dict):
        return gymnasium.spaces.Dict({key: to_gymnasium_space(sub) for key, sub in space.spaces})
    if isinstance(space, spaces.Tuple):
        return gymnasium.spaces.Tuple(tuple(to_gymnasium_space(sub) for sub in space.spaces))
    dtype = np.dtype(space.dtype)
    low = np.broadcast_to(np.asarray(space.low, dtype), space.shape)
    high = np.broadcast_to(np.asarray(space.high, dtype), space.shape)
    return gymnasium.spaces.Box(low, high, space.shape, dtype)


class GymnasiumEnv:
    """A Gymnasium env (or ``num_envs`` copies, as a vector env) stepped on the host.

    ``env`` is a Gymnasium id (made with ``gymnasium.make_vec(id, num_envs, **make_kwargs)``), a
    ``gymnasium.Env``, or a ``gymnasium.vector.VectorEnv`` created with
    ``vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP}``. Arrays carry a leading
    ``num_envs`` axis; ``observation_space()`` / ``action_space()`` describe one sub-env, as for
    agentax's JAX envs.
    """

    def __init__(
        self, env: str | gymnasium.Env | gymnasium.vector.VectorEnv, num_envs: int = 1, **make_kwargs: Any
    ):
        if isinstance(env, str):
            self.id = env
            if is_mujoco_id(env):
                require_mujoco(env)
            try:
                env = gymnasium.make_vec(
                    env,
                    num_envs,
                    vectorization_mode="sync",
                    vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP},
                    **make_kwargs,
                )
            except gymnasium.error.DependencyNotInstalled as error:
                if "box2d" not in str(error).lower():
                    raise UsageError(f"cannot make Gymnasium env {self.id!r}: {error}") from error
                raise UsageError(f"{env} needs Box2D, which is not installed: {BOX2D_EXTRA}") from None
            except gymnasium.error.Error as error:
                raise UsageError(f"cannot make Gymnasium env {self.id!r}: {error}") from error
        elif isinstance(env, gymnasium.Env):
            single, self.id = env, env.spec.id if env.spec is not None else type(env.unwrapped).__name__
            env = gymnasium.vector.SyncVectorEnv([lambda: single], autoreset_mode=AutoresetMode.SAME_STEP)
        else:
            self.id = env.spec.id if env.spec is not None else type(env).__name__
            mode = env.metadata.get("autoreset_mode")
            if mode != AutoresetMode.SAME_STEP:
                raise UsageError(
                    f"the vector env autoresets in mode {mode}; create it with "
                    "vector_kwargs={'autoreset_mode': gymnasium.vector.AutoresetMode.SAME_STEP}"
                )
        self.vector_env: gymnasium.vector.VectorEnv = env
        self.num_envs: int = env.num_envs
        self.make_kwargs = make_kwargs
        try:
            if not isinstance(env.single_action_space, ACTION_SPACES):
                raise UsageError(
                    f"its actions {env.single_action_space} are no space agentax takes; it takes "
                    "Discrete, Box, MultiDiscrete and MultiBinary actions"
                )
            self.original_space = from_gymnasium_space(env.single_observation_space)
            self._action_space = from_gymnasium_space(env.single_action_space)
            mask = self._info_mask()
            self._mask_in_info = mask is not None
            self.layout = spaces.layout_of(self.original_space, self.id, mask)
            if self.layout is not None and self.layout.mask is not None:
                self.reset(seed=0)  # a first mask with no legal action is refused before a run starts
        except UsageError as error:
            env.close()
            reason = str(error).removeprefix(f"{self.id} ")
            raise UsageError(f"{self.id} cannot run in agentax: {reason}") from None
        self._observation_space = self.original_space
        self._obs_dtype = None  # float64 observations (MuJoCo's) are handed on as float32
        if self.layout is not None:
            self._observation_space = spaces.packed_space(self.layout)
        elif np.dtype(self._observation_space.dtype) == np.float64:
            self._obs_dtype = np.float32
            self._observation_space = dataclasses.replace(self._observation_space, dtype=np.float32)

    def _info_mask(self) -> int | None:
        """The number of actions where the env gives its legal actions as ``info["action_mask"]``
        (Gymnasium's toy-text convention; seen in the info of one reset), else None."""
        if not isinstance(self._action_space, Discrete) or (
            isinstance(self.original_space, spaces.Dict)
            and spaces.MASK_KEY in dict(self.original_space.spaces)
        ):
            return None
        _, info = self.vector_env.reset(seed=0)
        return self._action_space.n if spaces.MASK_KEY in info else None

    def observation_space(self, params: EnvParams | None = None) -> Any:
        return self._observation_space

    def action_space(self, params: EnvParams | None = None) -> Any:
        return self._action_space

    def observe(self, obs: Any, info: Mapping[str, Any]) -> np.ndarray:
        """Observations ``[num_envs, ...]`` (or one sub-env's, as its own Gymnasium env gives it) as
        agents take them: packed where there is a layout (with ``info``'s action mask where the env
        gives it there), float32 for float64 ones."""
        if self.layout is None:
            return obs if self._obs_dtype is None else obs.astype(self._obs_dtype)
        if self._mask_in_info:
            obs = {"obs": obs, spaces.MASK_KEY: info[spaces.MASK_KEY]}
        packed = self.layout.pack(obs)
        if self.layout.mask is not None:
            spaces.check_mask(self.layout.legal(packed), self.id)
        return packed

    def reset(self, seed: int | None = None) -> np.ndarray:
        """First observations ``[num_envs, *obs_shape]``; sub-env ``i`` is seeded ``seed + i``."""
        obs, info = self.vector_env.reset(seed=seed)
        return self.observe(obs, info)

    def step(self, actions: Any) -> TimeStep:
        """One step of every sub-env; ``actions: [num_envs, *action_shape]``. Ended episodes auto-reset."""
        obs, reward, terminated, truncated, info = self.vector_env.step(np.asarray(actions))
        obs = self.observe(obs, info)
        final_obs = np.array(obs)
        for i in np.flatnonzero(info.get("_final_obs", ())):
            final_obs[i] = self._final_obs(info, i)
        return TimeStep(obs, reward.astype(np.float32), terminated, truncated, final_obs)

    def _final_obs(self, info: Mapping[str, Any], i: int) -> Any:
        """Sub-env ``i``'s observation really reached, from ``info["final_obs"]`` (packed where there
        is a layout; its mask, where the env gives masks in the info, from ``info["final_info"]``,
        all legal where that has none)."""
        final = info["final_obs"][i]
        if self.layout is None:
            return final
        if self._mask_in_info:
            mask = info.get("final_info", {}).get(spaces.MASK_KEY)
            legal = np.ones(self._action_space.n, np.int8) if mask is None else mask[i]
            final = {"obs": final, spaces.MASK_KEY: legal}
        return self.layout.pack(final)

    def snapshot(self) -> tuple[list[dict[str, Any]], list[dict[str, Any]]] | None:
        """Where every sub-env is, when each is an agentax JAX env (:class:`JaxToGymnasium`, in a
        vector env of this process): each one's JAX state and key (arrays) and the state of its
        NumPy generator, which draws the key of each next episode (JSON-able); else None (the state
        of a Gymnasium env cannot be saved in general)."""
        envs = [env.unwrapped for env in getattr(self.vector_env, "envs", [None])]
        if not all(isinstance(env, JaxToGymnasium) and env.state is not None for env in envs):
            return None
        arrays = [{"state": env.state, "key": env._key} for env in envs]
        return arrays, [env.np_random.bit_generator.state for env in envs]

    def restore(self, arrays: list[dict[str, Any]], generators: list[dict[str, Any]]) -> None:
        """Put every sub-env where :meth:`snapshot` found it (the vector env reset before)."""
        for env, saved, generator in zip(self.vector_env.envs, arrays, generators, strict=True):
            env = env.unwrapped
            env.state, env._key = jax.tree.map(jnp.asarray, saved["state"]), saved["key"]
            env.np_random.bit_generator.state = generator

    def close(self) -> None:
        self.vector_env.close()

    def __repr__(self) -> str:
        return f"GymnasiumEnv({self.id!r}, num_envs={self.num_envs})"


_REGISTERED: dict[str, Callable[[], Environment]] = {}
"""The JAX envs :func:`register_envs` registered in Gymnasium, by agentax id."""


@cache
def _compiled_by_id(env_id: str) -> tuple[Environment, EnvParams, Callable, Callable]:
    if env_id not in _REGISTERED:
        raise UsageError(f"unknown JAX env {env_id!r}; choose from {', '.join(_REGISTERED)}")
    env = spaces.packed(_REGISTERED[env_id]())
    return _compile(env, env.default_params())


def _compile(env: Environment, params: EnvParams) -> tuple[Environment, EnvParams, Callable, Callable]:
    """``env`` and ``params`` with a jitted ``reset(key) -> (obs, state, key)`` and a jitted
    ``step(key, state, action) -> (values, state, key)``, ``params`` built in.

    ``step`` does not auto-reset (Gymnasium's caller resets) and packs obs, reward, terminated and
    truncated into one float32 vector, so that one transfer brings them to the host (with params
    built in, ~4x the steps per second of four transfers and params passed in).
    """

    @jax.jit
    def reset(key):
        key, reset_key = jax.random.split(key)
        obs, state = env.reset(reset_key, params)
        return obs, state, key

    @jax.jit
    def step(key, state, action):
        key, step_key = jax.random.split(key)
        ts, state = env.step_env(step_key, state, action, params)
        flags = jnp.stack([ts.reward, ts.terminated, ts.truncated]).astype(jnp.float32)
        return jnp.concatenate([ts.obs.astype(jnp.float32).reshape(-1), flags]), state, key

    return env, params, reset, step


def frames_per_second(params: EnvParams) -> float:
    """Real time for an env with a step duration ``params.tau`` in seconds (CartPole: 50), else 30."""
    return 1.0 / float(params.tau) if hasattr(params, "tau") else 30.0


def _has_renderer(env: Environment) -> bool:
    env = env.env if isinstance(env, spaces.Packed) else env
    return type(env).render_frame is not Environment.render_frame


def gymnasium_values(values: Any, space: gymnasium.Space) -> Any:
    """NumPy values (a dict or tuple of them for Dict and Tuple spaces) as ``space`` holds them:
    an ``int`` for Discrete, else arrays of the space's (each leaf's) shape and dtype."""
    if isinstance(space, gymnasium.spaces.Discrete):
        return int(np.asarray(values).reshape(()))
    if isinstance(space, gymnasium.spaces.Dict):
        return {key: gymnasium_values(values[key], sub) for key, sub in space.spaces.items()}
    if isinstance(space, gymnasium.spaces.Tuple):
        return tuple(gymnasium_values(value, sub) for value, sub in zip(values, space.spaces, strict=True))
    return np.asarray(values).astype(space.dtype).reshape(space.shape)


class JaxToGymnasium(gymnasium.Env):
    """An agentax JAX env as a ``gymnasium.Env``: ``reset(seed=...)``, the five-value ``step``, NumPy out.

    ``env`` is a JAX env id (with default params, its compiled functions are shared by all
    instances) or an ``Environment``. ``reset(seed=s)`` seeds Gymnasium's ``np_random``, which
    draws the JAX key of the episode, so equal seeds give equal episodes. The env's own time limit
    sets ``truncated``. Composite observations travel packed (:func:`agentax.envs.spaces.packed`)
    and reach Gymnasium as the env gives them: its own Dict or Tuple space, a dict or tuple of
    arrays of each leaf's dtype.
    """

    metadata: Mapping[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self, env: str | Environment, render_mode: str | None = None, params: EnvParams | None = None
    ):
        if isinstance(env, str) and params is None:
            self.env, self.params, self._reset_fn, self._step_fn = _compiled_by_id(env)
        else:
            env = _compiled_by_id(env)[0] if isinstance(env, str) else spaces.packed(env)
            params = env.default_params() if params is None else params
            self.env, self.params, self._reset_fn, self._step_fn = _compile(env, params)
        self.metadata = {
            "render_modes": ["rgb_array"] if _has_renderer(self.env) else [],
            "render_fps": frames_per_second(self.params),
        }
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise UsageError(
                f"render_mode {render_mode!r} not supported; choose from {self.metadata['render_modes']}"
            )
        self.render_mode = render_mode
        self.layout = getattr(self.env, "layout", None)
        own_space = self.env.original_space if self.layout else self.env.observation_space(self.params)
        self.observation_space = to_gymnasium_space(own_space)
        self.action_space = to_gymnasium_space(self.env.action_space(self.params))
        self.state = None
        self._key = None

    def _obs(self, obs: np.ndarray) -> Any:
        """The observation as Gymnasium's space holds it, from the (packed) vector the program gave."""
        values = obs if self.layout is None else self.layout.unpack(obs)
        return gymnasium_values(values, self.observation_space)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        key = jax.random.key(int(self.np_random.integers(0, 2**32)))
        obs, self.state, self._key = self._reset_fn(key)
        return self._obs(np.asarray(obs)), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        values, self.state, self._key = self._step_fn(self._key, self.state, action)
        values = np.asarray(values)
        reward, terminated, truncated = values[-3:]
        return self._obs(values[:-3]), float(reward), bool(terminated), bool(truncated), {}

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array" or self.state is None:
            return None
        return np.asarray(self.env.render_frame(self.state, self.params))


def register_envs(jax_envs: Mapping[str, Callable[[], Environment]]) -> None:
    """Register each JAX env as Gymnasium id ``agentax/ID`` (ids already registered are kept)."""
    _REGISTERED.update(jax_envs)
    for env_id in jax_envs:
        gym_id = f"{NAMESPACE}/{env_id}"
        if gym_id not in gymnasium.registry:
            gymnasium.register(gym_id, entry_point="agentax.envs.gym:JaxToGymnasium", kwargs={"env": env_id})


def is_gymnasium_id(env_id: str) -> bool:
    return env_id in gymnasium.registry or ":" in env_id
