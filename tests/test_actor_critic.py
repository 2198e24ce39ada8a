"""SAC and TD3: the squashed Gaussian's density, the action scaling, TD3's delays, Polyak targets,
bad input, and both learning Pendulum on the compiled runner and training on the host runners."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.agents import presets, sac, td3
from agentax.agents.protocol import EnvSpec, scale_action
from agentax.cli import main
from agentax.envs import JAX_ENVS, make_jax
from agentax.envs.core import Box, Discrete
from agentax.errors import UsageError
from agentax.nets import sample_squashed
from agentax.replay import ReplaySample, Transition
from agentax.runners.compiled import RunnerConfig, compiled_program, train_program

PENDULUM = "Pendulum-v1" if "Pendulum-v1" in JAX_ENVS else "gymnax/Pendulum-v1"
SPEC = EnvSpec((3,), Box(np.full(1, -2.0, np.float32), np.full(1, 2.0, np.float32), (1,)))
MODULES = {"sac": sac, "td3": td3}


def batch(key: jax.Array, size: int = 32) -> ReplaySample:
    """A random replayed batch of Pendulum-shaped transitions."""
    k = jax.random.split(key, 4)
    transition = Transition(
        obs=jax.random.normal(k[0], (size, 3)),
        action=jax.random.uniform(k[1], (size, 1), minval=-1, maxval=1),
        reward=jax.random.normal(k[2], (size,)),
        next_obs=jax.random.normal(k[3], (size, 3)),
        terminated=jnp.zeros(size),
        truncated=jnp.zeros(size, bool),
        num_steps=jnp.ones(size, jnp.int32),
    )
    return ReplaySample(transition, jnp.arange(size), jnp.ones(size))


def test_squashed_gaussian_log_prob_is_the_change_of_variables():
    """log π(a) = log N(atanh a; μ, σ²) − log(1 − a²), summed over dimensions (float64 by hand)."""
    mean, log_std = jnp.array([[0.3, -1.0, 2.0]]), jnp.array([[-0.5, 0.0, 0.4]])
    action, log_prob = sample_squashed(mean, log_std, jax.random.key(0))
    a, mu, sigma = (np.asarray(x, np.float64) for x in (action, mean, jnp.exp(log_std)))
    u = np.arctanh(a)
    by_hand = (
        -0.5 * ((u - mu) / sigma) ** 2 - np.log(sigma) - 0.5 * np.log(2 * np.pi) - np.log(1 - a**2)
    ).sum()
    assert np.all(np.abs(a) < 1)
    np.testing.assert_allclose(float(log_prob[0]), by_hand, rtol=1e-4)


def test_actions_in_the_unit_box_are_scaled_onto_the_bounds():
    space = Box(np.array([-2.0, 0.0], np.float32), np.array([2.0, 10.0], np.float32), (2,))
    action = jnp.array([[-1.0, -1.0], [0.0, 0.5], [1.0, 1.0], [3.0, -7.0]])
    np.testing.assert_allclose(scale_action(action, space), [[-2, 0], [0, 7.5], [2, 10], [2, 0]])


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_discrete_envs_are_refused_naming_what_fits(algo):
    with pytest.raises(UsageError, match=f"{algo} needs continuous \\(Box\\) actions.*use dqn, pqn or ppo"):
        MODULES[algo].make_agent(
            EnvSpec((4,), Discrete(2)), MODULES[algo].TD3Config() if algo == "td3" else sac.SACConfig()
        )


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "sac", "--env", "CartPole-v1"], "sac needs continuous (Box) actions"),
        (["train", "td3", "--env", "CartPole-v1"], "td3 needs continuous (Box) actions"),
        (["train", "dqn", "--env", "Pendulum-v1"], "dqn takes Discrete actions, but this env's actions are"),
        (["train", "sac", "--utd", "0"], "utd must be positive"),
        (["train", "td3", "--policy-delay", "0"], "policy_delay must be positive"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(argv, message, capsys):
    assert main([*argv, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


@pytest.mark.slow
def test_td3_moves_the_actor_and_the_targets_every_policy_delay_steps():
    cfg = td3.TD3Config(hidden=(16, 16), policy_delay=2, tau=0.5)
    agent = td3.make_agent(SPEC, cfg)
    state0 = agent.init(jax.random.key(0))
    learn = jax.jit(agent.learn)
    state1, _ = learn(state0, batch(jax.random.key(1)), jax.random.key(2))
    state2, metrics = learn(state1, batch(jax.random.key(3)), jax.random.key(4))
    leaves = jax.tree.leaves

    def same(a, b):
        return all(np.array_equal(x, y) for x, y in zip(leaves(a), leaves(b), strict=True))

    assert not same(state1.params["critic"], state0.params["critic"])  # the critics learn every step
    assert same(state1.params["actor"], state0.params["actor"]) and same(
        state1.target_params, state0.target_params
    )
    assert not same(state2.params["actor"], state1.params["actor"])
    expected = jax.tree.map(lambda t, p: 0.5 * p + 0.5 * t, state1.target_params, state2.params)
    for x, y in zip(leaves(state2.target_params), leaves(expected), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-6)
    assert all(np.isfinite(float(metrics[k])) for k in ("critic_loss", "actor_loss", "q_mean"))


@pytest.mark.slow
def test_sac_copies_its_critics_with_tau_1_and_keeps_a_fixed_alpha_without_autotune():
    cfg = sac.SACConfig(hidden=(16, 16), tau=1.0, autotune=False, initial_alpha=0.2)
    agent = sac.make_agent(SPEC, cfg)
    state, metrics = jax.jit(agent.learn)(
        agent.init(jax.random.key(0)), batch(jax.random.key(1)), jax.random.key(2)
    )
    for x, y in zip(
        jax.tree.leaves(state.target_params), jax.tree.leaves(state.params["critic"]), strict=True
    ):
        np.testing.assert_array_equal(x, y)
    assert float(metrics["alpha"]) == pytest.approx(0.2)
    assert metrics["priority"].shape == (32,)


@pytest.mark.slow
def test_sac_fits_its_critics_and_moves_alpha_towards_the_target_entropy():
    """Repeated steps on one batch: the critic loss falls; α's first (Adam) step goes the way the
    entropy's gap to the target −d says (up while the entropy is below it), and the entropy rises."""
    agent = sac.make_agent(SPEC, sac.SACConfig(hidden=(32, 32), learning_rate=1e-3))
    sample = batch(jax.random.key(1), 64)

    def many(state, key):
        return jax.lax.scan(lambda s, k: agent.learn(s, sample, k), state, jax.random.split(key, 200))

    _, metrics = jax.jit(many)(agent.init(jax.random.key(0)), jax.random.key(2))
    loss, alpha, entropy = (np.asarray(metrics[k]) for k in ("critic_loss", "alpha", "entropy"))
    assert loss[-20:].mean() < 0.5 * loss[:20].mean()
    assert entropy[0] < -1.0 and alpha[0] == pytest.approx(
        1.0 + 1e-3, rel=1e-4
    )  # exp(lr) for Adam's first step
    assert entropy[-20:].mean() > entropy[:5].mean()


