"""``agentax train`` / ``agentax plot``: bad input is one line and exit code 2; kill then --resume."""

import json
import os
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import pytest

from agentax.cli import main
from agentax.runs import load_policy, read_metrics


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "alchemy"], "unknown algorithm 'alchemy'; choose from reinforce, ppo"),
        (["train", "ppo", "--preset", "turbo"], "unknown ppo preset 'turbo'; choose from"),
        (["train", "ppo", "--seeds", "0"], "--seeds must be at least 1"),
        (["train", "ppo", "--learning-rate", "-0.1"], "learning_rate must be positive"),
        (["train", "reinforce", "--stop-at-return", "lots"], "--stop-at-return must be a number"),
        (["train", "reinforce", "--env", "Pendulum-v1"], "reinforce trains only on agentax's JAX envs"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


def test_resuming_a_folder_without_a_run(tmp_path, capsys):
    assert main(["train", "--resume", str(tmp_path)]) == 2
    assert "holds no run" in capsys.readouterr().err


@pytest.mark.timeout(180)
def test_train_then_plot_then_load_policy(tmp_path, capsys):
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
    env_id, policy = load_policy(out)
    action = jax.jit(policy)(jnp.zeros(4, jnp.float32), jax.random.key(0))
    assert env_id == "CartPole-v1" and int(action) in (0, 1)


@pytest.mark.timeout(180)
def test_host_loop_trains_pendulum_and_loads(tmp_path):
    out = tmp_path / "pendulum"
    argv = ["train", "ppo", "--env", "Pendulum-v1", "--preset", "pendulum", "--total-steps", "4096"]
    assert main([*argv, "--out", str(out), "--no-progress"]) == 0
    evaluation = json.loads((out / "eval.json").read_text())
    assert -2000 < evaluation["mean_return"] <= 0  # Pendulum's returns lie in [-16.3 * 200, 0]
    _, policy = load_policy(out)
    action = policy(jnp.zeros(3, jnp.float32), jax.random.key(0))
    assert action.shape == (1,) and -2.0 <= float(action[0]) <= 2.0


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
    done = subprocess.run(
        [sys.executable, "-m", "agentax.cli", "train", "--resume", str(out), "--no-progress"],
        env=env,
        capture_output=True,
        text=True,
        timeout=150,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = read_metrics(out)
    assert [r["env_steps"] for r in rows] == [float(total * k // 6) for k in range(1, 7)]
    assert json.loads((out / "eval.json").read_text())["episodes"] == 20
