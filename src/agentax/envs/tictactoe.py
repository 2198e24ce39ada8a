"""Tic-tac-toe against a random opponent, with the legal moves in the observation.

* **Turns**: the agent plays X and moves first; the opponent (inside ``step``, drawing with the step's
  key) answers at once with a move chosen uniformly among the empty cells.
* **Actions** ``Discrete(9)``: the cell to mark, ``3 · row + column``.
* **Reward**: +1 for a win, −1 for a loss, 0 for a draw; a move onto a marked cell is illegal and
  ends the episode with −1 (so an agent that does not know the rules visibly loses games to them).
  Every episode terminates (at most 5 moves of the agent); none is truncated.
* **Observation** ``Dict(board: MultiDiscrete([3] * 9), action_mask: MultiBinary(9))``: each cell
  empty (0), the agent's (1) or the opponent's (2), and 1 for each empty cell, the legal moves. The
  ``action_mask`` key masks the agent's actions (:data:`agentax.envs.spaces.MASK_KEY`);
  ``TicTacToe(action_mask=False)`` observes the board alone, the same game for an agent without the
  mask.

:func:`play_games` plays games to their end and counts the illegal moves from the boards they were
played on (the reward alone cannot tell an illegal move from a loss).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.envs import spaces
from agentax.envs.core import Discrete, Environment, EnvParams, Policy, TimeStep

EMPTY, AGENT, OPPONENT = 0, 1, 2
LINES = np.array(
    [[0, 1, 2], [3, 4, 5], [6, 7, 8], [0, 3, 6], [1, 4, 7], [2, 5, 8], [0, 4, 8], [2, 4, 6]], np.int32
)
"""The eight lines of three cells that win."""


@struct.dataclass
class TicTacToeParams:
    pass


@struct.dataclass
class TicTacToeState:
    board: jax.Array  # int32 [9]: EMPTY, AGENT or OPPONENT per cell


def wins(board: jax.Array, player: int) -> jax.Array:
    """Whether ``player`` holds a whole line of ``board`` ``[9]``."""
    return jnp.any(jnp.all(board[jnp.asarray(LINES)] == player, axis=-1))


class TicTacToe(Environment):
    """Tic-tac-toe as X against a uniformly random O (see the module docstring)."""

    id = "TicTacToe-v0"

    def __init__(self, action_mask: bool = True):
        self.action_mask = action_mask
        if not action_mask:
            self.id = "TicTacToe-v0 without its mask"

    def default_params(self) -> TicTacToeParams:
        return TicTacToeParams()

    def reset_env(self, key: jax.Array, params: TicTacToeParams) -> tuple[dict, TicTacToeState]:
        state = TicTacToeState(jnp.zeros(9, jnp.int32))
        return self.get_obs(state), state

    def step_env(
        self, key: jax.Array, state: TicTacToeState, action: jax.Array, params: TicTacToeParams
    ) -> tuple[TimeStep, TicTacToeState]:
        legal = state.board[action] == EMPTY
        board = jnp.where(legal, state.board.at[action].set(AGENT), state.board)
        won = legal & wins(board, AGENT)
        over = ~legal | won | jnp.all(board != EMPTY)
        reply = jax.random.categorical(key, jnp.where(board == EMPTY, 0.0, -jnp.inf))
        board = jnp.where(over, board, board.at[reply].set(OPPONENT))
        lost = ~over & wins(board, OPPONENT)
        terminated = over | lost | jnp.all(board != EMPTY)
        reward = jnp.where(won, 1.0, jnp.where(~legal | lost, -1.0, 0.0)).astype(jnp.float32)
        state = TicTacToeState(board)
        obs = self.get_obs(state)
        return TimeStep(obs, reward, terminated, jnp.bool_(False), obs), state

    def get_obs(self, state: TicTacToeState) -> dict[str, jax.Array]:
        obs = {"board": state.board}
        if self.action_mask:
            obs[spaces.MASK_KEY] = (state.board == EMPTY).astype(jnp.int32)
        return obs

    def observation_space(self, params: TicTacToeParams | None = None) -> spaces.Dict:
        board = ("board", spaces.MultiDiscrete((3,) * 9))
        if not self.action_mask:
            return spaces.Dict((board,))
        return spaces.Dict((board, (spaces.MASK_KEY, spaces.MultiBinary(9))))

    def action_space(self, params: TicTacToeParams | None = None) -> Discrete:
        return Discrete(9)

    def render_frame(self, state: TicTacToeState, params: TicTacToeParams | None = None) -> np.ndarray:
        """The board ``[96, 96, 3]`` uint8, 32 pixels a cell: the agent's X red, the opponent's O blue."""
        cell = 32
        rows, columns = np.mgrid[0:cell, 0:cell] + 0.5 - cell / 2
        cross = (np.abs(np.abs(rows) - np.abs(columns)) < 2.5) & (np.abs(rows) < 11)
        ring = np.abs(np.hypot(rows, columns) - 10) < 2.2
        image = np.full((3 * cell, 3 * cell, 3), 250, np.uint8)
        for i, mark in enumerate(np.asarray(state.board)):
            view = image[i // 3 * cell : (i // 3 + 1) * cell, i % 3 * cell : (i % 3 + 1) * cell]
            if mark == AGENT:
                view[cross] = (220, 50, 40)
            elif mark == OPPONENT:
                view[ring] = (40, 90, 220)
        image[cell::cell, :], image[:, cell::cell] = 60, 60  # the grid's lines
        return image


def play_games(
    env: Environment, policy: Policy, key: jax.Array, num_games: int, params: EnvParams | None = None
) -> tuple[jax.Array, jax.Array]:
    """Play ``num_games`` games of the tic-tac-toe ``env`` (packed or not) side by side, each to its end.

    Returns ``(returns [num_games], illegal [num_games])``: each game's return (1 won, 0 drawn, −1
    lost or ended by an illegal move) and whether it ended by an illegal move of ``policy`` (a cell
    already marked on the board it moved on). Jittable (``env``, ``policy``, ``num_games`` static).
    """
    params = env.default_params() if params is None else params
    reset_key, key = jax.random.split(key)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(reset_key, num_games), params)
    alive = jnp.ones(num_games, bool)

    def body(carry):
        obs, state, returns, illegal, alive, key = carry
        key, act_key, step_key = jax.random.split(key, 3)
        actions = jax.vmap(policy)(obs, jax.random.split(act_key, num_games))
        marked = jnp.take_along_axis(state.board, actions[:, None], axis=1)[:, 0] != EMPTY
        ts, state = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
            jax.random.split(step_key, num_games), state, actions, params
        )
        returns = returns + ts.reward * alive
        illegal = illegal | (alive & marked)
        return ts.obs, state, returns, illegal, alive & ~ts.done, key

    carry = (obs, state, jnp.zeros(num_games, jnp.float32), ~alive, alive, key)
    _, _, returns, illegal, _, _ = jax.lax.while_loop(lambda c: c[4].any(), body, carry)
    return returns, illegal
