"""The run logger's guards, through ``agentax train``: a diverged run stops with one line and exit
code 3 keeping only finite checkpoints, a damaged checkpoint is skipped on --resume, and Ctrl-C says
how to continue."""

from __future__ import annotations

import dataclasses
import datetime
import functools
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.agents import config_to_dict, ppo, presets
from agentax.agents.protocol import EnvSpec
from agentax.cli import main
from agentax.envs import make_host_env
from agentax.errors import TrainingDiverged
from agentax.runners import host
from agentax.runners.host import HostRunnerConfig
from agentax.runners.logger import time_left
from agentax.runners.session import Session, checkpoint_target
from agentax.runs import Run, checkpoints, load_checkpoint, read_config, read_metrics, run_config

DIVERGED = re.compile(
    r"^agentax train: error: non-finite (\w+) at env step ([\d,]+): lower the learning rate or clip the "
    r"gradients \(--max-grad-norm\)"
)


def make_agent(module, cfg):
    env = make_host_env("CartPole-v1", 1)
    spec = EnvSpec.of(env)
    env.close()
    return module.make_agent(spec, cfg)


def assert_checkpoints_finite(run_dir, agent):
    """Every checkpoint left in ``run_dir`` loads, with finite parameters (the newest first)."""
    (state, _), meta, _ = load_checkpoint(run_dir, checkpoint_target(agent))
    for leaf in jax.tree.leaves(state):
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            assert np.all(np.isfinite(np.asarray(leaf)))
    return meta


# ---------------------------------------------------------------- non-finite guard


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    ("algo", "runner", "metric", "steps"),
    [
        # lr 1e30: Adam's first steps (≈ lr per weight, whatever the gradient clipping) overflow the net
        ("ppo", "host", "approx_kl", (2048, 2048)),  # the first row, after 8 iterations of 8 × 32 steps
        ("ppo", "compiled", "approx_kl", (2560, 2560)),  # the first chunk of 10 iterations
        # the first row, at 2,048 steps or a few batches later: the actor thread may have run ahead
        # of the learner by then (a fresh-clone CI run caught it at 2,176)
        ("dqn", "parallel", "loss", (2048, 4096)),
    ],
)
def test_a_diverging_run_stops_with_one_line_and_exit_code_3(tmp_path, capsys, algo, runner, metric, steps):
    out = tmp_path / "run"
    argv = ["train", algo, "--env", "CartPole-v1", "--runner", runner, "--learning-rate", "1e30"]
    assert main([*argv, "--total-steps", "4096", "--seed", "0", "--out", str(out), "--no-progress"]) == 3
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("agentax")]
    assert len(lines) == 1, lines
    match = DIVERGED.match(lines[0])
    assert match, lines[0]
    assert match.group(1) == metric
    assert steps[0] <= int(match.group(2).replace(",", "")) <= steps[1]
    # the first row diverged: nothing non-finite was ever written
    assert checkpoints(out) == []


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_only_finite_parameters_are_checkpointed(tmp_path):
    """Parameters turned NaN after the 4th iteration: the run stops at the next checkpoint and the
    folder keeps the last finite one (a checkpoint at every row of 256 steps)."""
    cfg = dataclasses.replace(presets.preset("ppo", "cartpole-fast").config, total_steps=4_096)
    agent = make_agent(ppo, cfg)

    def poisoned_learn(state, rollout, key):
        state, metrics = agent.learn(state, rollout, key)
        poison = jnp.where(state.updates > 4, jnp.nan, 0.0)
        return state.replace(params=jax.tree.map(lambda p: p + poison, state.params)), metrics

    runner = HostRunnerConfig(seed=0, log_every_steps=256, checkpoint_every_seconds=0.0, eval_episodes=1)
    run = Run.create(tmp_path / "run", run_config("ppo", "CartPole-v1", "cartpole-fast", "host", runner, {}))
    with pytest.raises(TrainingDiverged) as raised:
        host.train(dataclasses.replace(agent, learn=poisoned_learn), "CartPole-v1", runner, run)
    assert str(raised.value).startswith("non-finite parameters at env step 1,280: ")
    assert str(raised.value).endswith("; the run keeps its last finite checkpoint ckpt-4.msgpack")
    assert [p.name for p in checkpoints(run.path)] == ["ckpt-2.msgpack", "ckpt-3.msgpack", "ckpt-4.msgpack"]
    assert assert_checkpoints_finite(run.path, agent)["env_steps"] == 1_024


