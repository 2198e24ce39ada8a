"""A small gridworld with a Dict observation: an image of the grid and a vector beside it.

The grid is 8 × 8 cells: walls all around, a wall down the middle with a gap at the bottom, the goal
in the top-right corner::

    # # # # # # # #
    # . . . # . G #
    # . . . # . . #
    # . . . # . . #
    # . . . # . . #
    # . . . . . . #
    # . . . . . . #
    # # # # # # # #

* **Start**: a uniformly random free cell other than the goal.
* **Actions** ``Discrete(4)``: up, right, down, left; a move into a wall leaves the agent where it is.
* **Reward**: ``1 − 0.9 · t / max_steps`` on reaching the goal at step ``t`` (MiniGrid's), else 0, so
  the return says how short the path was; reaching the goal terminates the episode, ``max_steps`` =
  50 steps truncate it.
* **Observation** ``Dict(image: Box(0, 255, [8, 8, 3], uint8), vector: Box(0, 1, [3]))``: the image's
  channels are the walls, the agent and the goal (255 where present); the vector is the agent's
  row and column divided by 7 and the fraction of the time limit left.

Its observations reach agents packed (:mod:`agentax.envs.spaces`): the image goes through the small
CNN, the vector as it is. :data:`FREE_CELLS` and :func:`shortest_path_lengths` give every start and
its optimal number of steps (breadth-first search), so a test can hold a policy to the optimum.
"""

from __future__ import annotations

from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.envs import spaces
from agentax.envs.core import Box, Discrete, Environment, TimeStep

WALLS = np.array(
    [
        [1, 1, 1, 1, 1, 1, 1, 1],
        [1, 0, 0, 0, 1, 0, 0, 1],
        [1, 0, 0, 0, 1, 0, 0, 1],
        [1, 0, 0, 0, 1, 0, 0, 1],
        [1, 0, 0, 0, 1, 0, 0, 1],
        [1, 0, 0, 0, 0, 0, 0, 1],
        [1, 0, 0, 0, 0, 0, 0, 1],
        [1, 1, 1, 1, 1, 1, 1, 1],
    ],
    bool,
)
SIZE = WALLS.shape[0]
GOAL = (1, 6)
FREE_CELLS = np.array([cell for cell in zip(*np.nonzero(~WALLS), strict=True) if cell != GOAL], np.int32)
"""The start cells ``[N, 2]`` (row, column): every free cell but the goal."""
MOVES = np.array([(-1, 0), (0, 1), (1, 0), (0, -1)], np.int32)
"""Action ``a`` moves by ``MOVES[a]`` (row, column): up, right, down, left."""


@struct.dataclass
class GridWorldParams:
    max_steps: int = 50  # steps before the episode is truncated


@struct.dataclass
class GridWorldState:
    position: jax.Array  # int32 [2]: the agent's (row, column)
    time: jax.Array  # int32 []: steps taken in this episode


def shortest_path_lengths() -> dict[tuple[int, int], int]:
    """Each free cell's fewest steps to the goal (breadth-first search from the goal)."""
    lengths, queue = {GOAL: 0}, deque([GOAL])
    while queue:
        row, column = queue.popleft()
        for d_row, d_column in MOVES:
            cell = (row + int(d_row), column + int(d_column))
            if not WALLS[cell] and cell not in lengths:
                lengths[cell] = lengths[(row, column)] + 1
                queue.append(cell)
    return lengths


class GridWorld(Environment):
    """Walk to the goal around the wall (see the module docstring)."""

    id = "GridWorld-v0"

    def default_params(self) -> GridWorldParams:
        return GridWorldParams()

    def reset_env(self, key: jax.Array, params: GridWorldParams) -> tuple[dict, GridWorldState]:
        start = jax.random.randint(key, (), 0, len(FREE_CELLS))
        state = GridWorldState(jnp.asarray(FREE_CELLS)[start], jnp.int32(0))
        return self.get_obs(state, params), state

    def step_env(
        self, key: jax.Array, state: GridWorldState, action: jax.Array, params: GridWorldParams
    ) -> tuple[TimeStep, GridWorldState]:
        target = state.position + jnp.asarray(MOVES)[action]
        blocked = jnp.asarray(WALLS)[target[0], target[1]]
        state = GridWorldState(jnp.where(blocked, state.position, target), state.time + 1)
        at_goal = (state.position[0] == GOAL[0]) & (state.position[1] == GOAL[1])
        reward = jnp.where(at_goal, 1.0 - 0.9 * state.time / params.max_steps, 0.0).astype(jnp.float32)
        truncated = ~at_goal & (state.time >= params.max_steps)
        obs = self.get_obs(state, params)
        return TimeStep(obs, reward, at_goal, truncated, obs), state

    @staticmethod
    def get_obs(state: GridWorldState, params: GridWorldParams) -> dict[str, jax.Array]:
        background = np.zeros((SIZE, SIZE, 3), np.uint8)
        background[..., 0] = 255 * WALLS
        background[(*GOAL, 2)] = 255
        image = jnp.asarray(background).at[state.position[0], state.position[1], 1].set(255)
        time_left = 1.0 - state.time / params.max_steps
        vector = jnp.concatenate([state.position / (SIZE - 1), time_left[None]]).astype(jnp.float32)
        return {"image": image, "vector": vector}

    def observation_space(self, params: GridWorldParams | None = None) -> spaces.Dict:
        return spaces.Dict(
            (("image", Box(0, 255, (SIZE, SIZE, 3), jnp.uint8)), ("vector", Box(0.0, 1.0, (3,))))
        )

    def action_space(self, params: GridWorldParams | None = None) -> Discrete:
        return Discrete(4)

    def render_frame(self, state: GridWorldState, params: GridWorldParams | None = None) -> np.ndarray:
        """The grid ``[128, 128, 3]`` uint8, 16 pixels a cell: walls grey, goal green, agent red."""
        cells = np.full((SIZE, SIZE, 3), 245, np.uint8)
        cells[WALLS] = (90, 90, 100)
        cells[GOAL] = (60, 170, 80)
        cells[tuple(int(x) for x in np.asarray(state.position))] = (220, 50, 40)
        image = np.repeat(np.repeat(cells, 16, axis=0), 16, axis=1)
        image[::16, :], image[:, ::16] = 200, 200  # grid lines
        return image
