"""The Dict-observation gridworld and tic-tac-toe with its legal-move mask: rules by hand, both in
Gymnasium, and PPO learning each on the compiled runner with fixed seeds."""

import dataclasses

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from agentax.agents import ppo, presets
from agentax.envs import gridworld, make_jax
from agentax.envs.core import episode_returns
from agentax.envs.gridworld import GridWorld, GridWorldState
from agentax.envs.spaces import packed
from agentax.envs.tictactoe import AGENT, OPPONENT, TicTacToe, TicTacToeState, play_games
from agentax.runners.compiled import RunnerConfig, compiled_program, train_program

KEY = jax.random.key(0)


# ---------------------------------------------------------------- the gridworld's rules


def test_shortest_paths_by_hand():
    lengths = gridworld.shortest_path_lengths()
    assert lengths[(1, 5)] == 1  # beside the goal
    assert lengths[(1, 1)] == 13  # down 4 to the gap's row, right 4, up 4, right 1
    assert lengths[(6, 6)] == 5  # straight up
    assert len(gridworld.FREE_CELLS) == 31 == len(lengths) - 1  # 6 × 6 inside, 4 of wall, the goal


def test_gridworld_moves_walls_goal_and_time_limit():
    env, params = GridWorld(), GridWorld().default_params()
    state = GridWorldState(jnp.array([1, 3]), jnp.int32(0))
    ts, after = env.step_env(KEY, state, 1, params)  # right, into the middle wall: stays
    np.testing.assert_array_equal(after.position, [1, 3])
    assert float(ts.reward) == 0.0 and not ts.terminated and not ts.truncated
    ts, after = env.step_env(KEY, GridWorldState(jnp.array([1, 5]), jnp.int32(9)), 1, params)
    assert bool(ts.terminated) and float(ts.reward) == pytest.approx(1 - 0.9 * 10 / 50)  # step 10
    ts, _ = env.step_env(KEY, GridWorldState(jnp.array([6, 1]), jnp.int32(49)), 3, params)
    assert bool(ts.truncated) and not ts.terminated and float(ts.reward) == 0.0  # the 50th step
    obs = ts.obs
    assert obs["image"].dtype == jnp.uint8 and obs["image"].shape == (8, 8, 3)
    assert int(obs["image"][6, 1, 1]) == 255 and int(obs["image"][..., 1].sum()) == 255  # the agent
    assert int(obs["image"][1, 6, 2]) == 255 and int(obs["image"][0, 0, 0]) == 255  # goal, a wall
    np.testing.assert_allclose(obs["vector"], [6 / 7, 1 / 7, 0.0])


def test_packed_gridworld_unpacks_to_the_envs_own_observation():
    env = make_jax("GridWorld-v0")
    obs, state = env.reset(KEY)
    assert obs.shape == (8 * 8 * 3 + 3,) and env.layout.leaves[0].kind == "image"
    own = GridWorld.get_obs(state, env.default_params())
    unpacked = env.layout.unpack(obs)
    np.testing.assert_array_equal(unpacked["image"], own["image"])
    np.testing.assert_allclose(unpacked["vector"], own["vector"])


# ---------------------------------------------------------------- tic-tac-toe's rules


