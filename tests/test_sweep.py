"""agentax sweep: settings traced beside seeds in one program, shape settings as programs of their
own, and the best setting trained alone giving the sweep's numbers."""

from __future__ import annotations

import json

import numpy as np
import pytest

import agentax
from agentax.cli import main
from agentax.errors import UsageError
from agentax.sweeps import parse_range, random_settings, sweep

SMALL = {"env": "CartPole-v1", "seeds": 2, "total_steps": 2_048, "progress": False}


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """PPO: two learning rates (traced) × two env counts (a program each) × two seeds."""
    out = tmp_path_factory.mktemp("sweep") / "s"
    return sweep("ppo", grid={"learning_rate": "1e-3,3e-3", "num_envs": "4,8"}, out=out, **SMALL)


@pytest.mark.xdist_group("ray")  # beside the two-worker test: one worker sweeps once
@pytest.mark.slow
@pytest.mark.timeout(300)
def test_traced_and_static_names_and_the_folder(swept):
    asked = json.loads((swept.path / "sweep.json").read_text())
    assert asked["traced"] == ["learning_rate"] and asked["static"] == ["num_envs"]
    assert sorted(p.name for p in swept.path.glob("program-*")) == ["program-0", "program-1"]
    per_program = json.loads((swept.path / "program-0" / "eval.json").read_text())["per_seed"]
    assert len(per_program) == 4  # 2 learning rates × 2 seeds in one program
    assert [(s["learning_rate"], s["num_envs"]) for s in swept.settings] == [
        (1e-3, 4),
        (1e-3, 8),
        (3e-3, 4),
        (3e-3, 8),
    ]
    lines = (swept.path / "results.csv").read_text().splitlines()
    assert lines[0].startswith("learning_rate,num_envs,iqm,iqm_low,iqm_high,mean") and len(lines) == 5
    assert (swept.path / "scores.png").stat().st_size > 0
    for row in swept.settings:
        assert row["iqm_low"] <= row["iqm"] <= row["iqm_high"]
        assert row["mean"] == pytest.approx(np.mean(row["scores"]))
    best = json.loads((swept.path / "best.json").read_text())
    assert best["iqm"] == max(row["iqm"] for row in swept.settings)


@pytest.mark.xdist_group("ray")  # beside the two-worker test: one worker sweeps once
@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_setting_trained_alone_gives_the_sweeps_numbers(swept, tmp_path):
    """Agent (s, k) of a sweep starts from seed k's keys with setting s traced: the same final
    evaluation as a plain run of that setting with the same seeds."""
    setting = next(s for s in swept.settings if s["learning_rate"] == 3e-3 and s["num_envs"] == 4)
    run = agentax.train(
        "ppo", learning_rate=3e-3, num_envs=4, stop_at_return=None, out=tmp_path / "alone", **SMALL
    )
    assert [s["mean_return"] for s in run.final_eval["per_seed"]] == pytest.approx(setting["scores"])


@pytest.mark.xdist_group("ray")  # beside the two-worker test: one worker sweeps once
@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_finished_sweep_is_read_back_and_another_request_is_refused(swept, monkeypatch):
    from agentax.runners import workers

    assert json.loads((swept.path / "sweep.json").read_text())["workers"] == 1  # below the break-even
    # asked again where the default would split it: its own worker count, read back
    monkeypatch.setattr(workers, "BREAK_EVEN_FLOPS", 1)
    monkeypatch.setattr(workers, "usable_cores", lambda: 2)
    again = sweep("ppo", grid={"learning_rate": "1e-3,3e-3", "num_envs": "4,8"}, out=swept.path, **SMALL)
    assert [row["scores"] for row in again.settings] == [row["scores"] for row in swept.settings]
    with pytest.raises(UsageError, match="holds another sweep"):
        sweep("ppo", grid={"learning_rate": "1e-3"}, out=swept.path, **SMALL)


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
@pytest.mark.timeout(300)
@pytest.mark.xdist_group("ray")  # its worker processes stay off the time of the Ray tests' processes
def test_two_workers_give_each_setting_the_numbers_of_one_process(swept, tmp_path):
    """Each program's settings split over two processes (a program each): the same scores."""
    split = sweep(
        "ppo", grid={"learning_rate": "1e-3,3e-3", "num_envs": "4,8"}, workers=2, out=tmp_path / "w", **SMALL
    )
    assert sorted(p.name for p in split.path.glob("program-*")) == [
        "program-0-0",
        "program-0-1",
        "program-1-0",
        "program-1-1",
    ]
    assert [row["scores"] for row in split.settings] == [row["scores"] for row in swept.settings]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--grid", "learning_rat=1e-3"], "unknown ppo setting 'learning_rat'"),
        (["--grid", "activation=tanh"], "activation is not a number"),
        (["--grid", "num_envs=4,x"], "'x' is not an integer"),
        (["--random", "3"], "give at least one --range"),
        (["--grid", "learning_rate=1e-3", "--random", "2"], "give the settings as --grid"),
        (["--env", "Acrobot-v1", "--grid", "learning_rate=1e-3"], "a sweep runs in the compiled runner"),
        (["--random", "2", "--range", "learning_rate=1:0"], "low must be below high"),
    ],
)
def test_bad_sweeps_are_one_line_and_exit_2(argv, message, capsys, tmp_path):
    assert main(["sweep", "ppo", "--out", str(tmp_path / "s"), *argv]) == 2
    error = capsys.readouterr().err.strip()
    assert message in error and len(error.splitlines()) == 1


