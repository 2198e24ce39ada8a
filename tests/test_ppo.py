"""PPO: the clipped loss and Gaussian pieces by hand, and a short learning test on CartPole."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.agents import ppo, presets
from agentax.envs import make_jax
from agentax.errors import UsageError
from agentax.nets import gaussian_entropy, gaussian_log_prob
from agentax.runners.compiled import RunnerConfig, compiled_program, train_program


def test_clipped_surrogate_loss_hand_computed():
    # ratios [1.5, 0.5, 0.5, 1.5], advantages [1, 1, -1, -1], eps 0.2:
    # min(1.5, 1.2) = 1.2; min(0.5, 0.8) = 0.5; min(-0.5, -0.8) = -0.8; min(-1.5, -1.2) = -1.5
    # loss = -mean(1.2, 0.5, -0.8, -1.5) = -(-0.6 / 4) = 0.15
    ratios = jnp.array([1.5, 0.5, 0.5, 1.5])
    old = jnp.zeros(4)
    loss = ppo.clipped_surrogate_loss(jnp.log(ratios), old, jnp.array([1.0, 1.0, -1.0, -1.0]), 0.2)
    assert float(loss) == pytest.approx(0.15, abs=1e-6)


def test_clipped_surrogate_has_no_gradient_where_clipped():
    # ratio 1.5 > 1 + eps with a positive advantage: the clipped term wins, gradient 0.
    # ratio 1.1 inside the interval: d/dlogp of -(ratio * A) = -ratio * A = -1.1.
    grad = jax.grad(lambda lp: ppo.clipped_surrogate_loss(lp, jnp.zeros(1), jnp.ones(1), 0.2))
    assert float(grad(jnp.log(jnp.array([1.5])))[0]) == 0.0
    assert float(grad(jnp.log(jnp.array([1.1])))[0]) == pytest.approx(-1.1, rel=1e-5)


def test_gaussian_log_prob_and_entropy():
    # log N(0; 0, 1) = -0.5 log(2 pi) = -0.9189385 per dimension; N(1; 0, e^2): -0.5/e^2 - 1 - 0.9189385
    lp = gaussian_log_prob(jnp.zeros(2), jnp.array([0.0, 1.0]), jnp.array([0.0, 1.0]))
    assert float(lp) == pytest.approx(-0.9189385 + (-0.5 / np.e**2 - 1.0 - 0.9189385), rel=1e-6)
    # entropy of N(., 1) = 0.5 log(2 pi e) = 1.4189385
    assert float(gaussian_entropy(jnp.zeros(1))) == pytest.approx(1.4189385, rel=1e-6)


def test_config_validation_names_the_bad_value():
    with pytest.raises(UsageError, match="learning_rate"):
        ppo.PPOConfig(learning_rate=-1.0).validate()
    with pytest.raises(UsageError, match="minibatches"):
        ppo.PPOConfig(num_envs=3, num_steps=5, num_minibatches=2).validate()
    with pytest.raises(UsageError, match="unknown ppo preset"):
        presets.preset("ppo", "nope")


@pytest.mark.slow
def test_one_update_moves_the_policy_and_reports_finite_losses():
    env = make_jax("CartPole-v1")
    cfg = dataclasses.replace(
        presets.preset("ppo", "cartpole-fast").config, num_envs=4, num_steps=16, update_epochs=10
    )
    algorithm = compiled_program(ppo, env, cfg)
    state = algorithm.init(jax.random.key(0))
    _, first = jax.jit(algorithm.update)(state)
    # approx_kl grows from 0 as the policy moves away from the one that collected the data
    assert float(first["approx_kl"]) > 0.0
    assert np.isfinite(float(first["value_loss"]))


@pytest.mark.long  # make test-long; make test pins PPO's training by its golden rows and the tutorial
@pytest.mark.slow
@pytest.mark.timeout(240)
def test_ppo_learns_cartpole():
    env = make_jax("CartPole-v1")
    cfg = dataclasses.replace(presets.preset("ppo", "cartpole-fast").config, total_steps=30_720)
    result = train_program(
        compiled_program(ppo, env, cfg), env, RunnerConfig(seed=1, updates_per_chunk=30, eval_episodes=10)
    )
    first, last = result.rows[0], result.rows[-1]
    assert first["mean_return"] < 100  # early episodes are short
    assert last["mean_return"] > 2 * first["mean_return"]
    assert result.eval["mean_return"] > 120, result.rows
