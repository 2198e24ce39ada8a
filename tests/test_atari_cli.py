"""Atari through the CLI: ``agentax play`` films whole games from the full-resolution screen,
``agentax evaluate`` gives true game scores (the random baseline), and the host and parallel runners
train on both backends, write their run folders and resume."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import imageio.v3 as iio
import jax
import numpy as np
import pytest

from agentax.cli import main
from agentax.runners.launch import agent_maker

pytest.importorskip("ale_py")
pytest.importorskip("cv2")
pytest.importorskip("envpool")

BREAKOUT = "ALE/Breakout-v5"

# 300 random games (agentax evaluate --policy random --episodes 100, seeds 1-3; EnvPool, sticky
# actions 0.25): mean 1.39, standard deviation 1.24 points per game.
RANDOM_MEAN, RANDOM_STD = 1.39, 1.24


def played(out: str) -> tuple[float, int]:
    """``(score, length)`` from ``agentax play``'s line for an Atari game."""
    match = re.search(r"score (-?[\d.]+) over (\d+) steps", out)
    assert match, out
    return float(match.group(1)), int(match.group(2))


@pytest.mark.slow
def test_play_random_writes_a_gif_of_the_whole_game_and_its_true_score(tmp_path, capsys):
    video = tmp_path / "x.gif"
    args = ["--env", BREAKOUT, "--policy", "random", "--seed", "4"]
    assert main(["play", *args, "--video", str(video), "--scale", "1"]) == 0
    out = capsys.readouterr().out
    score, length = played(out)
    assert "game over" in out and "sticky actions 0.25" in out
    # the same game, played by evaluate (same seeds: one env, the same policy keys)
    assert main(["evaluate", *args, "--episodes", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert (result["mean_return"], result["mean_length"]) == (score, length)
    # a frame per agent step at 15 fps; Pillow merges a frame identical to the one before into it
    with iio.imopen(video, "r", plugin="pillow") as gif:
        frames = gif.read(index=None)
        durations = [gif.metadata(index=i)["duration"] for i in range(len(frames))]
    assert frames.shape[1:] == (210, 160, 3) and len(frames) <= length
    assert abs(sum(durations) - length * 1000 / 15) <= 10  # GIF counts in 10 ms


def tiny_run(run_dir: Path, algo: str = "ppo", backend: str = "ale", sticky_actions: float = 0.0) -> Path:
    """A run folder of an untrained agent (a checkpoint of its initial state), trained on ``backend``."""
    from agentax.agents import algorithm, config_to_dict
    from agentax.agents.protocol import EnvSpec
    from agentax.cli.train import parse
    from agentax.envs import make_host_env
    from agentax.runners.host import HostRunnerConfig
    from agentax.runners.session import agent_keys
    from agentax.runs import Run, run_config

    module = algorithm(algo)
    _, cfg, _ = parse(algo, ["--env", BREAKOUT])
    probe = make_host_env(BREAKOUT, 1, backend=backend, sticky_actions=sticky_actions)
    agent = agent_maker(module, EnvSpec.of(probe), cfg)()
    probe.close()
    runner = HostRunnerConfig(env_backend=backend, sticky_actions=sticky_actions)
    run = Run.create(run_dir, run_config(algo, BREAKOUT, "auto", "host", runner, config_to_dict(cfg)))
    init_key, learner_key, _ = agent_keys(0)
    meta = {"env_steps": 0, "updates": 0, "episodes": 0, "elapsed": 0.0}
    run.save_checkpoint(0, (jax.device_get(agent.init(init_key)), learner_key), meta)
    return run_dir


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # ffmpeg, which reads the MP4 back
def test_play_a_run_writes_an_mp4_of_one_frame_per_step_with_the_runs_env_settings(tmp_path, capsys):
    run_dir = tiny_run(tmp_path / "run")
    video = tmp_path / "breakout.mp4"
    assert main(["play", "--policy", str(run_dir), "--video", str(video), "--scale", "2"]) == 0
    out = capsys.readouterr().out
    score, length = played(out)
    assert "(ale, sticky actions 0)" in out and f"video {length} frames" in out
    frames = np.stack(list(iio.imiter(video, plugin="FFMPEG")))
    assert frames.shape == (length, 420, 320, 3)
    assert main(["evaluate", "--policy", str(run_dir), "--episodes", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)  # the run's settings: the same game again
    assert (result["env_backend"], result["sticky_actions"]) == ("ale", 0.0)
    assert (result["mean_return"], result["mean_length"]) == (score, length)
    assert (
        main(["evaluate", "--policy", str(run_dir), "--episodes", "1", "--json", "--env-backend", "envpool"])
        == 0
    )
    assert json.loads(capsys.readouterr().out)["env_backend"] == "envpool"


@pytest.mark.slow
def test_evaluate_random_gives_the_random_baseline_in_whole_games(capsys):
    episodes = 32
    assert (
        main(["evaluate", "--env", BREAKOUT, "--policy", "random", "--episodes", str(episodes), "--json"])
        == 0
    )
    result = json.loads(capsys.readouterr().out)
    assert result["episodes"] == episodes and result["env_backend"] == "envpool"
    # 4 standard errors of the mean of 32 games around the mean of 300
    assert abs(result["mean_return"] - RANDOM_MEAN) < 4 * RANDOM_STD / np.sqrt(episodes)
    assert result["min_return"] >= 0 and result["mean_length"] > 100  # whole games: 5 lives


def rows_of(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


DQN_SMOKE = [
    "--env", BREAKOUT,
    "--num-envs", "4",
    "--learning-starts", "1900",
    "--train-frequency", "32",
    "--gradient-steps", "1",
    "--batch-size", "32",
    "--buffer-size", "5000",
    "--sticky-actions", "0",
    "--no-progress",
]  # fmt: skip
# Learning starts before the first row (2,048 env steps): a row logged before it lacks the loss
# columns the later rows add, which metrics.csv refuses. Sticky actions 0: an untrained greedy
# agent that never presses FIRE has its lost ball relaunched by the env's FIRE, which sticky
# actions can swallow; its evaluation games would then run to the 108,000-frame cap.


@pytest.mark.long
def test_a_parallel_atari_dqn_run_writes_its_run_folder(tmp_path, capsys):
    run_dir = tmp_path / "dqn"
    args = ["--runner", "parallel", "--actors", "2", "--total-steps", "2560", "--out", str(run_dir)]
    assert main(["train", "dqn", *DQN_SMOKE, *args]) == 0
    evaluation = json.loads((run_dir / "eval.json").read_text())
    assert evaluation["episodes"] == 10 and evaluation["mean_length"] > 0
    rows = rows_of(run_dir)
    assert rows and int(rows[-1]["env_steps"]) >= 2560 and float(rows[-1]["updates"]) > 0
    if "replay_size" in rows[-1]:  # each actor's two envs filled their own streams of the shared buffer
        assert float(rows[-1]["replay_size"]) > 0.9 * float(rows[-1]["env_steps"])
    assert "evaluation: mean return" in capsys.readouterr().out


@pytest.mark.slow
@pytest.mark.parametrize("backend", [pytest.param(b, marks=pytest.mark.long) for b in ("ale", "envpool")])
def test_training_on_each_backend_writes_the_run_and_resume_finishes_it(
    tmp_path, monkeypatch, backend, capsys
):
    from agentax.runners.logger import RunLogger

    checkpoint = RunLogger.checkpoint

    def checkpoint_then_interrupt(self, step, tree, meta, *, force=False, before=None):
        checkpoint(self, step, tree, meta, force=True, before=before)
        raise KeyboardInterrupt  # Ctrl-C right after the first checkpoint (2,048 env steps)

    monkeypatch.setattr(RunLogger, "checkpoint", checkpoint_then_interrupt)
    run_dir = tmp_path / backend
    args = ["--runner", "host", "--env-backend", backend, "--total-steps", "2560", "--out", str(run_dir)]
    assert main(["train", "dqn", *DQN_SMOKE, *args]) == 130
    assert f"agentax train --resume {run_dir}" in capsys.readouterr().err
    assert [int(row["env_steps"]) for row in rows_of(run_dir)] == [2048]
    assert not (run_dir / "eval.json").exists()
    monkeypatch.undo()
    assert main(["train", "--resume", str(run_dir), "--no-progress"]) == 0
    rows = rows_of(run_dir)
    assert int(rows[0]["env_steps"]) == 2048 and int(rows[-1]["env_steps"]) >= 2560
    assert int(rows[-1]["updates"]) > int(rows[0]["updates"]) > 0  # continued from the checkpoint
    config = json.loads((run_dir / "config.json").read_text())
    assert config["runner"]["env_backend"] == backend
    assert json.loads((run_dir / "eval.json").read_text())["episodes"] == 10
    out, err = capsys.readouterr()
    assert "evaluation: mean return" in out and f"resuming dqn on {BREAKOUT} (host runner)" in err


def test_a_long_game_keeps_at_most_the_gif_cap_of_evenly_spaced_frames(tmp_path):
    from agentax.render import _GifWriter

    writer = _GifWriter(tmp_path / "long.gif", fps=15.0, scale=2, max_frames=16)
    for t in range(100):
        writer.append(np.full((4, 6, 3), t, np.uint8))  # frame t shows the value t
    assert writer.close() == 13 and writer.stride == 8  # frames 0, 8, ..., 96
    with iio.imopen(tmp_path / "long.gif", "r", plugin="pillow") as gif:
        frames = gif.read(index=None)
        durations = [gif.metadata(index=i)["duration"] for i in range(len(frames))]
    assert frames.shape == (13, 8, 12, 3)
    assert frames[:, 0, 0, 0].tolist() == list(range(0, 100, 8))
    assert abs(sum(durations) - 13 * 8 * 1000 / 15) <= 10


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "flags, says",
    [
        (["ppo", "--seeds", "2"], "one seed per process"),
        (["ppo", "--env-backend", "ale"], "--env-backend ale cannot run there"),
        (["dqn"], "(sac, td3) on EnvPool's MuJoCo tasks only; dqn on ALE/Breakout-v5 needs --runner host"),
    ],
)
def test_the_compiled_runner_refuses_what_it_cannot_train_on_atari(flags, says, tmp_path, capsys):
    out = tmp_path / "run"
    algo, rest = flags[0], flags[1:]
    args = ["train", algo, "--env", BREAKOUT, "--runner", "compiled", "--out", str(out), *rest]
    assert main(args) == 2
    assert says in capsys.readouterr().err
    assert not out.exists()  # refused before anything was written
