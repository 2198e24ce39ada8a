"""gymnax's JAX envs on agentax's env protocol: ``agentax.make("gymnax/Breakout-MinAtar")``.

gymnax (Lange, 2022; Apache-2.0) is the JAX RL world's env suite: MinAtar's Asterix, Breakout,
Freeway, Seaquest and SpaceInvaders, classic control, bsuite, misc. :class:`GymnaxEnv` adapts one
of them onto :class:`~agentax.envs.core.Environment`: ``reset_env``/``step_env`` are gymnax's
own (no auto-reset), ``terminated`` is gymnax's ``done`` of the step and ``truncated`` its time
limit (``is_truncated``), kept apart, and agentax's ``step`` adds the auto-reset with the same key
split as gymnax's ``step`` (``key_step, key_reset = split(key)``), so a step of the adapter is
gymnax's step, transition for transition (``tests/test_gymnax.py`` replays it), with
``final_obs`` its ``info["final_observation"]``.

Observations of more than one axis (MinAtar's ``[10, 10, C]`` channels) are flattened to a vector,
so every agent's MLP, every runner and every replay buffer takes them unchanged; the image's shape
stays known as :attr:`GymnaxEnv.image_shape` (and ``EnvSpec.image_shape``), so a network that wants
the image (:class:`agentax.nets.MinAtarCNN`, ``--conv-torso``) reshapes the vector back, a free
reshape inside the network. Why not hand agents the ``[10, 10, C]`` array: a 3-axis observation means
stacked uint8 Atari frames ``[C, H, W]`` to agentax's agents and replay (``nets.is_image``), and a
second image layout would have to be told apart everywhere an observation's shape is read.

**How gymnax is carried.** gymnax 1.0.1 declares ``gymnasium<1.4`` while agentax pins gymnasium
1.4.0; gymnax imports gymnasium only to convert spaces to Gymnasium's, which this adapter does not
call. So the install step (``make .venv/.installed``) installs gymnax without its declared
dependencies, beside what it really imports (jax, flax, matplotlib, seaborn, and ``six``, which it
does not declare), all in ``requirements.lock``. gymnax is imported only when a ``gymnax/`` env is
made.
"""

from __future__ import annotations

import importlib.util
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agentax.envs.core import Box, Discrete, Environment, TimeStep
from agentax.errors import UsageError

PREFIX = "gymnax/"
IDS = (
    "Asterix-MinAtar",
    "Breakout-MinAtar",
    "Freeway-MinAtar",
    "Seaquest-MinAtar",
    "SpaceInvaders-MinAtar",
    "CartPole-v1",
    "Acrobot-v1",
    "MountainCar-v0",
    "Pendulum-v1",
    "MountainCarContinuous-v0",
    "Catch-bsuite",
    "DeepSea-bsuite",
    "MemoryChain-bsuite",
    "UmbrellaChain-bsuite",
    "DiscountingChain-bsuite",
    "FourRooms-misc",
    "MetaMaze-misc",
    "PointRobot-misc",
)
"""gymnax 1.0.1's envs that agentax offers (its bandits and image-sized envs left out)"""


def available() -> bool:
    """Whether gymnax is installed (without importing it)."""
    return importlib.util.find_spec("gymnax") is not None


class GymnaxEnv(Environment):
    """gymnax's env ``name`` (an id of :data:`IDS`) as an agentax JAX env (see the module docstring)."""

    def __init__(self, name: str):
        if not available():
            raise UsageError(f"{PREFIX}{name} needs gymnax: pip install --no-deps gymnax==1.0.1 six seaborn")
        import gymnax

        self.name, self.id = name, PREFIX + name
        self.gymnax_env, self._params = gymnax.make(name)
        space = self.gymnax_env.observation_space(self._params)
        self.image_shape: tuple[int, ...] | None = tuple(space.shape) if len(space.shape) == 3 else None
        """``[H, W, C]`` of an image observation before flattening (MinAtar: ``[10, 10, C]``), else None"""
        self._obs_shape = (int(np.prod(space.shape)),)
        self._obs_space = Box(_flat(space.low, space.shape), _flat(space.high, space.shape), self._obs_shape)

    def default_params(self) -> Any:
        return self._params

    def reset_env(self, key: jax.Array, params: Any) -> tuple[jax.Array, Any]:
        obs, state = self.gymnax_env.reset_env(key, params)
        return self._flatten(obs), state

    def step_env(self, key: jax.Array, state: Any, action: jax.Array, params: Any) -> tuple[TimeStep, Any]:
        obs, state, reward, terminated, _ = self.gymnax_env.step_env(key, state, action, params)
        truncated = self.gymnax_env.is_truncated(state, params)
        obs = self._flatten(obs)
        time_step = TimeStep(
            obs=obs,
            reward=jnp.asarray(reward, jnp.float32).reshape(()),  # Pendulum's is [1]
            terminated=jnp.asarray(terminated, bool),
            truncated=jnp.asarray(truncated, bool),
            final_obs=obs,
        )
        return time_step, state

    def observation_space(self, params: Any = None) -> Box:
        return self._obs_space

    def action_space(self, params: Any = None) -> Discrete | Box:
        space = self.gymnax_env.action_space(self._params if params is None else params)
        if hasattr(space, "n"):
            return Discrete(int(space.n))
        return Box(np.asarray(space.low), np.asarray(space.high), tuple(space.shape))

    def _flatten(self, obs: jax.Array) -> jax.Array:
        return jnp.reshape(obs, self._obs_shape).astype(jnp.float32)


def _flat(bound: Any, shape: tuple[int, ...]) -> np.ndarray:
    return np.broadcast_to(np.asarray(bound, np.float32), shape).reshape(-1)


def factories() -> dict[str, Any]:
    """``{"gymnax/ID": factory}`` for every id of :data:`IDS` when gymnax is installed, else none."""
    if not available():
        return {}
    return {PREFIX + name: (lambda name=name: GymnaxEnv(name)) for name in IDS}


__all__ = ["IDS", "PREFIX", "GymnaxEnv", "available", "factories"]
