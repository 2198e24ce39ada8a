"""PQN: Q(λ) targets checked by hand, and a real agent that learns CartPole on the compiled and the
host runner (one agent file, every runner)."""

import jax.numpy as jnp
import numpy as np
import pytest

import agentax
from agentax.agents import pqn
from agentax.errors import UsageError
from agentax.returns import q_lambda_returns

REWARDS = jnp.ones((3, 1))
NEXT_Q = jnp.array([[2.0], [3.0], [4.0]])  # max_a Q(s'_t, a)
NEVER = jnp.zeros((3, 1), bool)


def test_q_lambda_targets_by_hand():
    """γ = 0.5, λ = 0.5; step 1 is truncated (bootstrap, but the trace stops there):
    G_2 = 1 + 0.5·4 = 3 (the last step bootstraps from its own q');
    G_1 = 1 + 0.5·3 = 2.5 (done: no trace from the next episode);
    G_0 = 1 + 0.5·(2 + 0.5·(2.5 − 2)) = 2.125."""
    truncated_1 = jnp.array([[False], [True], [False]])
    targets = q_lambda_returns(REWARDS, NEXT_Q, NEVER, truncated_1, 0.5, 0.5)
    np.testing.assert_allclose(targets[:, 0], [2.125, 2.5, 3.0])
    # terminated at step 1: G_1 = r_1 = 1, G_0 = 1 + 0.5·(2 + 0.5·(1 − 2)) = 1.75
    terminated_1 = truncated_1
    np.testing.assert_allclose(
        q_lambda_returns(REWARDS, NEXT_Q, terminated_1, terminated_1, 0.5, 0.5)[:, 0], [1.75, 1.0, 3.0]
    )
    # λ = 0: one-step Q-learning targets r + γ q'; λ = 1: the discounted return, bootstrapped at the end
    np.testing.assert_allclose(
        q_lambda_returns(REWARDS, NEXT_Q, NEVER, NEVER, 0.5, 0.0)[:, 0], [2.0, 2.5, 3.0]
    )
    np.testing.assert_allclose(
        q_lambda_returns(REWARDS, NEXT_Q, NEVER, NEVER, 0.5, 1.0)[:, 0], [2.25, 2.5, 3.0]
    )


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_targets_from_acts_q_values_equal_a_second_forward_pass():
    """On an EnvPool-style rollout (``info["valid"]``: ``next_obs[t]`` is ``obs[t + 1]``) PQN
    bootstraps from ``act``'s ``max_q`` and passes only the last next observations through the
    network; the update equals the one that passes every ``next_obs`` (no ``valid``)."""
    import jax

    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_jax
    from agentax.replay import Transition

    cfg = pqn.PQNConfig(num_envs=4, num_steps=8, num_minibatches=2, update_epochs=2)
    agent = pqn.make_agent(EnvSpec.of(make_jax("CartPole-v1")), cfg)
    state = jax.jit(agent.init)(jax.random.key(0))
    observations = jax.random.normal(jax.random.key(1), (9 * 4 * 4,)).reshape(9, 4, 4)  # [T + 1, E, obs]
    act = jax.jit(jax.vmap(lambda obs: agent.act(state, obs, jax.random.key(2), 0)))
    actions, info = act(observations[:-1])
    ends = jax.random.bernoulli(jax.random.key(3), 0.1, (8, 4))
    rollout = Transition(
        obs=observations[:-1],
        action=actions,
        reward=jnp.ones((8, 4)),
        next_obs=observations[1:],
        terminated=ends,
        truncated=jnp.zeros((8, 4), bool),
        num_steps=jnp.ones((8, 4), jnp.int32),
        info=info,
    )
    learn = jax.jit(agent.learn)
    reused, _ = learn(
        state, rollout.replace(info={**info, "valid": jnp.ones((8, 4), bool)}), jax.random.key(4)
    )
    passed, _ = learn(state, rollout, jax.random.key(4))
    for a, b in zip(jax.tree.leaves(reused.params), jax.tree.leaves(passed.params), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_pqn_solves_cartpole_on_the_compiled_runner(tmp_path):
    """The default preset, two seeds vmapped: every seed's greedy policy averages at least 475
    (CartPole-v1's solved mark) within 150k env steps (measured: 8 of 8 seeds by 102k)."""
    run = agentax.train(
        "pqn", env="CartPole-v1", seeds=2, total_steps=150_000, out=tmp_path / "c", progress=False
    )
    assert run.result.solved_env_steps is not None and run.result.solved_env_steps <= 150_000
    assert min(s["mean_return"] for s in run.final_eval["per_seed"]) >= 475


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_the_same_pqn_agent_learns_on_the_host_runner(tmp_path):
    """Gymnasium's CartPole-v1 stepped on the host by the Driver: far above a random policy (~22)."""
    run = agentax.train(
        "pqn",
        env="CartPole-v1",
        runner="host",
        total_steps=40_960,
        out=tmp_path / "h",
        progress=False,
        stop_at_return=None,
    )
    assert run.final_eval["mean_return"] > 150, run.final_eval


def test_pqn_refuses_what_it_cannot_learn():
    with pytest.raises(UsageError, match="pqn takes Discrete actions"):
        agentax.train("pqn", env="Pendulum-v1", runner="host", total_steps=512, progress=False)
    with pytest.raises(UsageError, match="must split into num_minibatches"):
        pqn.PQNConfig(num_envs=3, num_steps=5, num_minibatches=4).validate()
