"""CartPole in JAX, step for step equal to Gymnasium's ``CartPole-v0`` / ``CartPole-v1``.

Same constants, the same explicit-Euler integration, the same termination thresholds, the same
uniform(-0.05, 0.05) initial state, reward 1 on every step (the terminal one included), and the
time limit as a separate ``truncated`` flag: 200 steps for v0, 500 for v1. Gymnasium integrates
in float64 and returns float32 observations; this integrates in float32, so one step from the same
state agrees to float32 rounding (tests/test_cartpole.py checks it against Gymnasium itself).

Speed (benchmarks/bench_envs.py): the auto-reset of a batched ``step`` draws a fresh start for every
env on every step, so the random draws, not the physics, set the pace. Two things keep them cheap,
without changing any distribution: the dynamics are deterministic, so ``step`` hands its whole key
to the reset instead of splitting it (~1.3x at 8,192 envs, measured); and the four start values
come from two Threefry hashes (``core.uniform4``) where ``jax.random.uniform(key, (4,))`` spends
four, computed by an unrolled hash that XLA fuses (``core.threefry2x32``; together ~1.8x).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.envs.core import Box, Discrete, Environment, TimeStep, uniform4
from agentax.envs.core import threefry2x32 as threefry2x32  # re-exported: envs/vacuum.py imports it from here


@struct.dataclass
class CartPoleParams:
    gravity: float = 9.8
    masscart: float = 1.0
    masspole: float = 0.1
    length: float = 0.5  # half the pole's length
    force_mag: float = 10.0
    tau: float = 0.02  # seconds between state updates
    theta_threshold_radians: float = 12 * 2 * math.pi / 360
    x_threshold: float = 2.4
    max_steps_in_episode: int = 500


@struct.dataclass
class CartPoleState:
    x: jax.Array
    x_dot: jax.Array
    theta: jax.Array
    theta_dot: jax.Array
    time: jax.Array  # steps taken in this episode


class CartPole(Environment):
    """Push a cart left (0) or right (1) to keep its pole upright.

    Observation ``[4]`` float32: cart position, cart velocity, pole angle, pole angular velocity.
    """

    def __init__(
        self, max_steps_in_episode: int = 500, id: str = "CartPole-v1", reward_threshold: float = 475.0
    ):
        self.max_steps_in_episode = max_steps_in_episode
        self.id = id
        self.reward_threshold = reward_threshold

    def default_params(self) -> CartPoleParams:
        return CartPoleParams(max_steps_in_episode=self.max_steps_in_episode)

    def reset_env(self, key: jax.Array, params: CartPoleParams) -> tuple[jax.Array, CartPoleState]:
        x, x_dot, theta, theta_dot = uniform4(key, -0.05, 0.05)
        state = CartPoleState(x, x_dot, theta, theta_dot, jnp.int32(0))
        return self.get_obs(state), state

    def step(
        self, key: jax.Array, state: CartPoleState, action: jax.Array, params: CartPoleParams | None = None
    ) -> tuple[TimeStep, CartPoleState]:
        """``Environment.step`` (auto-reset) without its key split: ``step_env`` draws nothing."""
        params = self.default_params() if params is None else params
        ts, next_state = self.step_env(key, state, action, params)
        _, reset_state = self.reset_env(key, params)
        state = jax.tree.map(lambda r, s: jnp.where(ts.done, r, s), reset_state, next_state)
        return ts.replace(obs=self.get_obs(state)), state

    def step_env(
        self, key: jax.Array, state: CartPoleState, action: jax.Array, params: CartPoleParams
    ) -> tuple[TimeStep, CartPoleState]:
        total_mass = params.masspole + params.masscart
        polemass_length = params.masspole * params.length
        force = jnp.where(action == 1, params.force_mag, -params.force_mag)
        costheta, sintheta = jnp.cos(state.theta), jnp.sin(state.theta)
        temp = (force + polemass_length * state.theta_dot**2 * sintheta) / total_mass
        thetaacc = (params.gravity * sintheta - costheta * temp) / (
            params.length * (4.0 / 3.0 - params.masspole * costheta**2 / total_mass)
        )
        xacc = temp - polemass_length * thetaacc * costheta / total_mass
        state = CartPoleState(
            x=state.x + params.tau * state.x_dot,
            x_dot=state.x_dot + params.tau * xacc,
            theta=state.theta + params.tau * state.theta_dot,
            theta_dot=state.theta_dot + params.tau * thetaacc,
            time=state.time + 1,
        )
        terminated = (
            (state.x < -params.x_threshold)
            | (state.x > params.x_threshold)
            | (state.theta < -params.theta_threshold_radians)
            | (state.theta > params.theta_threshold_radians)
        )
        truncated = state.time >= params.max_steps_in_episode
        obs = self.get_obs(state)
        return TimeStep(obs, jnp.float32(1.0), terminated, truncated, obs), state

    @staticmethod
    def get_obs(state: CartPoleState) -> jax.Array:
        return jnp.stack([state.x, state.x_dot, state.theta, state.theta_dot]).astype(jnp.float32)

    def observation_space(self, params: CartPoleParams | None = None) -> Box:
        params = self.default_params() if params is None else params
        high = np.array(  # Gymnasium's bounds: the velocities are unbounded
            [params.x_threshold * 2, np.inf, params.theta_threshold_radians * 2, np.inf], dtype=np.float32
        )
        return Box(-high, high, (4,), jnp.float32)

    def action_space(self, params: CartPoleParams | None = None) -> Discrete:
        return Discrete(2)

    def render_frame(self, state: CartPoleState, params: CartPoleParams | None = None) -> np.ndarray:
        """The cart and its pole ``[400, 600, 3]`` uint8, drawn to Gymnasium's scale and colours."""
        params = self.default_params() if params is None else params
        return draw_cartpole(
            float(state.x), float(state.theta), float(params.x_threshold), float(params.length)
        )


