"""Discounting, normalisation, GAE and episode bookkeeping against hand-computed numbers."""

import jax.numpy as jnp
import numpy as np
import pytest

from agentax.returns import (
    EpisodeStats,
    discount_and_normalize_rewards,
    discount_rewards,
    discounted_returns,
    gae,
    normalize,
)


def test_discount_rewards_lecture_example():
    # G2 = -50; G1 = 0 + 0.8 * -50 = -40; G0 = 10 + 0.8 * -40 = -22
    np.testing.assert_allclose(discount_rewards([10, 0, -50], 0.8), [-22, -40, -50])


def test_discount_and_normalize_rewards_lecture_example():
    # Returns [-22, -40, -50] and [10 + 0.8 * 20, 20] = [26, 20]; over all five: mean -13.2,
    # std sqrt((8.8² + 26.8² + 36.8² + 39.2² + 33.2²) / 5) = sqrt(957.76) = 30.9477.
    first, second = discount_and_normalize_rewards([[10, 0, -50], [10, 20]], 0.8)
    np.testing.assert_allclose(first, [-0.28435071, -0.86597718, -1.18910299], rtol=1e-6)
    np.testing.assert_allclose(second, [1.26665318, 1.0727777], rtol=1e-6)


def test_masked_discounted_returns_match_per_episode_discounting():
    # One env, two episodes back to back: [1, 2, 3 | 4, 5]; done ends the first at index 2.
    rewards = jnp.array([1.0, 2.0, 3.0, 4.0, 5.0])
    done = jnp.array([0.0, 0.0, 1.0, 0.0, 0.0])
    returns = discounted_returns(rewards, 0.9 * (1.0 - done), jnp.float32(0.0))
    expected = np.concatenate([discount_rewards([1, 2, 3], 0.9), discount_rewards([4, 5], 0.9)])
    np.testing.assert_allclose(returns, expected, rtol=1e-6)


def test_discounted_returns_bootstrap_and_batch_axis():
    # Two envs, two steps, bootstrap values [10, 0]: env0: G1 = 1 + 0.5 * 10 = 6, G0 = 1 + 0.5 * 6 = 4.
    rewards = jnp.ones((2, 2))
    returns = discounted_returns(rewards, jnp.full((2, 2), 0.5), jnp.array([10.0, 0.0]))
    np.testing.assert_allclose(returns, [[4.0, 1.5], [6.0, 1.0]])


def test_gae_bootstraps_through_truncation_and_stops_at_termination():
    # Step 1 is truncated (bootstrap from V(final_obs) = 2.0), step 2 terminated (no bootstrap).
    # delta0 = 1 + 0.9 * 0.4 - 0.5 = 0.86; delta1 = 1 + 0.9 * 2.0 - 0.4 = 2.4; delta2 = 1 - 0.3 = 0.7
    # A2 = 0.7; A1 = 2.4 (the trace stops at done); A0 = 0.86 + 0.9 * 0.8 * 2.4 = 2.588
    advantages, targets = gae(
        rewards=jnp.array([1.0, 1.0, 1.0]),
        values=jnp.array([0.5, 0.4, 0.3]),
        next_values=jnp.array([0.4, 2.0, 0.7]),
        terminated=jnp.array([False, False, True]),
        done=jnp.array([False, True, True]),
        discount_factor=0.9,
        gae_lambda=0.8,
    )
    np.testing.assert_allclose(advantages, [2.588, 2.4, 0.7], rtol=1e-6)
    np.testing.assert_allclose(targets, [3.088, 2.8, 1.0], rtol=1e-6)


@pytest.mark.parametrize("gae_lambda", [0.0, 1.0])
def test_gae_limits_are_td_error_and_monte_carlo(gae_lambda):
    rewards, values = jnp.array([1.0, 2.0, 3.0]), jnp.array([0.5, 1.0, 1.5])
    next_values = jnp.array([1.0, 1.5, 4.0])  # V(s1), V(s2), V(s3) with s3 the bootstrap state
    no = jnp.zeros(3, bool)
    advantages, _ = gae(rewards, values, next_values, no, no, 0.9, gae_lambda)
    if gae_lambda == 0.0:  # one-step TD errors r + 0.9 V(s') - V(s)
        expected = [1 + 0.9 * 1.0 - 0.5, 2 + 0.9 * 1.5 - 1.0, 3 + 0.9 * 4.0 - 1.5]
    else:  # Monte-Carlo return bootstrapped from V(s3) = 4, minus V(s)
        g2 = 3 + 0.9 * 4.0
        g1 = 2 + 0.9 * g2
        g0 = 1 + 0.9 * g1
        expected = [g0 - 0.5, g1 - 1.0, g2 - 1.5]
    np.testing.assert_allclose(advantages, expected, rtol=1e-6)


def test_normalize_with_mask_ignores_masked_entries():
    x = jnp.array([1.0, 3.0, 100.0])
    out = normalize(x, jnp.array([True, True, False]))
    np.testing.assert_allclose(out[:2], [-1.0, 1.0], rtol=1e-5)  # mean 2, std 1 over the first two


def test_episode_stats_records_finished_episodes():
    stats = EpisodeStats.create(2)
    stats = stats.record(jnp.array([1.0, 1.0]), jnp.array([False, False]))
    stats = stats.record(jnp.array([1.0, 1.0]), jnp.array([True, False]))  # env0 ends with return 2
    stats = stats.record(jnp.array([1.0, 5.0]), jnp.array([False, True]), valid=jnp.array([False, True]))
    assert int(stats.completed) == 2
    assert float(stats.return_sum) == 2.0 + 7.0  # env1: 1 + 1 + 5
    np.testing.assert_allclose(stats.last_return, [2.0, 7.0])
    np.testing.assert_allclose(stats.episode_return, [0.0, 0.0])
    assert int(stats.env_steps) == 5  # the masked step of env0 is not counted
