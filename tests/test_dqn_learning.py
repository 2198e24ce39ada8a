"""DQN learns CartPole through both runners (fixed seeds, CI-sized); the lecture's episode schedule."""

import dataclasses

import jax
import numpy as np
import pytest

from agentax.agents import config_to_dict, dqn, presets
from agentax.agents.protocol import EnvSpec
from agentax.envs import make_jax
from agentax.envs.gym import GymnasiumEnv
from agentax.evaluate import host_episode_returns
from agentax.runners import host, session
from agentax.runners.compiled import RunnerConfig, compiled_program, train_program
from agentax.runs import Run, load_checkpoint, run_config

# The tuned preset, cut down: 16 learning steps per 64 env steps instead of 128 per 256, the target
# network synced every 128 learning steps.
SMALL = presets.preset(
    "dqn",
    "default",
    gradient_steps=16,
    train_frequency=16,
    target_update_period=128,
    total_steps=8_192,
).config


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_dqn_improves_on_the_compiled_runner_and_freezes():
    """From a near-random start to a greedy policy far above random (~22, see LECTURE-FACTS' basic
    policy at ~42); the seed freezes once 4 greedy side episodes each reach 150 and learns no more."""
    runner = RunnerConfig(
        seed=0, updates_per_chunk=32, eval_episodes=10, freeze_at_return=150.0, freeze_episodes=4
    )
    env = make_jax("CartPole-v1")
    result = train_program(compiled_program(dqn, env, SMALL, runner), env, runner)
    first, last = result.rows[0], result.rows[-1]
    assert last["env_steps"] == pytest.approx(8_192)
    assert first["mean_return"] < 40  # ε is still high in the first 2,048 steps
    assert result.eval["mean_return"] > 120, result.eval
    state = result.state
    assert bool(state.greedy.frozen[0]) and np.min(np.asarray(state.greedy.returns[0])) >= 150
    full_run = ((8_192 - 1_024) // 64 + 1) * 16  # learning phases from step 1,024 on, 16 steps each
    assert int(state.agent.step[0]) < full_run


def host_agent(env_id: str, cfg: dqn.DQNConfig):
    env = GymnasiumEnv(env_id, 1)
    spec = EnvSpec.of(env)
    env.close()
    return dqn.make_agent(spec, cfg)


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_dqn_improves_through_the_host_driver():
    agent = host_agent("CartPole-v1", SMALL)
    result = host.train(agent, "CartPole-v1", host.HostRunnerConfig(seed=0, log_every_steps=2_048))
    rows = result.rows
    assert [row["env_steps"] for row in rows] == [2_048, 4_096, 6_144, 8_192]
    # Learning phases after every 64 env steps from step 1,024 on: (8,192 − 1,024) / 64 + 1 = 113,
    # 16 learning steps each.
    assert result.updates == int(result.state.step) == 113 * 16
    assert [row["updates"] for row in rows] == [(1_024 // 64 + 1) * 16, 49 * 16, 81 * 16, 113 * 16]
    assert rows[0]["mean_return"] < 40 < 100 < rows[-1]["mean_return"]
    env = GymnasiumEnv("CartPole-v1", 8)
    returns, _ = host_episode_returns(env, agent.greedy_policy(result.state), 8, seed=123)
    assert returns.mean() > 100, returns  # Gymnasium's own CartPole, greedy policy
    assert result.eval["mean_return"] > 100, result.eval
    env.close()


@pytest.mark.timeout(240)
def test_lecture_schedule_counts_episodes(tmp_path):
    """The lecture: one learning step at the end of each episode once 50 are done; nothing after the last."""
    cfg = dataclasses.replace(presets.preset("dqn", "lecture").config, max_episodes=55, total_steps=2_000)
    env = make_jax("CartPole-v0")
    result = train_program(
        compiled_program(dqn, env, cfg), env, RunnerConfig(seed=0, updates_per_chunk=2_000, eval_episodes=1)
    )
    state = result.state
    assert int(state.episodes.completed[0]) == 55  # collection stopped after the 55th episode
    assert int(state.agent.step[0]) == 5  # episodes 51..55: one learning step each
    # ε = max(1 − episode/500, 0.01) is still ≥ 0.89 in these episodes: nearly random, short episodes,
    # and the env steps stop counting with the 55th.
    assert 55 * 8 < int(state.episodes.env_steps[0]) < 55 * 60
    # The host runner: the same schedule, episodes counted by the Driver's observers.
    agent = host_agent("CartPole-v0", cfg)
    runner = host.HostRunnerConfig(seed=0, log_every_steps=10_000, eval_episodes=1)
    run = Run.create(
        tmp_path / "host",
        run_config("dqn", "CartPole-v0", "lecture", "host", runner, config_to_dict(cfg)),
    )
    result = host.train(agent, "CartPole-v0", runner, run)
    assert result.updates == int(result.state.step) == 5
    _, meta, _ = load_checkpoint(run.path, session.checkpoint_target(agent))
    assert meta["episodes"] == 55 and meta["updates"] == 5 and meta["env_steps"] == result.env_steps
    assert 55 * 8 < result.env_steps < 55 * 60


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
@pytest.mark.timeout(240)
def test_lecture_schedule_in_a_batch_learns_exactly_as_alone():
    """Seeds end episodes at different steps: in a vmapped batch the learning branch runs when any
    seed is due (``any_seed``) and keeps its result only for the due ones, so each seed learns as alone."""
    cfg = dataclasses.replace(
        presets.preset("dqn", "lecture").config,
        learning_starts=5,
        gradient_steps=3,
        max_episodes=12,
        total_steps=800,
    )
    env = make_jax("CartPole-v0")
    runner = RunnerConfig(seed=0, num_seeds=3, updates_per_chunk=800, eval_episodes=1)
    batch = train_program(compiled_program(dqn, env, cfg), env, runner).state
    alone = train_program(
        compiled_program(dqn, env, cfg), env, dataclasses.replace(runner, seed=1, num_seeds=1)
    ).state
    assert [int(n) for n in batch.episodes.completed] == [12, 12, 12]
    assert [int(n) for n in batch.agent.step] == [21, 21, 21]  # episodes 6..12 end: 7 phases of 3 steps
    for in_batch, by_itself in zip(
        jax.tree.leaves(jax.tree.map(lambda x: x[1], batch.agent)), jax.tree.leaves(alone.agent), strict=True
    ):
        # equal up to the last bits that XLA's batched kernels (3 seeds vs 1) round differently
        np.testing.assert_allclose(np.asarray(in_batch), np.asarray(by_itself[0]), rtol=1e-5, atol=1e-6)