# ---------------------------------------------------------------- checkpoint fallback on --resume


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_resume_skips_a_damaged_checkpoint(tmp_path, capsys):
    cfg = dataclasses.replace(presets.preset("ppo", "cartpole-fast").config, total_steps=2_048)
    agent = make_agent(ppo, cfg)
    runner = HostRunnerConfig(seed=0, log_every_steps=512, checkpoint_every_seconds=0.0, eval_episodes=2)
    config = run_config("ppo", "CartPole-v1", "cartpole-fast", "host", runner, config_to_dict(cfg))
    run = Run.create(tmp_path / "run", config)
    host.train(agent, "CartPole-v1", runner, run)
    found = checkpoints(run.path)
    assert [p.name for p in found] == ["ckpt-4.msgpack", "ckpt-6.msgpack", "ckpt-8.msgpack"]
    newest = found[-1]
    newest.write_bytes(newest.read_bytes()[:100])  # cut short, as by a full disk
    capsys.readouterr()

    assert main(["train", "--resume", str(run.path), "--no-progress"]) == 0
    captured = capsys.readouterr()
    warnings = [line for line in captured.err.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1, captured.err
    assert warnings[0].startswith(f"warning: skipping damaged checkpoint {newest} (")
    assert warnings[0].endswith(f"); using {found[-2]}")
    assert "evaluation: mean return" in captured.out
    # continued from 1,536 env steps: metrics.csv trimmed there, then the last row written again
    assert [row["env_steps"] for row in read_metrics(run.path)] == [512, 1024, 1536, 2048]


# ---------------------------------------------------------------- Ctrl-C


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_ctrl_c_says_how_to_resume_and_resume_works(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    # a checkpoint at every row of 256 env steps (the CLI has no flag for the interval)
    monkeypatch.setattr(
        host,
        "HostRunnerConfig",
        functools.partial(HostRunnerConfig, log_every_steps=256, checkpoint_every_seconds=0.0),
    )
    rollout = host.Actor.rollout
    calls = []

    def interrupted_rollout(self, state, num_steps):
        calls.append(num_steps)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return rollout(self, state, num_steps)

    monkeypatch.setattr(host.Actor, "rollout", interrupted_rollout)
    argv = ["train", "ppo", "--env", "CartPole-v1", "--runner", "host", "--total-steps", "2048"]
    assert main([*argv, "--num-envs", "4", "--num-steps", "64", "--out", str(out), "--no-progress"]) == 130
    err = capsys.readouterr().err.splitlines()
    assert err[-1] == f"agentax train: interrupted; continue with: agentax train --resume {out}"
    assert [p.name for p in checkpoints(out)] == ["ckpt-1.msgpack", "ckpt-2.msgpack"]
    assert read_config(out)["runner"]["checkpoint_every_seconds"] == 0.0

    monkeypatch.setattr(host.Actor, "rollout", rollout)
    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert "evaluation: mean return" in capsys.readouterr().out
    assert [row["env_steps"] for row in read_metrics(out)] == [256 * i for i in range(1, 9)]
    assert [p.name for p in checkpoints(out)] == ["ckpt-6.msgpack", "ckpt-7.msgpack", "ckpt-8.msgpack"]


def test_the_progress_bar_says_how_long_a_run_has_left_and_when_it_ends():
    """Breakout at 142 steps/s after 8,192 of 10,000,000 env steps: (10,000,000 - 8,192) / 142 =
    70,364.8 s, so 19 h 32 min 45 s left, ending the next morning."""
    noon = datetime.datetime(2026, 12, 1, 12, 0).timestamp()
    assert time_left(10_000_000, 8_192, 142.0, now=noon) == "left 19:32:45, ends Dec 02 07:32"
    assert time_left(1_000, 400, 60.0, now=noon) == "left 0:00:10, ends 12:00"
    assert time_left(1_000, 1_000, 60.0, now=noon) == "left 0:00:00, ends 12:00"
    assert time_left(1_000, 0, 0.0) == time_left(1_000, 0, float("nan")) == ""  # no speed yet


class ScriptedEvaluator:
    """Row evaluations (the default seed) at 500; the final evaluation's (``seed=...``) from a list."""

    def __init__(self, finals: list[float]):
        self.finals, self.final_seeds = finals, []

    def __call__(self, state, seed=None):
        value = 500.0 if seed is None else self.finals.pop(0)
        self.final_seeds += [] if seed is None else [seed]
        return np.full(10, value), np.full(10, 500)

    def close(self):
        pass


def test_a_run_is_solved_only_when_its_final_evaluation_agrees(tmp_path):
    """The row's evaluation passes stop_at_return at both rows; the final evaluation (fresh episodes)
    does not at the first, so the run trains on; at the second it does: the run stops solved there and
    that evaluation is eval.json's, not evaluated once more (issue 30: 'solved', then 470.7)."""
    agent = make_agent(ppo, presets.preset("ppo", "cartpole-fast").config)
    runner = HostRunnerConfig(seed=3, stop_at_return=475.0)
    evaluator = ScriptedEvaluator([470.7, 480.0])
    session = Session(agent, Run.create(tmp_path, {"algo": "ppo", "env": "CartPole-v1"}), runner, evaluator)
    with session.begin("test"):
        rows = [
            session.log_row(session.state, session.learner_key, steps, 1, [500.0], {}, final=False)
            for steps in (512, 1024)
        ]
        result = session.finish(session.state, 1024, 2)
    assert rows == [False, True]
    assert evaluator.finals == [] and len(set(evaluator.final_seeds)) == 1  # the same fresh episodes
    assert (result.solved_env_steps, result.eval["mean_return"]) == (1024, 480.0)
    assert [row["eval_return"] for row in read_metrics(tmp_path)] == [500.0, 500.0]
