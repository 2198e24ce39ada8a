"""Pendulum-v1 and MountainCarContinuous-v0 in JAX, step for step equal to Gymnasium's.

The same constants, the same explicit integration and clipping, the same uniform starts, and the
time limit as a separate ``truncated`` flag (200 and 999 steps). Gymnasium integrates in float64
and returns float32 observations; these integrate in float32, so one step from the same state
agrees to float32 rounding (tests/test_continuous_envs.py checks them against Gymnasium itself).

Actions are ``[1]`` float32 in the env's own units (torque in [-2, 2], force in [-1, 1]); agents
that act in [-1, 1] have them rescaled by ``agents.protocol.scale_action``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.envs.core import Box, Environment, TimeStep


@struct.dataclass
class PendulumParams:
    max_speed: float = 8.0
    max_torque: float = 2.0
    dt: float = 0.05
    gravity: float = 10.0
    mass: float = 1.0
    length: float = 1.0
    max_steps_in_episode: int = 200


@struct.dataclass
class PendulumState:
    theta: jax.Array  # radians, 0 upright
    theta_dot: jax.Array
    time: jax.Array


def angle_normalize(x: jax.Array) -> jax.Array:
    """``x`` radians wrapped into [-π, π)."""
    return (x + jnp.pi) % (2 * jnp.pi) - jnp.pi


class Pendulum(Environment):
    """Swing a pendulum up and hold it there with a torque ``[1]`` in [-2, 2].

    Observation ``[3]`` float32: cos θ, sin θ, θ̇. Reward ``-(θ² + 0.1 θ̇² + 0.001 u²)`` (θ wrapped,
    u clipped), in [-16.27, 0]; no termination, truncation after 200 steps.
    """

    id = "Pendulum-v1"
    reward_threshold = None

    def default_params(self) -> PendulumParams:
        return PendulumParams()

    def reset_env(self, key: jax.Array, params: PendulumParams) -> tuple[jax.Array, PendulumState]:
        high = jnp.array([jnp.pi, 1.0], jnp.float32)
        theta, theta_dot = jax.random.uniform(key, (2,), jnp.float32, -high, high)
        state = PendulumState(theta, theta_dot, jnp.int32(0))
        return self.get_obs(state), state

    def step_env(
        self, key: jax.Array, state: PendulumState, action: jax.Array, params: PendulumParams
    ) -> tuple[TimeStep, PendulumState]:
        u = jnp.clip(jnp.reshape(action, (-1,))[0], -params.max_torque, params.max_torque)
        cost = angle_normalize(state.theta) ** 2 + 0.1 * state.theta_dot**2 + 0.001 * u**2
        gravity_term = 3 * params.gravity / (2 * params.length) * jnp.sin(state.theta)
        torque_term = 3.0 / (params.mass * params.length**2) * u
        theta_dot = state.theta_dot + (gravity_term + torque_term) * params.dt
        theta_dot = jnp.clip(theta_dot, -params.max_speed, params.max_speed)
        state = PendulumState(state.theta + theta_dot * params.dt, theta_dot, state.time + 1)
        obs = self.get_obs(state)
        truncated = state.time >= params.max_steps_in_episode
        return TimeStep(obs, (-cost).astype(jnp.float32), jnp.bool_(False), truncated, obs), state

    @staticmethod
    def get_obs(state: PendulumState) -> jax.Array:
        return jnp.stack([jnp.cos(state.theta), jnp.sin(state.theta), state.theta_dot]).astype(jnp.float32)

    def observation_space(self, params: PendulumParams | None = None) -> Box:
        params = self.default_params() if params is None else params
        high = np.array([1.0, 1.0, params.max_speed], np.float32)
        return Box(-high, high, (3,), jnp.float32)

    def action_space(self, params: PendulumParams | None = None) -> Box:
        params = self.default_params() if params is None else params
        high = np.full(1, params.max_torque, np.float32)
        return Box(-high, high, (1,), jnp.float32)


class PendulumNoVel(Pendulum):
    """Pendulum with its angular velocity hidden (RL Zoo's ``PendulumNoVel``, a partially observed
    task): observation ``[2]`` float32, cos θ and sin θ, equal to :class:`Pendulum`'s first two step
    for step. A policy must infer θ̇ from the angles it saw before: a task for memory."""

    id = "PendulumNoVel-v1"

    @staticmethod
    def get_obs(state: PendulumState) -> jax.Array:
        return jnp.stack([jnp.cos(state.theta), jnp.sin(state.theta)]).astype(jnp.float32)

    def observation_space(self, params: PendulumParams | None = None) -> Box:
        return Box(-np.ones(2, np.float32), np.ones(2, np.float32), (2,), jnp.float32)


@struct.dataclass
class MountainCarParams:
    min_action: float = -1.0
    max_action: float = 1.0
    min_position: float = -1.2
    max_position: float = 0.6
    max_speed: float = 0.07
    goal_position: float = 0.45
    goal_velocity: float = 0.0
    power: float = 0.0015
    max_steps_in_episode: int = 999


@struct.dataclass
class MountainCarState:
    position: jax.Array
    velocity: jax.Array
    time: jax.Array


class MountainCarContinuous(Environment):
    """Drive an underpowered car up the right hill with a force ``[1]`` in [-1, 1].

    Observation ``[2]`` float32: position, velocity. Reward 100 on reaching the flag (which ends
    the episode) minus ``0.1 a²`` every step (``a`` the action as given, before clipping);
    truncation after 999 steps.
    """

    id = "MountainCarContinuous-v0"
    reward_threshold = 90.0

    def default_params(self) -> MountainCarParams:
        return MountainCarParams()

    def reset_env(self, key: jax.Array, params: MountainCarParams) -> tuple[jax.Array, MountainCarState]:
        position = jax.random.uniform(key, (), jnp.float32, -0.6, -0.4)
        state = MountainCarState(position, jnp.float32(0.0), jnp.int32(0))
        return self.get_obs(state), state

    def step_env(
        self, key: jax.Array, state: MountainCarState, action: jax.Array, params: MountainCarParams
    ) -> tuple[TimeStep, MountainCarState]:
        a = jnp.reshape(action, (-1,))[0].astype(jnp.float32)
        force = jnp.clip(a, params.min_action, params.max_action)
        velocity = state.velocity + force * params.power - 0.0025 * jnp.cos(3 * state.position)
        velocity = jnp.clip(velocity, -params.max_speed, params.max_speed)
        position = jnp.clip(state.position + velocity, params.min_position, params.max_position)
        velocity = jnp.where((position == params.min_position) & (velocity < 0), 0.0, velocity)
        terminated = (position >= params.goal_position) & (velocity >= params.goal_velocity)
        reward = jnp.where(terminated, 100.0, 0.0) - 0.1 * a**2
        state = MountainCarState(position, velocity, state.time + 1)
        obs = self.get_obs(state)
        truncated = state.time >= params.max_steps_in_episode
        return TimeStep(obs, reward.astype(jnp.float32), terminated, truncated, obs), state

    @staticmethod
    def get_obs(state: MountainCarState) -> jax.Array:
        return jnp.stack([state.position, state.velocity]).astype(jnp.float32)

    def observation_space(self, params: MountainCarParams | None = None) -> Box:
        params = self.default_params() if params is None else params
        low = np.array([params.min_position, -params.max_speed], np.float32)
        high = np.array([params.max_position, params.max_speed], np.float32)
        return Box(low, high, (2,), jnp.float32)

    def action_space(self, params: MountainCarParams | None = None) -> Box:
        params = self.default_params() if params is None else params
        return Box(np.full(1, params.min_action, np.float32), np.full(1, params.max_action, np.float32), (1,))