class CartPoleNoVel(CartPole):
    """CartPole with its velocities hidden (RL Zoo's ``CartPoleNoVel``, a partially observed task):
    observation ``[2]`` float32, cart position and pole angle, equal to :class:`CartPole`'s positions
    step for step. A policy must infer the velocities from what it saw before: a task for memory."""

    def __init__(
        self, max_steps_in_episode: int = 500, id: str = "CartPoleNoVel-v1", reward_threshold: float = 475.0
    ):
        super().__init__(max_steps_in_episode, id, reward_threshold)

    @staticmethod
    def get_obs(state: CartPoleState) -> jax.Array:
        return jnp.stack([state.x, state.theta]).astype(jnp.float32)

    def observation_space(self, params: CartPoleParams | None = None) -> Box:
        params = self.default_params() if params is None else params
        high = np.array([params.x_threshold * 2, params.theta_threshold_radians * 2], dtype=np.float32)
        return Box(-high, high, (2,), jnp.float32)


def draw_cartpole(x: float, theta: float, x_threshold: float, length: float, width: int = 600) -> np.ndarray:
    """The cart at ``x`` metres, its pole at ``theta`` radians (positive: leaning right), as Gymnasium."""
    height, scale = width * 2 // 3, width / (2 * x_threshold)
    frame = np.full((height, width, 3), 255, np.uint8)
    track_row, cart_col = height - 100, x * scale + width / 2
    frame[track_row, :] = 0
    top, left = track_row - 15, int(round(cart_col - 25))
    frame[top : track_row + 15, max(left, 0) : max(left + 50, 0)] = 0  # the cart, 50 x 30 pixels
    axle = np.array([top + 7.5, cart_col])  # (row, column)
    tip = axle + 2 * length * scale * np.array([-math.cos(theta), math.sin(theta)])
    low = np.floor(np.minimum(axle, tip) - 6).astype(int).clip(0)
    high = np.ceil(np.maximum(axle, tip) + 6).astype(int).clip(0, [height, width])
    rows, cols = np.mgrid[low[0] : high[0], low[1] : high[1]] + 0.5
    pixels = np.stack([rows, cols], axis=-1)  # (h, w, 2)
    along = np.clip((pixels - axle) @ (tip - axle) / np.sum((tip - axle) ** 2), 0.0, 1.0)
    distance = np.linalg.norm(pixels - axle - along[..., None] * (tip - axle), axis=-1)
    patch = frame[low[0] : high[0], low[1] : high[1]]
    patch[distance <= 5] = (202, 152, 101)  # the pole, 10 pixels wide
    patch[np.linalg.norm(pixels - axle, axis=-1) <= 5] = (129, 132, 203)  # the axle
    return frame


def cartpole_v0() -> CartPole:
    return CartPole(max_steps_in_episode=200, id="CartPole-v0", reward_threshold=195.0)


def cartpole_v1() -> CartPole:
    return CartPole(max_steps_in_episode=500, id="CartPole-v1", reward_threshold=475.0)
