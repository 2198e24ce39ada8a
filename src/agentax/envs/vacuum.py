"""The lecture's robot vacuum cleaner: pick up as much dust as possible in 30 minutes.

The model (every number is a field of :class:`VacuumParams`):

* **Room**: a square of ``room_size`` = 5 m, its floor a ``grid_size`` × ``grid_size`` = 20 × 20 grid of
  0.25 m cells, each holding ``dust_per_cell`` = 1 unit of dust at the start (400 units in all).
* **Robot**: a disc of radius 0.17 m whose centre starts at a uniformly random point of the room
  (keeping the disc inside) with a uniformly random heading. It drives at 0.25 m/s.
* **Time**: one step is ``step_seconds`` = 2 s; an episode is ``episode_seconds`` = 30 min, i.e.
  900 steps, ended by truncation (nothing terminates it).
* **Action** ``[2]`` float32: ``[forward, turn]``. ``forward > 0.5`` drives straight ahead for the
  whole step (0.5 m); otherwise the robot rotates in place by ``turn`` radians (clipped to
  [−π, π]), which also takes the whole step.
* **Walls**: the robot stops where its bumper touches a wall and stays there (it does not bounce or
  slide) until it turns away; the observation's bump flag is then 1.
* **Cleaning**: the suction is always on: during a step it empties the cells under its centre at
  ``cleaning_points`` = 2 evenly spaced points of its path (the middle and the end of a move, or
  the cell it turns in). **Reward** = the dust picked up in this step, so the return is the dust
  collected in 30 minutes, and picked + remaining = initial dust always.
* **Observation** ``[5]`` float32: what the robot senses: ``[x / room_size, y / room_size,
  cos(heading), sin(heading), bumped]``. The lecture's (p, r) policy ignores it.

The state keeps the floor's dirty cells as bits (:func:`pack_cells`, :func:`unpack_cells`).

``Vacuum.render_frame`` draws the room (dust, clean floor, robot and heading); :func:`render_path`
draws a whole episode's path (from ``Vacuum.trajectory``) over the floor it left behind. The lecture's
(p, r) policy and the search over it live in :mod:`agentax.search.settings` (``vacuum_policy``,
``evaluate_settings``).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.envs.core import Box, Environment, Policy, TimeStep, rollout, uniform4


@struct.dataclass
class VacuumParams:
    room_size: float = 5.0  # metres, the side of the square room
    robot_radius: float = 0.17  # metres
    speed: float = 0.25  # metres per second, when driving forward
    step_seconds: float = 2.0  # simulated seconds per step
    episode_seconds: float = 1800.0  # 30 simulated minutes
    dust_per_cell: float = 1.0  # dust on each cell at the start
    grid_size: int = struct.field(pytree_node=False, default=20)  # cells per side of the room
    cleaning_points: int = struct.field(pytree_node=False, default=2)  # path points vacuumed per step

    @property
    def cell_size(self):
        return self.room_size / self.grid_size

    @property
    def max_steps_in_episode(self):
        """Steps per episode: ``episode_seconds / step_seconds`` (900 by default)."""
        return jnp.round(jnp.asarray(self.episode_seconds) / self.step_seconds).astype(jnp.int32)


@struct.dataclass
class VacuumState:
    x: jax.Array  # float32 [], metres, the robot's centre
    y: jax.Array  # float32 []
    heading: jax.Array  # float32 [], radians in [-pi, pi)
    dirty: jax.Array  # uint32 [num_words]: the cells still holding dust, as bits (see pack_cells)
    bumped: jax.Array  # bool []: the last move stopped at a wall
    time: jax.Array  # int32 []: steps taken in this episode


def pack_cells(cells: jax.Array) -> jax.Array:
    """Bool cells ``[..., grid_size, grid_size]`` as bits ``uint32 [..., ceil(grid_size² / 32)]``.

    Cell ``(row, column)`` is bit ``i % 32`` of word ``i // 32``, ``i = row · grid_size + column``. The
    floor travels packed because the env protocol's auto-reset selects between the stepped and a fresh
    room for every env on every step: 13 words instead of 400 bools made evaluating (p, r) settings
    (``agentax.search.settings.evaluate_settings``) 1.2-1.7× faster on the 2-core machine (measured side
    by side).
    """
    cells = jnp.asarray(cells, bool)
    flat = cells.reshape(*cells.shape[:-2], -1)
    padding = -flat.shape[-1] % 32
    flat = jnp.pad(flat, [(0, 0)] * (flat.ndim - 1) + [(0, padding)])
    bits = flat.reshape(*flat.shape[:-1], -1, 32).astype(jnp.uint32) << jnp.arange(32, dtype=jnp.uint32)
    return bits.sum(axis=-1, dtype=jnp.uint32)


def unpack_cells(words, grid_size: int):
    """The inverse of :func:`pack_cells`: bool ``[..., grid_size, grid_size]`` (NumPy in, NumPy out)."""
    xp = np if isinstance(words, np.ndarray) else jnp
    bits = (words[..., :, None] >> xp.arange(32, dtype=xp.uint32)) & 1
    flat = bits.reshape(*words.shape[:-1], -1)[..., : grid_size * grid_size]
    return flat.reshape(*words.shape[:-1], grid_size, grid_size).astype(bool)


def _wrap_angle(angle: jax.Array) -> jax.Array:
    return (angle + jnp.pi) % (2 * jnp.pi) - jnp.pi


def _fraction_before_wall(position: jax.Array, travel: jax.Array, low, high) -> jax.Array:
    """The fraction of ``travel`` (along one axis) the centre can cover before leaving ``[low, high]``."""
    safe = jnp.where(travel == 0, 1.0, travel)
    room = jnp.where(travel > 0, (high - position) / safe, (low - position) / safe)
    return jnp.where(travel == 0, jnp.inf, jnp.maximum(room, 0.0))


class Vacuum(Environment):
    """The robot vacuum cleaner of the lecture (see the module docstring for the model)."""

    id = "Vacuum-v0"

    def default_params(self) -> VacuumParams:
        return VacuumParams()

    def reset_env(self, key: jax.Array, params: VacuumParams) -> tuple[jax.Array, VacuumState]:
        low, high = params.robot_radius, params.room_size - params.robot_radius
        u = uniform4(key, 0.0, 1.0)  # jax.random.uniform(key, (4,)) through an unrolled hash; 3 are used
        x, y = low + (high - low) * u[:2]
        heading = jnp.pi * (2.0 * u[2] - 1.0)
        dirty = pack_cells(jnp.ones((params.grid_size, params.grid_size), bool))
        state = VacuumState(x, y, heading, dirty, jnp.bool_(False), jnp.int32(0))
        return self.get_obs(state, params), state

    def step(
        self, key: jax.Array, state: VacuumState, action: jax.Array, params: VacuumParams | None = None
    ) -> tuple[TimeStep, VacuumState]:
        """``Environment.step`` (auto-reset) without its key split: ``step_env`` draws nothing."""
        params = self.default_params() if params is None else params
        ts, next_state = self.step_env(key, state, action, params)
        _, reset_state = self.reset_env(key, params)
        state = jax.tree.map(lambda r, s: jnp.where(ts.done, r, s), reset_state, next_state)
        return ts.replace(obs=self.get_obs(state, params)), state

    def step_env(
        self, key: jax.Array, state: VacuumState, action: jax.Array, params: VacuumParams
    ) -> tuple[TimeStep, VacuumState]:
        action = jnp.asarray(action, jnp.float32)
        forward = action[0] > 0.5
        turn = jnp.clip(action[1], -jnp.pi, jnp.pi)
        low, high = params.robot_radius, params.room_size - params.robot_radius
        distance = jnp.where(forward, params.speed * params.step_seconds, 0.0)
        travel_x, travel_y = distance * jnp.cos(state.heading), distance * jnp.sin(state.heading)
        fraction = jnp.minimum(
            _fraction_before_wall(state.x, travel_x, low, high),
            _fraction_before_wall(state.y, travel_y, low, high),
        )
        fraction = jnp.minimum(fraction, 1.0)
        dirty, cells_cleaned = state.dirty, jnp.uint32(0)
        for k in range(1, params.cleaning_points + 1):  # vacuum evenly spaced points of the path
            along = fraction * k / params.cleaning_points
            column = self._cell(state.x + along * travel_x, params)
            row = self._cell(state.y + along * travel_y, params)
            cell = (row * params.grid_size + column).astype(jnp.uint32)
            word, bit = (cell >> 5).astype(jnp.int32), cell & jnp.uint32(31)
            cells_cleaned = cells_cleaned + ((dirty[word] >> bit) & jnp.uint32(1))
            dirty = dirty.at[word].set(dirty[word] & ~(jnp.uint32(1) << bit))
        picked = (cells_cleaned * params.dust_per_cell).astype(jnp.float32)
        state = VacuumState(
            x=jnp.clip(state.x + fraction * travel_x, low, high),
            y=jnp.clip(state.y + fraction * travel_y, low, high),
            heading=jnp.where(forward, state.heading, _wrap_angle(state.heading + turn)),
            dirty=dirty,
            bumped=forward & (fraction < 1.0),
            time=state.time + 1,
        )
        obs = self.get_obs(state, params)
        truncated = state.time >= params.max_steps_in_episode
        return TimeStep(obs, picked, jnp.bool_(False), truncated, obs), state

    @staticmethod
    def _cell(coordinate: jax.Array, params: VacuumParams) -> jax.Array:
        return jnp.clip(jnp.floor(coordinate / params.cell_size).astype(jnp.int32), 0, params.grid_size - 1)

    @staticmethod
    def get_obs(state: VacuumState, params: VacuumParams) -> jax.Array:
        return jnp.stack(
            [
                state.x / params.room_size,
                state.y / params.room_size,
                jnp.cos(state.heading),
                jnp.sin(state.heading),
                state.bumped.astype(jnp.float32),
            ]
        ).astype(jnp.float32)

    def observation_space(self, params: VacuumParams | None = None) -> Box:
        return Box(np.array([0, 0, -1, -1, 0], np.float32), np.array([1, 1, 1, 1, 1], np.float32), (5,))

    def action_space(self, params: VacuumParams | None = None) -> Box:
        return Box(np.array([0, -math.pi], np.float32), np.array([1, math.pi], np.float32), (2,))

    def render_frame(self, state: VacuumState, params: VacuumParams | None = None) -> np.ndarray:
        """The room from above ``[H, W, 3]`` uint8: dust brown, clean floor white, robot and heading."""
        params = self.default_params() if params is None else params
        return render_room(state, params)

    def trajectory(
        self, policy: Policy, key: jax.Array, params: VacuumParams | None = None
    ) -> tuple[VacuumState, jax.Array]:
        """One whole episode of ``policy``: states ``[T + 1]`` (the first from reset) and rewards ``[T]``."""
        params = self.default_params() if params is None else params
        states, rewards, _ = rollout(self, policy, key, int(params.max_steps_in_episode), params)
        return states, rewards


# Colours of the drawings (RGB).
FLOOR = np.array([250, 248, 240], np.uint8)
DUST = np.array([150, 115, 75], np.uint8)
ROBOT = np.array([60, 60, 70], np.uint8)
HEADING = np.array([230, 50, 40], np.uint8)
PATH = np.array([40, 110, 220], np.uint8)


def _floor_image(dirty: np.ndarray, pixels_per_cell: int) -> np.ndarray:
    """The floor ``[H, W, 3]``, image row 0 at the room's far wall (y = room_size)."""
    amount = np.asarray(dirty, np.float32)[::-1]  # y up
    colour = FLOOR + amount[..., None] * (DUST.astype(np.float32) - FLOOR)
    image = np.repeat(np.repeat(colour, pixels_per_cell, axis=0), pixels_per_cell, axis=1)
    image[::pixels_per_cell, :] = image[::pixels_per_cell, :] * 0.93  # faint grid lines
    image[:, ::pixels_per_cell] = image[:, ::pixels_per_cell] * 0.93
    return image.astype(np.uint8)


