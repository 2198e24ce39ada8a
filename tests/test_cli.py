"""The commands envs, evaluate, play and demo: output, files written, one-line errors with exit code 2;
the --policy argument (a name or a run folder) resolved and checked against the env."""

import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import pytest

from agentax import evaluate, make
from agentax.cli import main
from agentax.cli.policies import named_policy, resolve_policy
from agentax.errors import UsageError
from agentax.evaluate import check_policy_fits
from agentax.policies import basic_policy
from agentax.search.settings import load_best_setting, vacuum_policy

AGENTAX = str(Path(sys.executable).with_name("agentax"))


@pytest.mark.slow
def test_envs_lists_jax_and_gymnasium_envs_with_their_spaces(capsys):
    assert main(["envs", "--json"]) == 0
    rows = {row["id"]: row for row in json.loads(capsys.readouterr().out)}
    assert rows["CartPole-v1"]["kind"] == "JAX" and rows["CartPole-v1"]["action_space"] == "Discrete(2)"
    assert rows["CartPole-v0"]["observation_space"].startswith("Box(shape=(4,)")
    assert rows["FrozenLake-v1"] == {
        "id": "FrozenLake-v1",
        "kind": "Gymnasium",
        "observation_space": "Discrete(16)",
        "action_space": "Discrete(4)",
    }
    assert main(["envs"]) == 0
    table = capsys.readouterr().out
    assert "MountainCar-v0" in table and "Discrete(3)" in table


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_evaluate_json_matches_the_lecture(capsys):
    # The lecture: the basic policy over 500 episodes of CartPole (<= 200 steps) averages about 42,
    # std 8-9, min about 24, max 63-68.
    assert main(["evaluate", "--env", "CartPole-v0", "--policy", "basic", "--episodes", "500", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert {"env", "policy", "episodes", "mean_return", "std_return", "min_return", "max_return"} <= set(
        result
    )
    assert (result["env"], result["policy"], result["episodes"]) == ("CartPole-v0", "basic", 500)
    assert 38 < result["mean_return"] < 47 and 6 < result["std_return"] < 11
    assert 20 <= result["min_return"] <= 30 and 55 <= result["max_return"] <= 80
    stats = evaluate(make("CartPole-v0"), basic_policy, num_episodes=500, seed=0)  # the default seed
    assert result["mean_return"] == stats.mean_return and result["max_return"] == stats.max_return


def test_evaluate_table_and_gymnasium_env(capsys):
    assert (
        main(["evaluate", "--env", "FrozenLake-v1", "--policy", "random", "--episodes", "30", "--seed", "1"])
        == 0
    )
    out = capsys.readouterr().out
    assert "random policy on FrozenLake-v1" in out and "mean return" in out and "30 episodes, seed 1" in out


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_play_writes_the_animation_and_reports_the_return(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert (
        main(["play", "--env", "CartPole-v1", "--policy", "basic", "--video", "out.gif", "--seed", "3"]) == 0
    )
    out = capsys.readouterr().out
    assert out.startswith("wrote out.gif") and "return" in out
    steps = int(out.split(" over ")[1].split()[0])
    assert iio.imread(tmp_path / "out.gif", index=None).shape[0] == steps + 1
    assert main(["play", "--env", "CartPole-v0", "--policy", "random"]) == 0
    assert (tmp_path / "runs" / "play" / "CartPole-v0-random.gif").stat().st_size > 1000


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_demo_evaluates_and_writes_a_gif(tmp_path, capsys):
    video = tmp_path / "demo.gif"
    assert main(["demo", "--episodes", "50", "--video", str(video)]) == 0
    out = capsys.readouterr().out
    assert "basic policy on CartPole-v1" in out and f"wrote {video}" in out and video.stat().st_size > 1000


@pytest.mark.slow
@pytest.mark.timeout(200)
def test_a_trained_run_folder_is_a_policy(tmp_path, capsys):
    # A tiny vacuum grid search writes a run folder; evaluate and play take the env from it.
    run = tmp_path / "run"
    search = "search vacuum --method grid --grid-size 2 --episodes 1 --eval-episodes 2".split()
    assert main([*search, "--out", str(run)]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--policy", str(run), "--episodes", "3", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert (result["env"], result["policy"], result["episodes"]) == ("Vacuum-v0", "run", 3)
    # The run's best (p, r) policy on the same 3 episodes (seed 0), evaluated here without the CLI.
    stats = evaluate(make("Vacuum-v0"), vacuum_policy(*load_best_setting(run)), num_episodes=3, seed=0)
    assert result["mean_length"] == 900  # 30 minutes of 2 s steps
    assert (result["mean_return"], result["min_return"]) == (stats.mean_return, stats.min_return)
    assert main(["play", "--policy", str(run), "--video", str(tmp_path / "vacuum.gif")]) == 0
    assert "run policy on Vacuum-v0" in capsys.readouterr().out
    assert main(["evaluate", "--policy", str(run), "--env", "CartPole-v1"]) == 2
    assert "takes Discrete(2)" in capsys.readouterr().err  # a vacuum policy does not fit CartPole


BAD_INPUTS = [
    (["evaluate", "--env", "CartPol-v1"], "unknown env 'CartPol-v1'; did you mean CartPole-v1"),
    (["train", "ppo", "--env", "no_such_module:Thing-v0"], "cannot import 'no_such_module' for no_such"),
    (
        ["evaluate", "--env", "CartPole-v1", "--policy", "smart"],
        "unknown policy 'smart'; choose from basic, random",
    ),
    (["evaluate", "--env", "CartPole-v1", "--episodes", "0"], "--episodes must be at least 1"),
    (["evaluate", "--env", "CartPole-v1", "--episodes", "-3"], "--episodes must be at least 1"),
    (["evaluate", "--env", "MountainCar-v0", "--policy", "basic"], "MountainCar-v0 has observations Box"),
    (
        ["evaluate", "--env", "FrozenLake-v1", "--policy", "basic"],
        "FrozenLake-v1 has observations Discrete(16)",
    ),
    (["evaluate", "--policy", "basic"], "no env id given"),
    (["evaluate", "--env", "CartPole-v1", "--policy", "runs/none"], "no trained run at 'runs/none'"),
    (["evaluate", "--env", "CartPole-v1", "--policy", "tests"], "tests holds no run (no config.json)"),
    (["play", "--env", "Nope-v0"], "unknown env 'Nope-v0'"),
    (["play", "--env", "CartPole-v1", "--video", "out.avi"], "must end in .gif or .mp4"),
    (
        ["play", "--env", "Pendulum-v1", "--policy", "basic"],
        "policy 'basic' is the lecture's CartPole policy",
    ),
]


@pytest.mark.parametrize(("argv", "message"), BAD_INPUTS)
def test_bad_input_is_one_line_and_exit_code_2(argv, message, capsys):
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and message in captured.err
    assert captured.err.count("\n") == 1 and captured.err.startswith(f"agentax {argv[0]}: error: ")


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "argv", [["evaluate", "--env", "NoSuchEnv-v3"], ["play", "--env", "CartPole-v1", "--video", "x.txt"]]
)
def test_bad_input_from_the_shell(argv, tmp_path):
    result = subprocess.run([AGENTAX, *argv], capture_output=True, text=True, cwd=tmp_path, timeout=100)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert "choose" in result.stderr or "must end in" in result.stderr


def _raising(error):
    def command_main(argv):
        raise error

    return command_main


def test_a_diverged_training_is_one_line_and_exit_code_3(monkeypatch, capsys):
    from agentax.cli import envs
    from agentax.errors import TrainingDiverged

    monkeypatch.setattr(envs, "main", _raising(TrainingDiverged("loss is NaN at env step 4096")))
    assert main(["envs"]) == 3
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == "agentax envs: error: loss is NaN at env step 4096\n"


@pytest.mark.parametrize(
    ("run_dir", "line"),
    [
        ("runs/ppo-x", "agentax envs: interrupted; continue with: agentax train --resume runs/ppo-x\n"),
        (None, "agentax envs: interrupted\n"),
    ],
)
def test_an_interrupted_training_says_how_to_resume_and_exit_code_130(run_dir, line, monkeypatch, capsys):
    from agentax.cli import envs
    from agentax.errors import TrainingInterrupted

    monkeypatch.setattr(envs, "main", _raising(TrainingInterrupted(run_dir)))
    assert main(["envs"]) == 130
    assert capsys.readouterr().err == line
    monkeypatch.setattr(envs, "main", _raising(KeyboardInterrupt()))  # a plain Ctrl-C
    assert main(["envs"]) == 130
    assert capsys.readouterr().err == "agentax envs: interrupted\n"


@pytest.mark.parametrize("env_id", ["MountainCar-v0", "FrozenLake-v1", "Pendulum-v1"])
def test_basic_policy_fits_cartpole_only(env_id):
    env = make(env_id)
    with pytest.raises(UsageError, match="CartPole") as error:
        named_policy("basic", env, env_id)
    assert env_id in str(error.value) and "random" in str(error.value)  # names the problem and the choices
    check_policy_fits(env, named_policy("random", env, env_id), env_id)  # random fits any env
    assert named_policy("basic", make("CartPole-v1")) is basic_policy
    with pytest.raises(UsageError, match="unknown policy 'greedy'; choose from basic, random"):
        named_policy("greedy", env)


def test_resolve_policy_names_the_problem():
    env_id, env, policy = resolve_policy("random", "Acrobot-v1", num_envs=3)
    assert env_id == "Acrobot-v1" and env.num_envs == 3
    with pytest.raises(UsageError, match="no env id given"):
        resolve_policy("basic", None)
    with pytest.raises(UsageError, match="no trained run at 'runs/missing'"):
        resolve_policy("runs/missing", "CartPole-v1")