@pytest.mark.slow  # compiles learning steps or plays thousands of games: not for the edit-test loop
def test_win_illegal_move_and_loss_by_hand():
    env, params = TicTacToe(), TicTacToe().default_params()
    x, o = AGENT, OPPONENT
    # X . .      the agent completes the top row at cell 2: +1, the opponent does not move
    # X X .
    # O O .
    board = jnp.array([x, x, 0, x, x, 0, o, o, 0])
    ts, after = env.step_env(KEY, TicTacToeState(board), 2, params)
    assert float(ts.reward) == 1.0 and bool(ts.terminated)
    assert int((after.board == o).sum()) == 2
    ts, after = env.step_env(KEY, TicTacToeState(board), 6, params)  # cell 6 is the opponent's
    assert float(ts.reward) == -1.0 and bool(ts.terminated)
    np.testing.assert_array_equal(after.board, board)  # an illegal move marks nothing
    # O O .      the agent plays 4 (no line); the opponent's replies are 2 (wins: -1, the end) and
    # X . .      5 (the game goes on), half and half over many keys, never another cell
    # X X O
    board = jnp.array([o, o, 0, x, 0, 0, x, x, o])
    ts, after = jax.vmap(lambda k: env.step_env(k, TicTacToeState(board), 4, params))(
        jax.random.split(KEY, 200)
    )
    took_2 = after.board[:, 2] == o
    assert bool(jnp.all(took_2 ^ (after.board[:, 5] == o))) and bool(jnp.all(after.board[:, 4] == x))
    np.testing.assert_array_equal(ts.reward, jnp.where(took_2, -1.0, 0.0))
    np.testing.assert_array_equal(ts.terminated, took_2)
    assert 60 < int(took_2.sum()) < 140
    # X O X      the agent fills the last cell without a line: a draw, 0, and no legal move left
    # X O O
    # O X .
    ts, _ = env.step_env(KEY, TicTacToeState(jnp.array([x, o, x, x, o, o, o, x, 0])), 8, params)
    assert float(ts.reward) == 0.0 and bool(ts.terminated)
    assert int(np.asarray(ts.obs["action_mask"]).sum()) == 0


@pytest.mark.slow  # compiles learning steps or plays thousands of games: not for the edit-test loop
def test_random_players_win_as_often_as_known():
    # Both players uniformly random, X first: X wins 58.5 %, O 28.8 %, draws 12.7 % (enumerating
    # every game, weighted by its probability). 4,000 games: standard errors below 0.8 points.
    env = make_jax("TicTacToe-v0")

    def random_legal(obs, key):
        return jax.random.categorical(key, jnp.where(env.layout.legal(obs), 0.0, -jnp.inf))

    returns, illegal = play_games(env, random_legal, KEY, 4000)
    returns = np.asarray(returns)
    assert (returns == 1).mean() == pytest.approx(0.585, abs=0.03)
    assert (returns == -1).mean() == pytest.approx(0.288, abs=0.03)
    assert not np.asarray(illegal).any()
    returns, illegal = play_games(env, lambda obs, key: jnp.int32(4), KEY, 100)  # the centre, again
    np.testing.assert_array_equal(illegal, True)  # every game ends on its second move
    np.testing.assert_array_equal(returns, -1.0)


# ---------------------------------------------------------------- in Gymnasium