def _to_pixels(x, y, params: VacuumParams, size: int):
    scale = size / float(params.room_size)
    return np.asarray(x, np.float64) * scale, size - np.asarray(y, np.float64) * scale


def render_room(state: VacuumState, params: VacuumParams, pixels_per_cell: int = 12) -> np.ndarray:
    """The room from above ``[H, W, 3]`` uint8 (H = W = grid_size · pixels_per_cell): dust, floor, robot."""
    image = _floor_image(unpack_cells(np.asarray(state.dirty), params.grid_size), pixels_per_cell)
    size = image.shape[0]
    rows, columns = np.mgrid[0:size, 0:size] + 0.5
    cx, cy = _to_pixels(state.x, state.y, params, size)
    radius = float(params.robot_radius) * size / float(params.room_size)
    image[(columns - cx) ** 2 + (rows - cy) ** 2 <= radius**2] = ROBOT
    heading = float(state.heading)
    for t in np.linspace(0.0, radius, 4 * int(radius) + 2):  # the heading as a line from the centre
        column, row = int(cx + t * math.cos(heading)), int(cy - t * math.sin(heading))
        image[max(row - 1, 0) : row + 1, max(column - 1, 0) : column + 1] = HEADING
    return image


def render_path(
    states: VacuumState, params: VacuumParams | None = None, pixels_per_cell: int = 12
) -> np.ndarray:
    """The robot's path over its room ``[H, W, 3]`` uint8 from stacked states ``[T, ...]`` (``trajectory``).

    The floor shows the dust left at the end, the path is a blue line and the robot sits at its last position.
    """
    params = Vacuum().default_params() if params is None else params
    last = jax.tree.map(lambda leaf: np.asarray(leaf)[-1], states)
    image = render_room(last, params, pixels_per_cell)
    size = image.shape[0]
    xs, ys = _to_pixels(states.x, states.y, params, size)
    for (x0, y0), (x1, y1) in zip(
        zip(xs[:-1], ys[:-1], strict=True), zip(xs[1:], ys[1:], strict=True), strict=True
    ):
        for t in np.linspace(0.0, 1.0, int(max(abs(x1 - x0), abs(y1 - y0))) + 2):
            column, row = int(x0 + t * (x1 - x0)), int(y0 + t * (y1 - y0))
            image[min(max(row, 0), size - 1), min(max(column, 0), size - 1)] = PATH
    return image
