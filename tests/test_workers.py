"""The compiled runner's seeds split over worker processes (``--workers N``, agentax.runners.workers)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import resume_to_the_end, with_sigint_ignored

import agentax
from agentax.cli import main
from agentax.runners import workers
from agentax.runners.compiled import RunnerConfig
from agentax.runners.workers import merge_rows, split
from agentax.runs import read_metrics

NAN = math.nan


def test_the_seeds_split_into_contiguous_slices_one_worker_each():
    parts = split(RunnerConfig(seed=5, num_seeds=5, workers=2, eval_episodes=3))
    assert [(p.seed, p.num_seeds, p.workers, p.eval_episodes) for p in parts] == [(5, 3, 1, 3), (8, 2, 1, 3)]
    assert [p.num_seeds for p in split(RunnerConfig(num_seeds=2, workers=4))] == [1, 1]


def test_merged_rows_renumber_the_seeds_and_weight_the_means_by_them():
    first = [
        {"env_steps": 10, "mean_return": 2, "return_seed0": 1, "return_seed1": 3, "eval_return": 6}
        | {"eval_seed0": 4, "eval_seed1": 8, "steps_per_second": 100, "wall_seconds": 1, "loss": 1},
        {"env_steps": 20, "mean_return": 9, "return_seed0": 9, "return_seed1": NAN, "eval_return": NAN}
        | {"eval_seed0": NAN, "eval_seed1": NAN, "steps_per_second": 50, "wall_seconds": 2, "loss": 1},
    ]
    second = [
        {"env_steps": 10, "mean_return": 5, "return_seed0": 5, "eval_return": 9, "eval_seed0": 9}
        | {"steps_per_second": 40, "wall_seconds": 3, "loss": 4}
    ]
    rows = merge_rows([first, second], [2, 1])
    assert list(rows[0]) == [
        "env_steps",
        "mean_return",
        *("return_seed0", "return_seed1", "return_seed2"),
        "eval_return",
        *("eval_seed0", "eval_seed1", "eval_seed2"),
        *("steps_per_second", "wall_seconds", "loss"),
    ]
    assert rows[0]["mean_return"] == 3 and rows[0]["return_seed2"] == 5  # (1 + 3 + 5) / 3
    assert rows[0]["eval_return"] == 7 and rows[0]["eval_seed2"] == 9
    assert rows[0]["loss"] == 2 and rows[0]["steps_per_second"] == 80  # (2 × 1 + 4) / 3, (200 + 40) / 3
    assert rows[0]["wall_seconds"] == 3 and rows[0]["env_steps"] == 10
    # the second worker stopped first: the row holds the first one's seeds only
    assert (
        rows[1]["mean_return"] == 9 and "return_seed2" not in rows[1] and math.isnan(rows[1]["eval_return"])
    )


def test_workers_refuse_a_runner_that_trains_one_seed(capsys):
    host = ["train", "ppo", "--env", "CartPole-v1", "--runner", "host", "--workers", "2", "--out", "unused"]
    assert main(host) == 2
    assert "--workers splits the compiled runner's seeds" in capsys.readouterr().err
    assert main(["train", "ppo", "--workers", "0"]) == 2
    assert "--workers must be at least 1, got 0" in capsys.readouterr().err


def test_every_core_by_default_once_the_run_reaches_the_break_even(monkeypatch):
    monkeypatch.setattr(workers, "usable_cores", lambda: 2)
    below, at = workers.BREAK_EVEN_FLOPS * 0.999, workers.BREAK_EVEN_FLOPS
    assert [workers.default_count(8, below), workers.default_count(8, at)] == [1, 2]
    assert workers.default_count(8, lambda: at) == 2  # the cost asked for where it decides
    assert workers.default_count(1, 10 * at) == 1  # never more workers than seeds (or settings)
    monkeypatch.setattr(workers, "usable_cores", lambda: 1)
    assert workers.default_count(8, 10 * at) == 1


def test_the_cost_counts_every_step_of_every_scan_which_xlas_count_takes_once():
    import jax
    import jax.numpy as jnp

    from agentax.runners import cost

    def inner(c, _):
        return c @ c, None

    def outer(c, _):
        return jax.lax.scan(inner, c, None, length=4)[0], None

    def matmuls(x):  # 3 × 4 nested steps of one [64, 64] product each, and one more outside
        return jax.lax.scan(outer, x, None, length=3)[0] @ x

    closed = jax.make_jaxpr(matmuls)(jnp.ones((64, 64)))
    one = 2 * 64**3  # a [64, 64] @ [64, 64] product's multiply-adds
    assert cost.xla_flops(closed) == pytest.approx(2 * one, rel=0.01)  # XLA: each body once
    assert cost.flops(closed) == pytest.approx(13 * one, rel=0.01)


@pytest.mark.slow
def test_the_split_follows_the_programs_cost_not_its_steps(monkeypatch):
    """Two seeds of 1M steps (2M agent steps, half the old step rule's break-even): PPO's default
    64-64 CartPole program costs too little to gain from a second core (its calibration: XLA's
    flops per step as :data:`workers.PPO_CARTPOLE_FLOPS_PER_STEP`), the same with 256-256 networks
    (~15× the flops) gets both cores."""
    import functools

    from agentax.agents import ppo
    from agentax.agents.presets import PPO_PRESETS
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_jax
    from agentax.runners import cost
    from agentax.runners.compiled import program_of

    monkeypatch.setattr(workers, "usable_cores", lambda: 2)
    env = make_jax("CartPole-v1")
    chosen, per_step = {}, {}
    for hidden in ((64, 64), (256, 256)):
        cfg = dataclasses.replace(PPO_PRESETS["default"].config, hidden=hidden, total_steps=1_000_000)
        program = program_of(ppo.make_agent(EnvSpec.of(env), cfg), env)
        seed_flops = functools.cache(functools.partial(cost.program_flops, program))
        chosen[hidden] = workers.default_for(2, seed_flops, None)
        per_step[hidden] = seed_flops() / cfg.total_steps
    assert per_step[(64, 64)] == pytest.approx(workers.PPO_CARTPOLE_FLOPS_PER_STEP, rel=0.02)
    assert per_step[(256, 256)] > 10 * per_step[(64, 64)]
    assert chosen == {(64, 64): 1, (256, 256): 2}


def test_the_chosen_split_is_announced_in_one_line(monkeypatch):
    from agentax import runfile
    from agentax.agents import algorithm
    from agentax.agents.presets import PPO_PRESETS
    from agentax.runners import launch

    monkeypatch.setattr(workers, "usable_cores", lambda: 2)
    preset = PPO_PRESETS["default"]
    steps = workers.BREAK_EVEN_AGENT_STEPS // 2  # 4 seeds: 8M PPO CartPole steps, twice the break-even

    def prepared(**given):
        run_args = runfile.RunArgs(**{"seeds": 4, "stop_at_return": "none", **given}).check()
        cfg = dataclasses.replace(preset.config, total_steps=steps)
        return launch.prepare(algorithm("ppo"), run_args, cfg, preset, "compiled")

    chosen = prepared()
    assert chosen.runner.workers == 2
    assert chosen.where == "4 seeds over 2 worker processes, one per core; --workers 1 keeps one process"
    assert prepared(workers=1).where == "4 seeds"
    assert prepared(workers=2).where == "4 seeds over 2 worker processes"
    # a run that stops at a return may end at any time, and a split would stop each worker apart
    assert prepared(stop_at_return="400").runner.workers == 1


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
@pytest.mark.slow
@pytest.mark.timeout(300)
def test_seeds_over_two_workers_survive_sigterm_and_resume_to_the_numbers_of_an_uninterrupted_run(tmp_path):
    """Fault injection by the path users take: ``agentax train --seeds 3 --workers 2``, SIGTERM at
    the first checkpoint of either worker (the run started with SIGINT ignored, as ``nohup ... &``
    starts it: the workers still stop on the parent's SIGINT), ``agentax train --resume``; then every seed's
    curve and final evaluation equal an uninterrupted run's, and the run's policy (its best seed's
    worker) plays.
    (Against one process of 3 seeds they agree only at first: XLA's program for a batch of 1 or 2
    seeds rounds differently from the one for 3, and over 300 updates a seed's episodes part.)"""
    out, total = tmp_path / "run", 160 * 512  # 160 updates of PPO's default 4 envs × 128 steps
    env = {**os.environ, "AGENTAX_JAX_CACHE": str(tmp_path / "cache")}
    flags = ["--preset", "default", "--seeds", "3", "--total-steps", str(total), "--stop-at-return", "none"]
    command = [sys.executable, "-m", "agentax.cli", "train", "ppo", *flags, "--workers", "2"]
    process = subprocess.Popen(
        with_sigint_ignored([*command, "--out", str(out), "--no-progress"]),
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 200
        while process.poll() is None and not list(out.glob("worker-*/checkpoints/ckpt-*.msgpack")):
            assert time.monotonic() < deadline, "the workers wrote no checkpoint"
            time.sleep(0.02)
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=100)
    finally:
        process.kill()
    assert process.returncode == 143, err[-2000:].decode()
    assert f"continue with: agentax train --resume {out}" in err.decode()
    assert not (out / "eval.json").exists(), "the run finished before SIGTERM reached it"
    assert not list(out.glob("worker-*/final-returns.json")), "a worker did not stop on the interrupt"
    resume_to_the_end(out, env, timeout=200)

    alone = agentax.train(  # the same split, never interrupted
        "ppo",
        preset="default",
        seeds=3,
        workers=2,
        total_steps=total,
        stop_at_return="none",
        out=tmp_path / "one",
    )
    split_rows, one_rows = read_metrics(out), read_metrics(alone.path)
    assert [r["env_steps"] for r in split_rows] == [r["env_steps"] for r in one_rows]
    columns = [f"{p}{k}" for p in ("return_seed", "eval_seed") for k in range(3)]
    np.testing.assert_allclose(
        [[r[c] for c in columns] for r in split_rows], [[r[c] for c in columns] for r in one_rows], rtol=1e-5
    )
    finals = json.loads((out / "eval.json").read_text())
    assert finals["workers"] == 2 and finals["episodes"] == alone.final_eval["episodes"]
    assert [s["mean_return"] for s in finals["per_seed"]] == [
        s["mean_return"] for s in alone.final_eval["per_seed"]
    ]
    assert agentax.load(out).evaluate(episodes=2).episodes == 2


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_packed_masked_dict_observations_train_over_two_worker_processes(tmp_path):
    """Tic-tac-toe's Dict observation with its mask on the compiled runner, 2 seeds over 2 worker
    processes for a few updates: every seed's evaluation, a tic-tac-toe return in [-1, 1]."""
    run = agentax.train(
        "ppo",
        env="TicTacToe-v0",
        seeds=2,
        workers=2,
        num_envs=4,
        num_steps=16,
        total_steps=256,
        stop_at_return="none",
        progress=False,
        out=tmp_path / "run",
    )
    returns = [seed["mean_return"] for seed in run.final_eval["per_seed"]]
    assert len(returns) == 2 and all(-1.0 <= r <= 1.0 for r in returns), returns
    assert sorted(p.name for p in (tmp_path / "run").glob("worker-*")) == ["worker-0", "worker-1"]
