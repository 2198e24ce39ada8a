"""Observation and reward normalisation: the running statistics against numpy, the reward scale by
hand, and PPO carrying them in its state (learn updates them, the greedy policy reads them, a
checkpoint keeps them, the compiled runner's program runs them)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agentax
from agentax import export
from agentax import normalize as running
from agentax.agents import ppo
from agentax.agents.presets import DEFAULT_PRESETS, preset
from agentax.agents.protocol import EnvSpec, acting_view
from agentax.envs.core import Box
from agentax.errors import UsageError
from agentax.replay import Transition

SPEC = EnvSpec((3,), Box(low=-2.0, high=2.0, shape=(1,)))
SMALL = dict(num_envs=2, num_steps=8, num_minibatches=2, update_epochs=1)


@pytest.mark.parametrize("wrap", [lambda f: f, jax.jit], ids=["plain", "jit"])
def test_running_stats_equal_numpy_over_every_batch_seen(wrap):
    rng = np.random.default_rng(0)
    batches = [
        rng.normal(loc=[1.0, -3.0], scale=[0.5, 4.0], size=(n, 2)).astype(np.float32) for n in (7, 50, 1, 30)
    ]
    update = wrap(running.update)
    stats = running.init((2,))
    for batch in batches:
        stats = update(stats, jnp.asarray(batch))
    seen = np.concatenate(batches).astype(np.float64)  # 88 samples; the 1e-4 prior moves them < 1e-5
    np.testing.assert_allclose(stats.mean, seen.mean(axis=0), atol=1e-5)
    np.testing.assert_allclose(stats.var, seen.var(axis=0), atol=1e-5, rtol=1e-5)
    assert float(stats.count) == pytest.approx(88 + running.INITIAL_COUNT)
    assert stats.mean.dtype == stats.var.dtype == stats.count.dtype == jnp.float32


@pytest.mark.slow
def test_a_mask_merges_only_the_samples_it_marks():
    rng = np.random.default_rng(1)
    batch = rng.normal(size=(40, 3)).astype(np.float32)
    mask = rng.random(40) < 0.6
    masked = running.update(running.init((3,)), jnp.asarray(batch), jnp.asarray(mask))
    kept = running.update(running.init((3,)), jnp.asarray(batch[mask]))
    for got, want in zip(jax.tree.leaves(masked), jax.tree.leaves(kept), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
    nothing = running.update(masked, jnp.asarray(batch), jnp.zeros(40, bool))
    for got, want in zip(jax.tree.leaves(nothing), jax.tree.leaves(masked), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-6)


def test_normalize_standardises_and_clips():
    stats = running.RunningMeanStd(jnp.array([1.0, -2.0]), jnp.array([4.0, 0.25]), jnp.float32(10))
    # (3 - 1) / 2 = 1; (-2 - -2) / 0.5 = 0; (100 - 1) / 2 = 49.5 → 10; (-10 + 2) / 0.5 = -16 → -10
    got = running.normalize(stats, jnp.array([[3.0, -2.0], [100.0, -10.0]]), clip=10.0)
    np.testing.assert_allclose(got, [[1.0, 0.0], [10.0, -10.0]], rtol=1e-6)


def _rollout(reward, terminated, truncated, obs=None, info=None) -> Transition:
    T, E = reward.shape
    obs = jnp.zeros((T, E, 3)) if obs is None else obs
    return Transition(
        obs=obs,
        action=jnp.zeros((T, E, 1)),
        reward=reward,
        next_obs=obs,
        terminated=terminated,
        truncated=truncated,
        num_steps=jnp.ones((T, E), jnp.int32),
        info={"log_prob": jnp.zeros((T, E))} if info is None else info,
    )


@pytest.mark.slow
def test_rewards_are_scaled_by_the_std_of_the_discounted_return_hand_computed():
    # One env, γ = 0.5, rewards [1, 2, 3, 4], the episode ends (truncated) after step 1:
    #   R_0 = 1,  R_1 = 0.5·1 + 2 = 2.5 (then reset),  R_2 = 3,  R_3 = 0.5·3 + 4 = 5.5
    # mean 3, variance ((−2)² + (−0.5)² + 0² + 2.5²) / 4 = 10.5 / 4 = 2.625; merged with the prior
    # (mean 0, variance 1, count 1e-4): (1e-4·1 + 4·2.625 + 3²·1e-4·4 / 4.0001) / 4.0001
    n = 4 + running.INITIAL_COUNT
    var = (running.INITIAL_COUNT * 1.0 + 4 * 2.625 + 9.0 * running.INITIAL_COUNT * 4 / n) / n
    cfg = ppo.PPOConfig(
        num_envs=1, num_steps=4, num_minibatches=1, discount_factor=0.5, normalize_rewards=True
    )
    agent = ppo.init(jax.random.key(0), SPEC, cfg)
    reward = jnp.array([[1.0], [2.0], [3.0], [4.0]])
    ended = jnp.array([[False], [True], [False], [False]])
    rollout = _rollout(reward, jnp.zeros((4, 1), bool), ended)
    agent, seen = ppo.take_in(agent, rollout, cfg)
    np.testing.assert_allclose(agent.return_stats.var, var, rtol=1e-6)
    np.testing.assert_allclose(seen.reward, reward / np.sqrt(var + 1e-8), rtol=1e-6)
    np.testing.assert_allclose(agent.discounted_return, [5.5])  # no end after step 3: carried on
    # the next rollout goes on from 5.5: R = 0.5·5.5 + 1 = 3.75, and a termination resets it too
    agent, _ = ppo.take_in(
        agent, _rollout(jnp.ones((1, 1)), jnp.ones((1, 1), bool), jnp.zeros((1, 1), bool)), cfg
    )
    np.testing.assert_allclose(agent.discounted_return, [0.0])
    _, returns = running.discounted_returns(jnp.array([5.5]), jnp.ones((1, 1)), jnp.ones((1, 1), bool), 0.5)
    np.testing.assert_allclose(returns, [[3.75]])
    clipped = dataclasses.replace(cfg, reward_clip=0.5)
    _, seen = ppo.take_in(ppo.init(jax.random.key(0), SPEC, clipped), rollout, clipped)
    assert float(jnp.max(seen.reward)) == pytest.approx(0.5)


def test_without_normalisation_the_state_and_the_rollout_are_as_before():
    cfg = ppo.PPOConfig(**SMALL)
    agent = ppo.init(jax.random.key(0), SPEC, cfg)
    assert agent.obs_stats is None and agent.return_stats is None and agent.discounted_return is None
    rollout = _rollout(jnp.arange(16.0).reshape(8, 2), jnp.zeros((8, 2), bool), jnp.zeros((8, 2), bool))
    same, seen = ppo.take_in(agent, rollout, cfg)
    assert same is agent and seen is rollout


@pytest.mark.slow
def test_ppo_learn_updates_the_stats_and_the_greedy_policy_reads_them():
    cfg = ppo.PPOConfig(**SMALL, normalize_observations=True, normalize_rewards=True)
    agent = ppo.make_agent(SPEC, cfg)
    state = agent.init(jax.random.key(0))
    obs = jax.random.normal(jax.random.key(1), (8, 2, 3)) * jnp.array([1.0, 5.0, 0.1]) + 3.0
    rollout = _rollout(
        jax.random.normal(jax.random.key(2), (8, 2)), jnp.zeros((8, 2), bool), jnp.zeros((8, 2), bool), obs
    )
    learned, metrics = jax.jit(agent.learn)(state, rollout, jax.random.key(3))
    assert all(np.isfinite(float(v)) for v in metrics.values())
    np.testing.assert_allclose(learned.obs_stats.mean, obs.reshape(16, 3).mean(axis=0), rtol=1e-4)
    # the prior (mean 0, variance 1, weight 1e-4) adds ~1e-4 · (1 + 3²) / 16 ≈ 6e-5 to each variance
    np.testing.assert_allclose(learned.obs_stats.var, obs.reshape(16, 3).var(axis=0), rtol=1e-4, atol=1e-4)
    assert float(learned.return_stats.count) == pytest.approx(16 + running.INITIAL_COUNT)
    # the greedy policy standardises with the state's statistics: other statistics, another action
    x = jnp.array([3.0, 8.0, 3.1])
    action = agent.greedy_policy(learned)(x, None)
    shifted = learned.replace(obs_stats=learned.obs_stats.replace(mean=learned.obs_stats.mean + 1.0))
    assert not np.allclose(action, agent.greedy_policy(shifted)(x, None))
    raw = ppo.greedy_policy(learned.params, SPEC, cfg)  # the same parameters on raw observations
    assert not np.allclose(action, raw(x, None))
    standardized = running.normalize(learned.obs_stats, x, cfg.observation_clip)
    np.testing.assert_allclose(action, raw(standardized, None), rtol=1e-6)
    # the actors' view keeps what act reads (the Ray runner ships only that)
    view = acting_view(learned)
    assert view.opt_state is None and view.obs_stats is not None
    key, batch = jax.random.key(4), x[None]
    np.testing.assert_array_equal(agent.act(learned, batch, key, 0)[0], agent.act(view, batch, key, 0)[0])
    assert not np.allclose(agent.act(learned, batch, key, 0)[0], agent.act(shifted, batch, key, 0)[0])


def test_stats_get_no_gradient_and_frames_are_refused():
    cfg = ppo.PPOConfig(**SMALL, normalize_observations=True)
    state = ppo.init(jax.random.key(0), SPEC, cfg)
    assert jax.tree.structure(ppo.optimizer(cfg).init(state.params)) == jax.tree.structure(state.opt_state)
    with pytest.raises(UsageError, match="flat observations"):
        ppo.make_agent(EnvSpec((4, 84, 84), SPEC.action_space, jnp.uint8), cfg)
    with pytest.raises(UsageError, match="observation_clip"):
        ppo.PPOConfig(observation_clip=0.0).validate()


def test_the_mujoco_preset_is_cleanrls_and_the_v5_tasks_pick_it():
    cfg = preset("ppo", "mujoco").config
    assert (cfg.total_steps, cfg.num_envs, cfg.num_steps, cfg.num_minibatches, cfg.update_epochs) == (
        1_000_000,
        1,
        2048,
        32,
        10,
    )
    assert (cfg.learning_rate, cfg.anneal_lr, cfg.discount_factor, cfg.gae_lambda) == (3e-4, True, 0.99, 0.95)
    assert (cfg.clip_eps, cfg.ent_coef, cfg.vf_coef, cfg.max_grad_norm) == (0.2, 0.0, 0.5, 0.5)
    assert (cfg.hidden, cfg.activation) == ((64, 64), "tanh")
    assert cfg.normalize_observations and cfg.normalize_rewards
    assert (cfg.observation_clip, cfg.reward_clip) == (10.0, 10.0)
    for task in ("HalfCheetah", "Hopper", "Walker2d", "Ant", "Humanoid"):
        assert DEFAULT_PRESETS["ppo"][f"{task}-v5"] == "mujoco"
    pendulum = preset("ppo", "pendulum").config  # untouched: no normalisation
    assert not pendulum.normalize_observations and not pendulum.normalize_rewards
    assert (pendulum.num_envs, pendulum.num_steps, pendulum.discount_factor) == (4, 512, 0.9)


def _observations(n: int = 5) -> jax.Array:
    rng = np.random.default_rng(7)
    return jnp.asarray(rng.uniform(-1.0, 1.0, size=(n, 3)) * [1.0, 1.0, 8.0], jnp.float32)  # cos, sin, θ'


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_host_checkpoint_saves_and_restores_the_stats(tmp_path):
    from agentax.runners.host import restore
    from agentax.runners.session import checkpoint_target
    from agentax.runs import load_checkpoint

    run = agentax.train(
        "ppo",
        env="Pendulum-v1",
        runner="host",
        preset="default",
        total_steps=256,
        progress=False,
        out=tmp_path / "run",
        **SMALL | {"num_steps": 64},
        normalize_observations=True,
        normalize_rewards=True,
    )
    state = run.result.state
    assert float(state.obs_stats.count) == pytest.approx(256 + running.INITIAL_COUNT)
    assert float(state.return_stats.count) == pytest.approx(256 + running.INITIAL_COUNT)
    cfg = ppo.PPOConfig(
        **SMALL | {"num_steps": 64}, total_steps=256, normalize_observations=True, normalize_rewards=True
    )
    spec = EnvSpec((3,), Box(low=-2.0, high=2.0, shape=(1,)))
    agent = ppo.make_agent(spec, cfg)
    (saved, _), _, _ = load_checkpoint(run.path, checkpoint_target(agent))
    for got, want in zip(jax.tree.leaves(saved), jax.tree.leaves(state), strict=True):
        np.testing.assert_array_equal(got, want)
    obs = _observations()
    loaded = jax.vmap(agentax.load(run.path).policy, in_axes=(0, None))(obs, jax.random.key(0))
    np.testing.assert_array_equal(loaded, jax.vmap(agent.greedy_policy(state), in_axes=(0, None))(obs, None))
    np.testing.assert_array_equal(
        loaded, jax.vmap(restore(run.path, {}, agent), in_axes=(0, None))(obs, None)
    )
    fresh_stats = state.replace(obs_stats=running.init((3,)))
    assert not np.allclose(loaded, jax.vmap(agent.greedy_policy(fresh_stats), in_axes=(0, None))(obs, None))
    # the exported file computes the same: the statistics are constants of its program
    exported = export.load(run.export(tmp_path / "policy.stablehlo", "stablehlo")).run(np.asarray(obs))
    np.testing.assert_allclose(exported, loaded, rtol=0, atol=1e-5)


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_compiled_runner_runs_normalised_ppo_and_restores_its_stats(tmp_path):
    run = agentax.train(
        "ppo",
        env="gymnax/Pendulum-v1",
        runner="compiled",
        preset="default",
        seeds=2,
        total_steps=256,
        progress=False,
        out=tmp_path / "run",
        **SMALL | {"num_steps": 64},
        normalize_observations=True,
        normalize_rewards=True,
    )
    rows = run.metrics
    assert rows and all(np.isfinite(r["value_loss"]) for r in rows)
    state = run.result.state
    is_stats = lambda x: isinstance(x, running.RunningMeanStd)  # noqa: E731
    found = [leaf for leaf in jax.tree.leaves(state, is_leaf=is_stats) if is_stats(leaf)]
    assert len(found) == 2  # the observations' and the returns', a seed axis each
    for stats in found:
        np.testing.assert_allclose(stats.count, [256 + running.INITIAL_COUNT] * 2, rtol=1e-6)
    obs = _observations()
    loaded = jax.vmap(agentax.load(run.path).policy, in_axes=(0, None))(obs, jax.random.key(0))
    np.testing.assert_array_equal(loaded, jax.vmap(run.policy, in_axes=(0, None))(obs, jax.random.key(0)))


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_compiled_mujoco_picks_the_preset_and_leaves_envpools_reset_steps_out_of_the_stats(tmp_path):
    """EnvPool's Hopper-v5 inside the program (``--preset auto``: mujoco, both normalisers on), 4 envs
    × 64 steps, two updates: an untrained Hopper falls within ~20-80 steps, so some of the 512 steps
    are EnvPool's reset steps, which the statistics do not count."""
    pytest.importorskip("envpool")
    pytest.importorskip("mujoco")
    run = agentax.train(
        "ppo",
        env="Hopper-v5",
        runner="compiled",
        total_steps=512,
        progress=False,
        out=tmp_path / "run",
        **SMALL | {"num_envs": 4, "num_steps": 64},
    )
    assert run.config["preset"] == "mujoco"
    state = run.result.state
    for stats in (state.obs_stats, state.return_stats):
        assert 0.8 * 512 < float(stats.count) < 512  # valid steps only
        assert float(stats.count) == float(state.obs_stats.count)
    assert np.isfinite(np.asarray(state.obs_stats.var)).all() and float(state.return_stats.var) > 0
