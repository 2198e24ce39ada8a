"""REINFORCE: the loss by hand, and the lecture's preset learning CartPole-v0 (CI-sized)."""

import dataclasses

import jax
import jax.numpy as jnp
import pytest

from agentax.agents import presets, reinforce
from agentax.api import compiled_program
from agentax.envs import make_jax
from agentax.errors import UsageError
from agentax.runners.compiled import RunnerConfig, train


def test_loss_is_minus_mean_log_prob_times_normalized_return():
    cfg = reinforce.ReinforceConfig(hidden=(5,), sigmoid_head=True)
    agent = reinforce.init(jax.random.key(0), (4,), 2, cfg)
    agent = agent.replace(params=jax.tree.map(jnp.zeros_like, agent.params))  # P(left) = sigmoid(0) = 0.5
    batch = {
        "obs": jnp.zeros((2, 1, 4)),
        "action": jnp.array([[0], [1]]),
        "returns": jnp.array([[3.0], [1.0]]),  # normalised: mean 2, std 1 -> [1, -1]
        "valid": jnp.array([[True], [True]]),
    }
    loss, _ = reinforce.loss_fn(agent.params, batch, 2, cfg)
    # -mean(log 0.5 * 1 + log 0.5 * -1) = 0
    assert float(loss) == pytest.approx(0.0, abs=1e-6)
    batch["valid"] = jnp.array([[True], [False]])  # one valid step: normalised advantage 0 -> loss 0
    assert float(reinforce.loss_fn(agent.params, batch, 2, cfg)[0]) == pytest.approx(0.0, abs=1e-6)
    grads = jax.grad(lambda p: reinforce.loss_fn(p, {**batch, "valid": jnp.ones((2, 1), bool)}, 2, cfg)[0])(
        agent.params
    )
    # the good action (0, advantage +1) gets its probability pushed up: z (logit of action 0) rises
    assert float(grads["policy"]["params"]["Dense_0"]["bias"][0]) < 0


def test_validation_and_sigmoid_head_needs_two_actions():
    with pytest.raises(UsageError, match="learning_rate"):
        reinforce.ReinforceConfig(learning_rate=-0.01).validate()
    with pytest.raises(UsageError, match="discount_factor"):
        reinforce.ReinforceConfig(discount_factor=1.5).validate()


@pytest.mark.slow
@pytest.mark.timeout(240)
@pytest.mark.parametrize("preset", ["lecture", "baseline"])
def test_reinforce_learns_cartpole_v0(preset):
    env = make_jax("CartPole-v0")
    cfg = dataclasses.replace(
        presets.preset("reinforce", preset).config, total_steps=75 * 2000
    )  # 75 iterations
    result = train(
        compiled_program(reinforce, env, cfg),
        env,
        RunnerConfig(seed=1, updates_per_chunk=15, eval_episodes=10),
    )
    first, last = result.rows[0]["mean_return"], result.rows[-1]["mean_return"]
    assert first < 40  # the untrained policy: ~20-step episodes
    assert last > 3 * first and last > 100, [r["mean_return"] for r in result.rows]
