from agentax.envs import make_jax
from agentax.evaluate import evaluate
from agentax.policies import basic_policy


def test_basic_policy_matches_the_lecture():
    # The lecture: 500 episodes of CartPole (<= 200 steps) give mean ~42, std ~8-9, min ~24, max ~63-68.
    stats = evaluate(make_jax("CartPole-v0"), basic_policy, num_episodes=500, seed=42)
    assert 38 < stats.mean_return < 47
    assert 6 < stats.std_return < 11
    assert 20 <= stats.min_return <= 30
    assert 55 <= stats.max_return <= 80
    assert stats.episodes == 500
    assert stats.mean_length == stats.mean_return  # CartPole pays 1 a step: each return is its length
