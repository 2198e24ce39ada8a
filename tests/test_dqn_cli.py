"""``agentax train dqn``: a tiny run with every variant flag, its run folder, evaluate, bad input."""

import json
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from conftest import resume_to_the_end

from agentax.agents import config_from_dict, dqn
from agentax.agents.protocol import EnvSpec
from agentax.api import restore_policy
from agentax.cli import main
from agentax.envs import make_host_env
from agentax.evaluate import host_episode_returns
from agentax.runners import session
from agentax.runs import load_checkpoint, read_metrics


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_train_dqn_with_every_flag_writes_a_run(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "dqn", "--env", "CartPole-v1", "--double", "--dueling", "--per", "--n-step", "2"]
    argv += [
        "--target-update",
        "10",
        "--seeds",
        "2",
        "--total-steps",
        "2048",
        "--hidden",
        "16",
        "--num-envs",
        "2",
    ]
    argv += ["--train-frequency", "16", "--gradient-steps", "4", "--learning-starts", "256"]
    argv += ["--stop-at-return", "none", "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["algo"] == "dqn" and config["runner"]["num_seeds"] == 2
    chosen = {key: config["config"][key] for key in ("double", "dueling", "prioritized", "n_step")}
    assert chosen == {"double": True, "dueling": True, "prioritized": True, "n_step": 2}
    assert config["config"]["target_update_period"] == 10
    evaluation = json.loads((out / "eval.json").read_text())
    assert len(evaluation["per_seed"]) == 2 and evaluation["env_steps"] == 2048
    assert (out / "curve.png").is_file() and (out / "metrics.csv").read_text().startswith("env_steps,")
    capsys.readouterr()
    assert main(["evaluate", "--policy", str(out), "--episodes", "3"]) == 0
    assert "mean" in capsys.readouterr().out.lower()


@pytest.mark.parametrize(
    "argv, message",
    [
        (["train", "dqn", "--env", "Pendulum-v1"], "dqn takes Discrete actions, but this env's actions are"),
        (["train", "dqn", "--preset", "nope"], "choose from default, lecture"),
        (["train", "dqn", "--discount-factor", "1.5"], "discount_factor"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err


def test_continuous_actions_are_refused_before_a_run_folder_exists(tmp_path, capsys):
    """Gymnasium envs go to the host driver, which names the problem: dqn takes Discrete actions."""
    out = tmp_path / "run"
    assert main(["train", "dqn", "--env", "Pendulum-v1", "--out", str(out)]) == 2
    assert "Box" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_a_gymnasium_env_trains_through_the_host_driver(tmp_path):
    out = tmp_path / "acrobot"
    assert main(["train", "dqn", "--env", "Acrobot-v1", "--total-steps", "1000", "--out", str(out)]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["runner_kind"] == "host" and config["env"] == "Acrobot-v1"
    evaluation = json.loads((out / "eval.json").read_text())
    # 4 envs collect 64 steps each between learning phases: the run stops at 1,024 env steps, after
    # its one learning phase (learning starts at 1,000) of 128 learning steps.
    assert evaluation["env_steps"] == 1024 and evaluation["updates"] == 128
    assert read_metrics(out)[-1]["updates"] == 128
    episodes = config["runner"]["eval_episodes"]
    env = make_host_env("Acrobot-v1", min(episodes, 8))  # as the runner's evaluator
    agent = dqn.make_agent(EnvSpec.of(env), config_from_dict(dqn.DQNConfig, config["config"]))
    (state, _), meta, _ = load_checkpoint(out, session.checkpoint_target(agent))
    assert int(state.step) == meta["updates"] == 128 and meta["env_steps"] == 1024
    # The reloaded policy replays the final evaluation (seed + 123,457) to eval.json's returns.
    _, policy = restore_policy(out)
    returns, lengths = host_episode_returns(env, policy, episodes, seed=config["runner"]["seed"] + 123_457)
    env.close()
    assert float(np.mean(returns)) == pytest.approx(evaluation["mean_return"], rel=1e-6)
    assert evaluation["episodes"] == episodes


CRASH_AT = textwrap.dedent(
    """
    import os, sys
    from agentax.cli import main

    stage, argv = sys.argv[1], sys.argv[2:]
    renames, real_replace = {"replay": 0, "ckpt": 0}, os.replace

    def replace(src, dst):
        kind = next((k for k in renames if f"/{k}-" in str(dst)), None)
        if kind == "ckpt" and stage == "checkpoint_half_written" and renames["ckpt"] == 1:
            os._exit(9)  # the second checkpoint's file written under its temporary name, not renamed
        real_replace(src, dst)
        if kind is not None:
            renames[kind] += 1
            if stage == "replay_written" and kind == "replay" and renames[kind] == 2:
                os._exit(9)  # the second replay is in place, its checkpoint not yet begun
            if stage == "first_committed" and kind == "ckpt" and renames[kind] == 1:
                os._exit(9)  # the first checkpoint committed (the issue's kill -9 after it)

    os.replace = replace
    sys.exit(main(argv))
    """
)


@pytest.mark.slow
@pytest.mark.timeout(240)
@pytest.mark.parametrize("stage", ["first_committed", "replay_written", "checkpoint_half_written"])
def test_a_kill_at_each_stage_of_a_checkpoint_resumes_with_the_replay_of_its_checkpoint(tmp_path, stage):
    """Issue 18 item 1, by fault injection (the process exits at a chosen rename, as ``kill -9``
    would leave it): the replay is written before the checkpoint that commits it, so whatever the
    stage, the resumed run starts from a checkpoint with its own replay and ends holding every
    transition an uninterrupted run holds (1-step returns, a buffer larger than the run)."""
    out, total = tmp_path / "run", 3_072
    env = {**os.environ, "AGENTAX_JAX_CACHE": str(tmp_path / "cache")}
    argv = ["train", "dqn", "--runner", "host", "--total-steps", str(total), "--stop-at-return", "none"]
    argv += ["--n-step", "1", "--out", str(out), "--no-progress"]
    killed = subprocess.run(
        [sys.executable, "-c", CRASH_AT, stage, *argv], env=env, capture_output=True, timeout=150
    )
    assert killed.returncode == 9, killed.stderr[-2000:]
    assert not (out / "eval.json").exists()
    resumed = resume_to_the_end(out, env)
    assert "refills" not in resumed.stderr, resumed.stderr  # it came back with a replay
    last = read_metrics(out)[-1]
    assert last["env_steps"] == total and last["replay_size"] == total
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]  # the half-written one is gone


@pytest.mark.slow
@pytest.mark.timeout(240)
@pytest.mark.parametrize("runner", [pytest.param("compiled", marks=pytest.mark.long), "host"])
def test_resume_of_a_run_killed_before_its_first_checkpoint_starts_it_from_its_config(tmp_path, runner):
    """Issue 30: a run killed before its first checkpoint (a DQN Breakout run still filling its
    replay) holds its config.json only, and ``--resume`` refused it ("has no checkpoint ... train it
    first"). Nothing is lost by starting it from its config: it does, and gives the numbers of a run
    never killed."""
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    argv = ["train", "dqn", "--env", "CartPole-v1", "--runner", runner, "--total-steps", "3072"]
    assert main([*argv, "--stop-at-return", "none", "--no-progress", "--out", str(whole)]) == 0
    (killed / "checkpoints").mkdir(parents=True)
    shutil.copy(whole / "config.json", killed / "config.json")  # what the killed run had written
    resumed = resume_to_the_end(killed, {**os.environ, "AGENTAX_JAX_CACHE": str(tmp_path / "cache")})
    assert f"{killed} has no checkpoint yet: training it from its config.json" in resumed.stderr
    columns = ("env_steps", "updates", "mean_return", "eval_return")
    rows = [[row[c] for c in columns] for row in read_metrics(killed)]
    np.testing.assert_array_equal(rows, [[row[c] for c in columns] for row in read_metrics(whole)])
    evaluation = json.loads((killed / "eval.json").read_text())
    assert evaluation["mean_return"] == json.loads((whole / "eval.json").read_text())["mean_return"]
    assert any((killed / "checkpoints").iterdir())
