"""Evaluation on any env: JAX envs vectorized, Gymnasium envs on the host, policies checked to fit."""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.envs import GymnasiumEnv, make
from agentax.envs.core import episode_returns
from agentax.errors import UsageError
from agentax.evaluate import EvalStats, HostPolicy, check_policy_fits, evaluate, host_episode_returns
from agentax.policies import basic_policy, random_policy


def test_host_evaluation_of_a_random_policy_equals_a_plain_gymnasium_loop():
    # One sub-env: the host evaluation must be exactly Gymnasium's reset(seed) / step / reset() loop
    # with the same random actions (drawn from one generator seeded alike).
    seed, num_episodes = 5, 200
    random_actions = HostPolicy(lambda obs, rng: rng.integers(0, 4, size=len(obs)))
    returns, lengths = host_episode_returns(GymnasiumEnv("FrozenLake-v1"), random_actions, num_episodes, seed)

    env, rng = gymnasium.make("FrozenLake-v1"), np.random.default_rng(seed)
    env.reset(seed=seed)
    expected_returns, expected_lengths = [], []
    for _ in range(num_episodes):
        total, steps, done = 0.0, 0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(int(rng.integers(0, 4, size=1)[0]))
            total, steps, done = total + reward, steps + 1, terminated or truncated
        expected_returns.append(total)
        expected_lengths.append(steps)
        env.reset()
    np.testing.assert_array_equal(returns, expected_returns)
    np.testing.assert_array_equal(lengths, expected_lengths)
    assert 0 < sum(expected_returns) < num_episodes  # the slippery lake: some episodes reach the goal


def _pump(obs):
    """Push the car the way it is moving: solves MountainCar in ~100-200 steps."""
    return np.where(np.asarray(obs)[..., 1] >= 0, 2, 0)


def test_jax_policy_on_a_host_env_plays_one_episode_per_sub_env():
    # A JAX policy, vmapped over 4 sub-envs seeded 7..10, 4 episodes: episode i is sub-env i's first,
    # i.e. a single Gymnasium env reset with seed 7 + i and driven by the same rule.
    stats_returns, lengths = host_episode_returns(
        GymnasiumEnv("MountainCar-v0", num_envs=4), lambda obs, key: jnp.where(obs[1] >= 0, 2, 0), 4, seed=7
    )
    for i in range(4):
        env = gymnasium.make("MountainCar-v0")
        obs, _ = env.reset(seed=7 + i)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(int(_pump(obs)))
            total, done = total + reward, terminated or truncated
        assert stats_returns[i] == total and lengths[i] == -total  # reward -1 per step
    assert np.all(lengths < 200)  # every episode reached the flag before the time limit


def test_host_evaluation_counts_the_first_episodes_started():
    # 3 sub-envs, 7 episodes of different lengths (slippery lake, a fixed rule): the episodes
    # counted are the first 7 to start, ordered by start step then sub-env -- worked out here by
    # running 3 independent Gymnasium envs and listing every episode's start step.
    num_envs, num_episodes, seed = 3, 7, 11
    rule = lambda obs: (np.asarray(obs, np.int64).reshape(-1) * 7 + 1) % 4  # noqa: E731  (packed [n, 1])
    returns, lengths = host_episode_returns(
        GymnasiumEnv("FrozenLake-v1", num_envs=num_envs),
        HostPolicy(lambda obs, rng: rule(obs)),
        num_episodes,
        seed,
    )
    started = []  # (start step, sub-env, return, length)
    for i in range(num_envs):
        env = gymnasium.make("FrozenLake-v1")
        obs, _ = env.reset(seed=seed + i)
        step = 0
        for _ in range(num_episodes):
            start, total, done = step, 0.0, False
            while not done:
                obs, reward, terminated, truncated, _ = env.step(int(rule(obs)[0]))
                step, total, done = step + 1, total + reward, terminated or truncated
            started.append((start, i, total, step - start))
            obs, _ = env.reset()
    first = sorted(started)[:num_episodes]
    np.testing.assert_array_equal(returns, [e[2] for e in first])
    np.testing.assert_array_equal(lengths, [e[3] for e in first])
    assert len(set(lengths)) > 1


def test_evaluate_dispatches_on_the_env():
    env = make("CartPole-v0")
    stats = evaluate(env, basic_policy, num_episodes=50, seed=3)
    returns, lengths = jax.jit(episode_returns, static_argnums=(0, 1, 3))(
        env, basic_policy, jax.random.key(3), 50
    )
    assert stats.episodes == 50 and stats.mean_return == pytest.approx(float(np.mean(returns)))
    assert stats.max_return == float(np.max(returns)) and stats.mean_length == pytest.approx(
        float(np.mean(lengths))
    )
    # An id: a Gymnasium env with min(20, 16) sub-envs, played on the host from seed 0.
    random_actions = random_policy(make("FrozenLake-v1").action_space())
    host = evaluate("FrozenLake-v1", random_actions, num_episodes=20)
    sixteen = GymnasiumEnv("FrozenLake-v1", num_envs=16)
    returns, lengths = host_episode_returns(sixteen, random_actions, 20, seed=0)
    assert host == EvalStats.from_returns(returns, lengths) and host.episodes == 20


def test_evaluate_rejects_bad_input():
    with pytest.raises(UsageError, match="at least 1"):
        evaluate(make("CartPole-v1"), basic_policy, num_episodes=0)
    with pytest.raises(UsageError, match="JAX env"):
        evaluate(make("CartPole-v1"), HostPolicy(lambda obs, rng: np.zeros(len(obs), int)), num_episodes=5)


def test_policies_that_do_not_fit_are_caught_before_running():
    env = make("CartPole-v1")
    with pytest.raises(UsageError, match="cannot read CartPole-v1's observations"):
        check_policy_fits(env, lambda obs, key: jnp.int32(obs @ jnp.ones(6) > 0))  # weights for 6 inputs
    with pytest.raises(UsageError, match="takes Discrete"):
        check_policy_fits(env, lambda obs, key: jnp.zeros(3, jnp.int32))
    with pytest.raises(UsageError, match="takes Discrete"):
        check_policy_fits(env, lambda obs, key: obs[0])  # a float is no discrete action
    with pytest.raises(UsageError, match="takes Box"):
        check_policy_fits(make("Pendulum-v1"), lambda obs, key: jnp.zeros((2,)))


def test_with_random_actions_mixes_in_uniform_actions_at_rate_epsilon():
    from agentax.policies import with_random_actions

    always_two = lambda obs, key: jnp.int32(2)  # noqa: E731
    keys = jax.random.split(jax.random.key(0), 4_000)
    obs = jnp.zeros(3)
    for epsilon in (0.0, 0.3):
        policy = jax.vmap(with_random_actions(always_two, epsilon, num_actions=4), in_axes=(None, 0))
        actions = np.asarray(policy(obs, keys))
        # an action other than 2 comes only from the random draws: 3 of 4 of them
        assert np.mean(actions != 2) == pytest.approx(0.75 * epsilon, abs=0.03)
        assert set(actions.tolist()) <= {0, 1, 2, 3}
