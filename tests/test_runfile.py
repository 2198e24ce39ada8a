"""Run files (agentax.runfile): a preset's file trains as its flags do, a run folder's run.toml
repeats the run, a sweep's best.toml trains the best setting, flags beside --config override its
fields, and each bad file is one line and exit code 2."""

from __future__ import annotations

import csv
import json
import tomllib
from dataclasses import replace

import pytest

from agentax import runfile
from agentax.agents.ppo import PPOConfig
from agentax.agents.presets import PRESETS
from agentax.cli import main
from agentax.cli.train import parse_file
from agentax.runfile import RunArgs
from agentax.sweeps import sweep

TIME_COLUMNS = {"wall_seconds", "steps_per_second"}
TINY = ["--total-steps", "5120", "--seeds", "2", "--no-progress"]  # 2 rows of 10 updates (cartpole-fast)


def rows(run_dir) -> list[dict[str, str]]:
    """metrics.csv's rows without the columns that measure time."""
    with open(run_dir / "metrics.csv", newline="") as f:
        return [{k: v for k, v in row.items() if k not in TIME_COLUMNS} for row in csv.DictReader(f)]


def body(path) -> str:
    """A run file without its comment lines (the header names the folder)."""
    return "\n".join(line for line in path.read_text().splitlines() if not line.startswith("#"))


@pytest.fixture(scope="module")
def by_flags(tmp_path_factory):
    """PPO on CartPole-v1 (the compiled runner, cartpole-fast), 2 seeds, trained by flags."""
    out = tmp_path_factory.mktemp("flags") / "run"
    assert main(["train", "ppo", "--env", "CartPole-v1", "--out", str(out), *TINY]) == 0
    return out


@pytest.mark.xdist_group("runfile")  # one worker trains the shared run once
@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_preset_file_trains_as_the_flags_do(by_flags, tmp_path, capsys):
    preset = tmp_path / "ppo.toml"
    assert main(["presets", "ppo", "cartpole-fast", "--out", str(preset)]) == 0
    table = tomllib.loads(preset.read_text())
    assert (table["algo"], table["env"], table["preset"]) == ("ppo", "CartPole-v1", "cartpole-fast")
    assert table["config"]["learning_rate"] == 3e-3 and table["config"]["hidden"] == [64, 64]
    out = tmp_path / "run"
    assert main(["train", "--config", str(preset), "--out", str(out), *TINY]) == 0
    assert "evaluation: mean return" in capsys.readouterr().out
    assert len(rows(out)) >= 2 and rows(out) == rows(by_flags)
    assert body(out / "run.toml") == body(by_flags / "run.toml")
    config, flags = (json.loads((d / "config.json").read_text()) for d in (out, by_flags))
    assert config == flags


@pytest.mark.xdist_group("runfile")  # one worker trains the shared run once
@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_run_folders_run_toml_repeats_the_run(by_flags, tmp_path):
    written = tomllib.loads((by_flags / "run.toml").read_text())
    assert written["seeds"] == 2 and written["config"]["total_steps"] == 5120 and "out" not in written
    again = tmp_path / "again"
    assert main(["train", "--config", str(by_flags / "run.toml"), "--out", str(again), "--no-progress"]) == 0
    assert rows(again) == rows(by_flags)
    assert (
        json.loads((again / "eval.json").read_text())["per_seed"]
        == (json.loads((by_flags / "eval.json").read_text())["per_seed"])
    )


def test_flags_beside_the_file_override_its_fields(tmp_path):
    path = tmp_path / "run.toml"
    runfile.write(path, "ppo", RunArgs(preset="cartpole-fast", seeds=3), PPOConfig(learning_rate=1e-3))
    algo, run_args, cfg, preset = parse_file(
        ["--config", str(path), "--learning-rate", "2e-4", "--seed", "5"]
    )
    assert algo == "ppo" and (run_args.seeds, run_args.seed, run_args.preset) == (3, 5, "cartpole-fast")
    assert cfg.learning_rate == 2e-4 and cfg.num_envs == PPOConfig().num_envs  # the file's, not the preset's
    assert preset.updates_per_chunk == 10
    # a key left out keeps the preset's value; None round-trips as "none"
    path.write_text('algo = "dqn"\n[config]\nmax_grad_norm = "none"\n')
    algo, run_args, cfg, _ = parse_file(["--config", str(path), "--env", "CartPole-v0"])
    assert (algo, run_args.env, run_args.preset, cfg.max_grad_norm) == ("dqn", "CartPole-v0", "default", None)
    assert runfile.load(path).config == replace(PRESETS["dqn"]["default"].config, max_grad_norm=None)
    assert 'max_grad_norm = "none"' in runfile.dumps("dqn", run_args, cfg)


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_sweeps_best_toml_trains_the_best_setting(tmp_path):
    swept = sweep(
        "ppo",
        "CartPole-v1",
        grid={"learning_rate": "1e-3,3e-3"},
        seeds=2,
        total_steps=2_048,
        out=tmp_path / "sweep",
        progress=False,
    )
    best = tomllib.loads((swept.path / "best.toml").read_text())
    assert best["config"]["learning_rate"] == swept.best["learning_rate"]
    assert (best["seeds"], best["stop_at_return"]) == (2, "none")
    out = tmp_path / "best"
    assert main(["train", "--config", str(swept.path / "best.toml"), "--out", str(out), "--no-progress"]) == 0
    per_seed = json.loads((out / "eval.json").read_text())["per_seed"]
    assert [s["mean_return"] for s in per_seed] == pytest.approx(swept.best["scores"])


GOOD = 'algo = "ppo"\nenv = "CartPole-v1"\n'

BAD_FILES = {
    "syntax error": ('algo = "ppo\n', "not valid TOML"),
    "unknown key": (GOOD + "speed = 3\n", "unknown key speed; the keys are env, preset"),
    "wrong type": (
        GOOD + '[config]\nlearning_rate = "fast"\n',
        'config.learning_rate must be a number, got "fast"',
    ),
    "bad range": (GOOD + "[config]\nlearning_rate = -0.1\n", "learning_rate must be positive"),
    "unknown algorithm": ('algo = "alchemy"\n', "unknown algorithm algo = 'alchemy'; choose from reinforce"),
    "unknown env": ('algo = "ppo"\nenv = "Nope-v9"\n', "Nope"),
    "unknown runner": (GOOD + 'runner = "warp"\n', "unknown runner 'warp'; choose from compiled"),
    "another algorithm's key": (
        GOOD + "[config]\ntarget_update_period = 100\n",
        "unknown key config.target_update_period (a setting of dqn, not of ppo's PPOConfig)",
    ),
    "missing required key": ('env = "CartPole-v1"\n', "missing the required key 'algo'"),
    "unreadable": (None, "cannot read the run file (No such file or directory)"),
    "empty": ("\n  \n", "the run file is empty"),
}


@pytest.mark.parametrize("case", BAD_FILES)
def test_a_bad_file_is_one_line_and_exit_code_2(case, tmp_path, capsys):
    text, message = BAD_FILES[case]
    path = tmp_path / "run.toml"
    if text is not None:
        path.write_text(text)
    out = tmp_path / "out"
    assert main(["train", "--config", str(path), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert err.startswith("agentax train: error: ")
    assert not out.exists()