@pytest.mark.slow
def test_the_uniform_warm_up_then_the_policy_and_greedy_actions_in_bounds():
    for module, cfg in (
        (sac, sac.SACConfig(hidden=(8,), learning_starts=10)),
        (td3, td3.TD3Config(hidden=(8,), learning_starts=10)),
    ):
        agent = module.make_agent(SPEC, cfg)
        state = agent.init(jax.random.key(0))
        obs = jnp.zeros((4096, 3))
        early, _ = agent.act(state, obs, jax.random.key(1), jnp.int32(0))
        late, _ = agent.act(state, obs, jax.random.key(1), jnp.int32(10))
        assert early.shape == late.shape == (4096, 1)
        assert abs(float(early.mean())) < 0.05 and float(early.std()) == pytest.approx(
            1 / np.sqrt(3), abs=0.02
        )
        assert float(late.std()) < float(early.std())  # the untrained policy is narrower than uniform
        greedy = agent.greedy_policy(state)(jnp.zeros(3), jax.random.key(2))
        assert greedy.shape == (1,) and -2.0 <= float(greedy[0]) <= 2.0
        assert np.all(np.abs(np.asarray(agent.env_action(late))) <= 2.0)


SMALL = {  # the Zoo's Pendulum presets with 64-wide layers and a short warm-up
    "sac": {"hidden": (64, 64), "total_steps": 5_000, "learning_starts": 500},
    "td3": {"hidden": (64, 64), "total_steps": 8_000, "learning_starts": 500},
}


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("algo", ["sac", pytest.param("td3", marks=pytest.mark.long)])
def test_learns_pendulum_on_the_compiled_runner(algo):
    """From random swings (about −1,200) to an upright pendulum for both seeds in 5,000 (SAC) or
    8,000 (TD3) steps. TD3's (~100 s with an empty compile cache) runs in make test-long: in make
    test its numbers are pinned by the golden rows td3_compiled and td3_host (tests/test_golden.py),
    and SAC's learning, on the same off-policy machinery, is checked here."""
    cfg = presets.preset(algo, "pendulum", **SMALL[algo]).config
    runner = RunnerConfig(seed=0, num_seeds=2, updates_per_chunk=1_000, eval_episodes=10)
    env = make_jax(PENDULUM)
    result = train_program(compiled_program(MODULES[algo], env, cfg, runner), env, runner)
    assert result.rows[0]["mean_return"] < -900, result.rows[0]
    assert min(result.eval["per_seed_mean"]) > -400, result.eval


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("runner", ["host", "parallel"])
@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_trains_gymnasiums_pendulum_on_the_host_runners(algo, runner, tmp_path):
    out = tmp_path / "run"
    argv = ["train", algo, "--env", "Pendulum-v1", "--runner", runner, "--total-steps", "400"]
    argv += ["--learning-starts", "200", "--hidden", "16", "16", "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    evaluation = json.loads((out / "eval.json").read_text())
    assert (
        evaluation["env_steps"] >= 400
        and evaluation["updates"] > 0
        and np.isfinite(evaluation["mean_return"])
    )


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_non_finite_action_stops_the_host_run_with_exit_code_3(monkeypatch, tmp_path, capsys):
    """A policy that turns NaN (its actor's output here) stops the run as a NaN loss does: one line
    saying where it came from, exit code 3, before the env ever receives it."""
    import dataclasses

    real = sac.make_agent

    def nan_acting(spec, cfg, **kwargs):
        agent = real(spec, cfg, **kwargs)

        def act(state, obs, key, progress):
            action, info = agent.act(state, obs, key, progress)
            return jnp.where(progress >= 250, jnp.nan, action), info

        return dataclasses.replace(agent, act=act)

    monkeypatch.setattr(sac, "make_agent", nan_acting)
    argv = ["train", "sac", "--env", "Pendulum-v1", "--runner", "host", "--total-steps", "400"]
    argv += ["--learning-starts", "200", "--hidden", "16", "16", "--out", str(tmp_path / "run")]
    assert main([*argv, "--no-progress"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith(
        "non-finite action from finite observations: lower the learning rate or clip the gradients"
    ), err