def test_random_settings_stay_in_their_ranges_and_repeat_with_the_seed():
    ranges = dict([parse_range("learning_rate=1e-5:1e-2:log"), parse_range("num_envs=2:16")])
    types = {"learning_rate": float, "num_envs": int}
    drawn = random_settings(ranges, types, 200, seed=3)
    rates = np.array([d["learning_rate"] for d in drawn])
    assert 1e-5 <= rates.min() and rates.max() <= 1e-2
    assert 0.3 < np.mean(np.log10(rates) < -3.5) < 0.7  # log-uniform: half below the log midpoint
    assert {type(d["num_envs"]) for d in drawn} == {int} and all(2 <= d["num_envs"] <= 16 for d in drawn)
    assert drawn == random_settings(ranges, types, 200, seed=3)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_optuna_asks_batches_and_a_rerun_asks_the_same(tmp_path):
    """Two batches of two TPE trials, each batch one program; the same command again reads every
    batch back (its asked settings enqueued) and reports the same trials and scores."""
    pytest.importorskip("optuna")
    ranges = dict([parse_range("learning_rate=1e-4:1e-2:log")])
    asked = {"method": "optuna", "trials": 4, "batch": 2, "ranges": ranges, "out": tmp_path / "o", **SMALL}
    first = sweep("ppo", **asked)
    assert len(first.settings) == 4 and len(list((tmp_path / "o").glob("program-*"))) == 2
    assert all(1e-4 <= row["learning_rate"] <= 1e-2 for row in first.settings)
    again = sweep("ppo", **asked)
    assert [(r["learning_rate"], r["scores"]) for r in again.settings] == [
        (r["learning_rate"], r["scores"]) for r in first.settings
    ]
    with pytest.raises(UsageError, match="suggests traced values only"):
        sweep("ppo", **{**asked, "ranges": {"num_envs": (2.0, 8.0, False)}, "out": tmp_path / "p"})


@pytest.mark.slow
def test_sacs_utd_is_traced_and_a_traced_count_loops_that_many_times():
    """``--utd`` sets the learning steps per phase, a count: traced, the phase loops as many times
    as each agent's count (under vmap the longest, the others masked), with the scan's carry and
    metrics where the count is fixed."""
    import jax
    import jax.numpy as jnp

    from agentax.agents import presets, sac
    from agentax.envs import make_jax
    from agentax.runners.compiled import compiled_program
    from agentax.runners.replay_program import traced_count_loop
    from agentax.runners.sweep import traceable

    env, base = make_jax("Pendulum-v1"), presets.preset("sac", "pendulum").config
    assert traceable(lambda cfg: compiled_program(sac, env, cfg), base, "utd")

    def step(carry, _):
        total, key = carry
        key, draw = jax.random.split(key)
        value = jax.random.normal(draw)
        return (total + value, key), {"value": value}

    start = (jnp.float32(0.0), jax.random.key(0))
    counts = jnp.array([1, 3, 2], jnp.int32)
    (totals, _), metrics = jax.vmap(lambda n: traced_count_loop(step, start, n))(counts)
    for k, n in enumerate([1, 3, 2]):
        (total, _), scanned = jax.lax.scan(step, start, length=n)
        assert totals[k] == total
        np.testing.assert_allclose(metrics["value"][k], scanned["value"].mean(), rtol=1e-6)
