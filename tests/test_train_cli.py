"""``agentax train`` / ``agentax plot``: bad input is one line and exit code 2; kill then --resume."""

import json
import math
import os
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import resume_to_the_end, with_sigint_ignored

from agentax.api import restore_policy
from agentax.cli import main
from agentax.envs import make_host_env, make_jax
from agentax.envs.core import episode_returns
from agentax.evaluate import host_episode_returns
from agentax.runners.session import EVAL_KEY_OFFSET
from agentax.runs import read_metrics


@pytest.mark.slow
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "alchemy"], "unknown algorithm 'alchemy'; choose from reinforce, ppo"),
        (["train", "ppo", "--preset", "turbo"], "unknown ppo preset 'turbo'; choose from"),
        (["train", "ppo", "--seeds", "0"], "--seeds must be at least 1"),
        (["train", "ppo", "--learning-rate", "-0.1"], "learning_rate must be positive"),
        (["train", "reinforce", "--stop-at-return", "lots"], "--stop-at-return must be a number"),
        (["train", "pqn", "--env", "Pendulum-v1"], "pqn takes Discrete actions, but this env's actions are"),
        (
            ["train", "sac", "--env", "CartPole-v1"],
            "sac needs continuous (Box) actions, but this env's actions are Discrete(2)",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


def test_an_out_that_is_a_file_and_seeds_past_memory_are_one_line_and_nothing_written(tmp_path, capsys):
    """Issue 18 items 4 and 5: ``--out`` naming a file (or a folder under one), and more seeds than
    memory holds (refused up front, with what they would need, instead of hanging)."""
    blocker = tmp_path / "notes.txt"
    blocker.write_text("mine")
    for out in (blocker, blocker / "run"):
        assert main(["train", "ppo", "--out", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert f"cannot make the run folder there ({blocker} is a file, not a folder)" in err, err
        assert err.count("\n") == 1
    assert blocker.read_text() == "mine"
    out = tmp_path / "many"
    assert main(["train", "ppo", "--seeds", "100000000", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--seeds 100,000,000 needs about" in err and "seeds fit" in err and err.count("\n") == 1, err
    assert not out.exists()


def test_cli_aliases_parse_into_the_algorithms_own_config_and_show_in_help(capsys):
    """The short flags live in cli/train.py (ALIASES), not in the algorithm: ``--per`` and
    ``--target-update`` set DQNConfig's fields, listed beside the long names with their docstrings."""
    from agentax.agents.dqn import DQNConfig
    from agentax.cli.train import parse

    _, cfg, _ = parse("dqn", ["--per", "--target-update", "500", "--preset", "lecture"])
    assert type(cfg) is DQNConfig  # not the CLI's annotated subclass
    assert (cfg.prioritized, cfg.target_update_period, cfg.schedule_unit) == (True, 500, "episodes")
    _, cfg, _ = parse("dqn", ["--no-prioritized", "--target-update-period", "7"])
    assert (cfg.prioritized, cfg.target_update_period) == (False, 7)
    with pytest.raises(SystemExit):
        parse("dqn", ["--help"])
    help_text = capsys.readouterr().out
    assert "--target-update INT, --target-update-period INT" in help_text
    assert "--per, --no-per, --prioritized, --no-prioritized" in help_text
    assert "Learning steps between target-network updates" in help_text  # the field's docstring


def test_resuming_a_folder_without_a_run(tmp_path, capsys):
    assert main(["train", "--resume", str(tmp_path)]) == 2
    assert "holds no run" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_train_then_plot_then_restore_policy(tmp_path, capsys):
    out = tmp_path / "run"
    argv = [
        "train",
        "ppo",
        "--env",
        "CartPole-v1",
        "--total-steps",
        "4096",
        "--num-envs",
        "4",
        "--num-steps",
        "64",
    ]
    assert main([*argv, "--seeds", "2", "--out", str(out), "--no-progress"]) == 0
    assert "evaluation: mean return" in capsys.readouterr().out
    assert {"config.json", "metrics.csv", "curve.png", "eval.json", "checkpoints", "tensorboard"} <= {
        p.name for p in out.iterdir()
    }
    config = json.loads((out / "config.json").read_text())
    assert config["algo"] == "ppo" and config["env"] == "CartPole-v1" and config["config"]["num_envs"] == 4
    assert read_metrics(out)[-1]["env_steps"] == 4096
    assert main(["plot", str(out), "--out", str(tmp_path / "curves.png")]) == 0
    env_id, policy = restore_policy(out)
    assert env_id == "CartPole-v1"
    # The reloaded policy is the best seed's: replaying the final evaluation's episodes (its key:
    # the seed's, folded with the number of evaluations before it) gives eval.json's return.
    evaluation = json.loads((out / "eval.json").read_text())
    best = int(np.argmax([s["mean_return"] for s in evaluation["per_seed"]]))
    evaluations = sum(not math.isnan(row["eval_return"]) for row in read_metrics(out))
    seed_key = jax.random.key(config["runner"]["seed"] + best)
    key = jax.random.fold_in(seed_key, EVAL_KEY_OFFSET + evaluations)
    episodes = config["runner"]["eval_episodes"]
    returns, _ = jax.jit(episode_returns, static_argnums=(0, 1, 3))(make_jax(env_id), policy, key, episodes)
    assert float(np.mean(returns)) == pytest.approx(evaluation["per_seed"][best]["mean_return"])


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_host_loop_trains_pendulum_and_loads(tmp_path):
    out = tmp_path / "pendulum"
    argv = [
        "train",
        "ppo",
        "--env",
        "Pendulum-v1",
        "--preset",
        "pendulum",
        "--total-steps",
        "4096",
        "--runner",
        "host",
    ]
    assert main([*argv, "--out", str(out), "--no-progress"]) == 0
    evaluation = json.loads((out / "eval.json").read_text())
    config = json.loads((out / "config.json").read_text())
    assert config["runner_kind"] == "host" and evaluation["env_steps"] == 4096
    _, policy = restore_policy(out)
    action = policy(jnp.zeros(3, jnp.float32), jax.random.key(0))
    assert action.shape == (1,) and -2.0 <= float(action[0]) <= 2.0
    # The reloaded policy is the trained one: its episodes on the final evaluation's seed (the host
    # runner's: seed + 123,457) give eval.json's mean return.
    episodes = config["runner"]["eval_episodes"]
    env = make_host_env("Pendulum-v1", min(episodes, 8))
    returns, _ = host_episode_returns(env, policy, episodes, seed=config["runner"]["seed"] + 123_457)
    env.close()
    assert float(np.mean(returns)) == pytest.approx(evaluation["mean_return"], rel=1e-6)


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
@pytest.mark.slow
@pytest.mark.timeout(240)
def test_killed_run_resumes_to_the_full_number_of_steps(tmp_path):
    out = tmp_path / "run"
    env = {**os.environ, "AGENTAX_JAX_CACHE": str(tmp_path / "cache")}
    total = 60 * 512  # 60 updates of 4 envs × 128 steps, 6 chunks
    command = [
        sys.executable,
        "-m",
        "agentax.cli",
        "train",
        "ppo",
        "--preset",
        "default",
        "--total-steps",
        str(total),
    ]
    command += ["--stop-at-return", "none", "--out", str(out), "--no-progress"]
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 150
        while not list((out / "checkpoints").glob("ckpt-*.msgpack")) and process.poll() is None:
            assert time.monotonic() < deadline, "no checkpoint appeared"
            time.sleep(0.02)
        process.send_signal(signal.SIGKILL)
    finally:
        process.wait()
    assert not (out / "eval.json").exists(), "the run finished before it could be killed"
    resume_to_the_end(out, env)
    rows = read_metrics(out)
    assert [r["env_steps"] for r in rows] == [float(total * k // 6) for k in range(1, 7)]
    assert json.loads((out / "eval.json").read_text())["episodes"] == 20


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_sigterm_checkpoints_says_how_to_continue_and_exits_143(tmp_path):
    """Issue 18 item 2: SIGTERM (``kill``, a scheduler) ends a run as Ctrl-C does, and the first
    checkpoint comes with the first row, so a run stopped in its first seconds resumes too. The run
    starts as ``nohup agentax train ... &`` in a script starts it, with SIGINT ignored (a SIGTERM
    turned into a raised SIGINT was lost there, and the run went on to its end)."""
    out = tmp_path / "run"
    env = dict(os.environ)  # the suite's compile cache: test_runs' full disk compiles the same program
    total = 60 * 512
    command = [sys.executable, "-m", "agentax.cli", "train", "ppo", "--preset", "default"]
    command += ["--total-steps", str(total), "--stop-at-return", "none", "--out", str(out), "--no-progress"]
    process = subprocess.Popen(
        with_sigint_ignored(command),
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 150
        while not list((out / "checkpoints").glob("ckpt-*.msgpack")) and process.poll() is None:
            assert time.monotonic() < deadline, "no checkpoint appeared"  # (before: only after 30 s)
            time.sleep(0.02)
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 143, err[-2000:]
    assert f"agentax train: terminated; continue with: agentax train --resume {out}" in err
    assert not (out / "eval.json").exists(), "the run finished before SIGTERM reached it"
    resume_to_the_end(out, env)
    assert read_metrics(out)[-1]["env_steps"] == total


@pytest.mark.timeout(30)
@pytest.mark.parametrize("sigint", [signal.default_int_handler, signal.SIG_IGN], ids=["default", "ignored"])
def test_sigterm_interrupts_whatever_sigint_was_at_start(sigint):
    from agentax.cli import terminate_as_interrupt

    previous = signal.signal(signal.SIGINT, sigint)
    try:
        with pytest.raises(KeyboardInterrupt), terminate_as_interrupt() as seen:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler runs at once, between bytecodes
        assert seen == [signal.SIGTERM]
        assert signal.getsignal(signal.SIGINT) is sigint
    finally:
        signal.signal(signal.SIGINT, previous)