@pytest.mark.parametrize("env_id", ["GridWorld-v0", "TicTacToe-v0"])
def test_gymnasium_sees_the_dict_space_and_dict_observations(env_id):
    env = gymnasium.make(f"agentax/{env_id}", render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    obs, _ = env.reset(seed=3)
    assert isinstance(env.observation_space, gymnasium.spaces.Dict)
    assert env.observation_space.contains(obs)
    obs, *_ = env.step(env.action_space.sample())
    assert env.observation_space.contains(obs)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3 and frame.shape[0] >= 64


# ---------------------------------------------------------------- learning, fixed seeds

GRID_PPO = dataclasses.replace(presets.PPO_PRESETS["small-games"].config, total_steps=24_576)
"""PPO on the gridworld: 48 updates of 16 envs × 32 steps, lr 2.5e-3 annealed, 4 epochs × 4
minibatches, entropy 0.01, γ 0.99, 64-64 tanh on the encoder's features (seeds 0-7 all optimal from
every start; with 32 updates one seed took 2 steps too many from one start)."""
BOARD_PPO = dataclasses.replace(GRID_PPO, total_steps=32_768)
"""PPO on tic-tac-toe: the same, 64 updates (masked: 94.6-97.6 % of wins on seeds 0-3)."""


def steps_to_goal(env, policy, params):
    """Steps the greedy ``policy`` takes to the goal from each start (``FREE_CELLS``), −1 where it
    does not arrive within the time limit (traceable: the seeds' policies are vmapped through it)."""

    def from_cell(cell):
        state = GridWorldState(cell, jnp.int32(0))
        obs = env.layout.pack(GridWorld.get_obs(state, params), jnp)

        def body(carry, _):
            obs, state, steps, arrived = carry
            ts, state = env.step_env(KEY, state, policy(obs, KEY), params)
            return (ts.obs, state, steps + ~arrived, arrived | ts.terminated), None

        start = (obs, state, jnp.int32(0), jnp.bool_(False))
        (_, _, steps, arrived), _ = jax.lax.scan(body, start, None, length=params.max_steps)
        return jnp.where(arrived, steps, -1)

    return jax.vmap(from_cell)(jnp.asarray(gridworld.FREE_CELLS))


def per_seed(play):
    """``play(policy, key)`` for every seed of a vmapped agent state at once: one program compiled
    once, not one per seed (``states`` ``[S, ...]``, ``keys`` ``[S]``)."""
    return lambda algorithm, states, keys: jax.jit(
        jax.vmap(lambda state, key: play(algorithm.greedy_policy(state), key))
    )(states, keys)


@pytest.mark.long  # 8 seeds to the optimum, ~45 s: make test-long (test_encoders_override trains it)
@pytest.mark.timeout(600)
def test_ppo_solves_the_gridworld_on_every_seed():
    env = make_jax("GridWorld-v0")
    algorithm = compiled_program(ppo, env, GRID_PPO)
    result = train_program(algorithm, env, RunnerConfig(seed=0, num_seeds=8, updates_per_chunk=16))
    lengths = gridworld.shortest_path_lengths()
    optimal = np.array([lengths[tuple(cell)] for cell in gridworld.FREE_CELLS])
    play = per_seed(
        lambda policy, key: (
            episode_returns(env, policy, key, 200)[0],
            steps_to_goal(env, policy, env.default_params()),
        )
    )
    returns, steps = play(algorithm, result.state, jax.random.split(jax.random.key(100), 8))
    for seed in range(8):
        assert float(returns[seed].min()) > 0.0, f"seed {seed}: an episode never reached the goal"
        np.testing.assert_array_equal(steps[seed], optimal)


@pytest.mark.long  # make test-long: 4 seeds; tutorial 10 shows one seed's 1,000 games in make test
@pytest.mark.slow
@pytest.mark.timeout(600)
def test_masked_ppo_beats_the_random_player_and_the_unmasked_one_plays_illegal_moves():
    runner = RunnerConfig(seed=0, num_seeds=4, updates_per_chunk=32)
    illegal_moves = {}
    for mask, env in ((True, make_jax("TicTacToe-v0")), (False, packed(TicTacToe(action_mask=False)))):
        algorithm = compiled_program(ppo, env, BOARD_PPO)
        result = train_program(algorithm, env, runner)
        play = per_seed(lambda policy, key, env=env: play_games(env, policy, key, 1000))
        returns, illegal = play(algorithm, result.state, jax.random.split(jax.random.key(100), 4))
        illegal_moves[mask] = int(illegal.sum())
        if mask:
            won = np.asarray((returns == 1).mean(axis=1))
            assert (won >= 0.9).all(), f"the seeds won {won}"
    assert illegal_moves[True] == 0  # the mask: never an illegal move in 4 × 1,000 games
    assert illegal_moves[False] > 0  # without it the agent still plays some (5, 0, 6, 13 seen)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_sweep_on_the_masked_board_game_traces_its_settings_beside_the_seeds(tmp_path):
    """The packed, masked observations of a JAX env go through a sweep's one program: two learning
    rates × two seeds, each agent's evaluation a tic-tac-toe return in [-1, 1]."""
    from agentax.sweeps import sweep

    swept = sweep(
        "ppo",
        "TicTacToe-v0",
        grid={"learning_rate": "1e-3,2.5e-3"},
        seeds=2,
        total_steps=8_192,
        out=tmp_path / "sweep",
        progress=False,
    )
    assert [s["learning_rate"] for s in swept.settings] == [1e-3, 2.5e-3]
    for setting in swept.settings:
        assert len(setting["scores"]) == 2 and all(-1.0 <= score <= 1.0 for score in setting["scores"])
    # above random legal play's expected return, 58.5 % won less 28.8 % lost ≈ 0.3 (seen: 0.8 and 0.7)
    assert min(setting["iqm"] for setting in swept.settings) > 0.5
