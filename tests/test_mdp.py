"""Markov chains, tabular MDPs (dense and sparse), the Gymnasium converters and MDPEnv."""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.envs.mdp import (
    MarkovChain,
    MDPEnv,
    SparseMDP,
    TabularMDP,
    chain_mdp,
    check_discount_factor,
    frozenlake,
    gridworld,
    improper_states,
    lecture_markov_chain,
    lecture_mdp,
    lecture_mdp_env,
    taxi,
)
from agentax.errors import UsageError

LECTURE_CHAIN = np.array(
    [[0.7, 0.2, 0.0, 0.1], [0.0, 0.0, 0.9, 0.1], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


def test_markov_chain_empirical_transition_frequencies_match_the_matrix():
    chain = lecture_markov_chain()
    assert np.asarray(chain.terminal).tolist() == [False, False, False, True]
    simulate = jax.jit(jax.vmap(lambda key, start: chain.simulate(key, start, 30)))
    starts = jnp.arange(4000) % 3  # start in each non-terminal state
    paths = np.asarray(simulate(jax.random.split(jax.random.key(0), 4000), starts))  # [4000, 31]
    assert paths.shape == (4000, 31)
    counts = np.zeros((4, 4))
    np.add.at(counts, (paths[:, :-1], paths[:, 1:]), 1)
    frequencies = counts[:3] / counts[:3].sum(-1, keepdims=True)
    # Each row has thousands of samples: a binomial std of at most 0.5 / sqrt(2000) ~ 0.011.
    np.testing.assert_allclose(frequencies, LECTURE_CHAIN[:3], atol=0.04)
    # Once in s3 the path stays there: every step after the first 3 is 3.
    first_terminal = np.argmax(paths == 3, axis=1)
    reached = (paths == 3).any(1)
    # P(in s3 after 30 steps) from each start, by matrix power, averaged over the three starts.
    absorbed = np.linalg.matrix_power(LECTURE_CHAIN, 30)[:3, 3].mean()
    assert abs(reached.mean() - absorbed) < 0.03
    for path, first in zip(paths[reached][:100], first_terminal[reached][:100], strict=True):
        assert (path[first:] == 3).all()


def test_lecture_mdp_tables():
    mdp = lecture_mdp()
    assert np.asarray(mdp.possible_actions).tolist() == [
        [True, True, True],
        [True, False, True],
        [False, True, False],
    ]
    # Expected rewards by hand: R(s0, a0) = 0.7 * 10 = 7; R(s1, a2) = 1.0 * -50; R(s2, a1) = 0.8 * 40 = 32.
    np.testing.assert_allclose(mdp.expected_rewards(), [[7, 0, 0], [0, 0, -50], [0, 32, 0]], atol=1e-5)
    np.testing.assert_allclose(mdp.transition_probabilities[2, 1], [0.8, 0.1, 0.1])
    assert not np.asarray(mdp.terminal).any()
    np.testing.assert_allclose(mdp.initial_distribution, [1, 0, 0])


@pytest.mark.parametrize(
    "build, message",
    [
        (
            lambda: TabularMDP.create([[[0.5, 0.4]], [[0.0, 1.0]]], np.zeros((2, 1, 2))),
            r"\[0, 0\] sums to 0.9",
        ),
        (
            lambda: TabularMDP.create([[[1.2, -0.2]], [[0.0, 1.0]]], np.zeros((2, 1, 2))),
            r"\[0, 0, 1\].*negative",
        ),
        (lambda: TabularMDP.create([[[1.0, 0.0]], [[0.0, 1.0]]], np.zeros((2, 2, 2))), "rewards has shape"),
        (
            lambda: TabularMDP.create([[[1.0, 0.0, 0.0]], [[0.0, 1.0]]], np.zeros((2, 1, 2))),
            r"\[0\]\[0\] has shape",
        ),
        (
            lambda: TabularMDP.create([[[1.0, 0.0]], [None]], np.zeros((2, 1, 2))),
            "state 1 has no possible action",
        ),
        (lambda: TabularMDP.create([[[1.0, 0.0]], [[0, 1]]], [[[0, np.nan]], [[0, 0]]]), "not finite"),
        (lambda: MarkovChain.create([[0.5, 0.5, 0.0], [0.0, 1.0, 0.0]]), "square"),
        (lambda: MarkovChain.create([[0.5, 0.6], [0.0, 1.0]]), r"\[0\] sums to 1.1"),
        (
            lambda: SparseMDP.create([[[0, 2]]], [[[0.5, 0.5]]], [[[0, 0]]]),
            r"next_states\[0, 0, 1\] = 2 is outside",
        ),
        (lambda: SparseMDP.create([[[0]]], [[[1.0]]], [[[0.0, 1.0]]]), "share one"),
        (
            lambda: TabularMDP.create(np.eye(2)[:, None, :], np.zeros((2, 1, 2)), None, [0, 1], [1]),
            "terminal state 1",
        ),
    ],
)
def test_invalid_tables_raise_a_clear_usage_error(build, message):
    with pytest.raises(UsageError, match=message):
        build()


def test_frozenlake_converter_matches_gymnasium_p_tables():
    env = gymnasium.make("FrozenLake-v1", map_name="4x4", is_slippery=True)
    dense, sparse = frozenlake("4x4"), frozenlake("4x4", sparse=True)
    expected = np.zeros((16, 4, 16))
    expected_rewards = np.zeros((16, 4))
    for s in range(16):
        for a in range(4):
            for probability, next_state, reward, _ in env.unwrapped.P[s][a]:
                expected[s, a, next_state] += probability
                expected_rewards[s, a] += probability * reward
    holes_and_goal = [i for i, c in enumerate(b"".join(env.unwrapped.desc.reshape(-1))) if c in b"HG"]
    assert np.flatnonzero(dense.terminal).tolist() == holes_and_goal == [5, 7, 11, 12, 15]
    np.testing.assert_allclose(dense.transition_probabilities, expected, atol=1e-6)
    np.testing.assert_allclose(dense.expected_rewards(), expected_rewards, atol=1e-6)
    np.testing.assert_allclose(sparse.expected_rewards(), expected_rewards, atol=1e-6)
    np.testing.assert_allclose(sparse.to_dense().transition_probabilities, expected, atol=1e-6)
    assert sparse.next_states.shape == (16, 4, 3)
    values = jnp.linspace(0.0, 1.0, 16)
    np.testing.assert_allclose(sparse.expected_next_values(values), expected @ values, atol=1e-5)


def test_taxi_converter_terminal_states_are_the_delivered_passengers_at_their_destination():
    mdp = taxi(sparse=True)
    assert mdp.next_states.shape == (500, 6, 1)
    env = gymnasium.make("Taxi-v4").unwrapped
    terminal = np.flatnonzero(mdp.terminal)
    for s in terminal:  # the taxi stands on the destination with the passenger delivered there
        row, col, passenger, destination = env.decode(int(s))
        assert passenger == destination and (row, col) == env.locs[destination]
    assert len(terminal) == 4
    np.testing.assert_allclose(mdp.initial_distribution, env.initial_state_distrib, atol=1e-7)


def test_mdp_env_steps_like_gymnasium_on_deterministic_frozenlake():
    gym_env = gymnasium.make("FrozenLake-v1", map_name="8x8", is_slippery=False)
    mdp = frozenlake("8x8", is_slippery=False, sparse=True)
    env = MDPEnv(mdp, max_steps_in_episode=200)
    step = jax.jit(env.step)
    rng = np.random.default_rng(0)
    key = jax.random.key(0)
    obs, state = env.reset(key)
    gym_obs, _ = gym_env.reset(seed=0)
    episodes = 0
    for _ in range(600):
        action = int(rng.integers(4))
        key, step_key = jax.random.split(key)
        ts, state = step(step_key, state, action)
        gym_obs, gym_reward, gym_terminated, gym_truncated, _ = gym_env.step(action)
        assert int(ts.final_obs) == gym_obs
        assert float(ts.reward) == gym_reward
        assert bool(ts.terminated) == gym_terminated
        if gym_terminated:
            episodes += 1
            assert int(ts.obs) == 0  # auto-reset to the start
            gym_obs, _ = gym_env.reset()
    assert episodes > 5


@pytest.mark.slow
def test_mdp_env_impossible_action_is_a_no_op_and_time_limit_truncates():
    env = lecture_mdp_env()  # unpacked: its integer states (agentax.envs.make packs them one-hot for agents)
    assert env.observation_space().n == 3 and env.action_space().n == 3
    params = env.default_params()
    step_env = jax.jit(env.step_env)
    _, state = env.reset(jax.random.key(0))
    state = state.replace(state=jnp.int32(1))
    ts, next_state = step_env(jax.random.key(1), state, jnp.int32(1), params)  # a1 is impossible in s1
    assert int(ts.obs) == 1 and float(ts.reward) == 0.0 and not bool(ts.done)
    assert int(next_state.time) == 1
    # s2 allows only a1: reward +40 on the way to s0 with probability 0.8 (lecture table).
    state = state.replace(state=jnp.int32(2))
    rewards = jax.vmap(lambda k: step_env(k, state, jnp.int32(1), params)[0].reward)(
        jax.random.split(jax.random.key(2), 2000)
    )
    assert abs(float((rewards == 40).mean()) - 0.8) < 0.03
    truncated = step_env(jax.random.key(3), state.replace(time=jnp.int32(99)), jnp.int32(1), params)[0]
    assert bool(truncated.truncated) and not bool(truncated.terminated)


def test_discount_factor_one_only_where_every_policy_terminates():
    # Chain: "left" in state 0 stays there forever, so a policy can avoid the terminal end.
    assert improper_states(chain_mdp(5)).tolist() == [True, True, True, True, False]
    with pytest.raises(UsageError, match="every policy to terminate"):
        check_discount_factor(chain_mdp(5), 1.0)
    with pytest.raises(UsageError, match="outside"):
        check_discount_factor(chain_mdp(5), -0.1)
    # A slippery grid: from every cell each action can slip toward the goal, so all policies end.
    assert not improper_states(gridworld(6, slip=0.2)).any()
    check_discount_factor(gridworld(6, slip=0.2), 1.0)
    # Without slip, bumping into a wall forever is a policy that never ends.
    assert improper_states(gridworld(6, slip=0.0)).sum() == 35
    with pytest.raises(UsageError, match="a policy can run forever"):
        check_discount_factor(frozenlake("4x4"), 1.0)
