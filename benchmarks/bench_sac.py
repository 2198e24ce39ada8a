"""SAC on Pendulum-v1: learned across seeds, and the whole process beside Stable-Baselines3's.

Rows, all measured in this run:

- the whole ``agentax train sac --env Pendulum-v1 --seeds 8 --precision auto`` command (SAC's
  ``pendulum`` preset, the RL Zoo's Pendulum-v1 settings: SB3's defaults with lr 1e-3, 20k env steps;
  the compiled runner on agentax's JAX Pendulum): how many seeds' final evaluation (10 greedy
  episodes each) reaches -200, and the wall-clock;
- the whole ``agentax train sac --env Pendulum-v1`` process for one seed (start-up, compile, 20k steps,
  final evaluation, run folder), against SB3's SAC with the same settings and steps (whole process);

SB3 runs in ``.bench-venv`` (stable-baselines3, torch, gymnasium[mujoco]) with every core; agentax
pins itself to one core (``AGENTAX_PIN_CPU``, DESIGN.md's known hazard). Without ``.bench-venv`` the
SB3 rows and ratios are left out.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
BENCH_VENV = ROOT / ".bench-venv"
PENDULUM_STEPS = 20_000
SOLVED = -200.0
SEEDS = 8

MARK_CALLBACK = """
from stable_baselines3.common.callbacks import BaseCallback
class Mark(BaseCallback):  # the time at env step `at` (0: none), for the rate of the steps after it
    def __init__(self, at):
        super().__init__()
        self.at, self.seen = at, None
    def _on_step(self):
        if self.num_timesteps == self.at:
            self.seen = time.perf_counter()
        return True
"""
"""An SB3 callback (for SB3 and SBX alike; the script imports ``time``): ``Mark(at).seen``."""

SB3_SCRIPT = (
    """
import json, sys, time
start = time.perf_counter()
import gymnasium as gym, numpy as np, torch
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.noise import NormalActionNoise
algo, env_id, steps, learning_starts = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
if int(sys.argv[5]):
    torch.set_num_threads(int(sys.argv[5]))
env = gym.make(env_id)
if algo == "sac":  # RL Zoo: Pendulum-v1 lr 1e-3; MuJoCo SB3's defaults, learning_starts 10k
    kwargs = dict(learning_rate=1e-3) if env_id == "Pendulum-v1" else {}
    model = SAC("MlpPolicy", env, learning_starts=learning_starts, seed=0, verbose=0, **kwargs)
else:  # RL Zoo MuJoCo: SB3's defaults, Gaussian exploration noise 0.1
    noise = NormalActionNoise(np.zeros(env.action_space.shape), 0.1 * np.ones(env.action_space.shape))
    model = TD3("MlpPolicy", env, learning_starts=learning_starts, action_noise=noise, seed=0, verbose=0)
"""
    + MARK_CALLBACK
    + """
mark = Mark(int(sys.argv[6]) if len(sys.argv) > 6 else 0)
train_start = time.perf_counter()
model.learn(total_timesteps=steps, callback=mark)
end = time.perf_counter()
mean = float("nan")
if env_id == "Pendulum-v1":
    mean, _ = evaluate_policy(model, gym.make(env_id), n_eval_episodes=10)
print(json.dumps({"train_seconds": end - train_start, "total_seconds": time.perf_counter() - start,
                  "mean_return": float(mean), "after_mark_seconds": end - mark.seen if mark.seen else None}))
"""
)


def pendulum_id() -> str:
    from agentax.envs import JAX_ENVS

    return "Pendulum-v1" if "Pendulum-v1" in JAX_ENVS else "gymnax/Pendulum-v1"


def process(args: list[str]) -> tuple[float, dict, dict]:
    """``agentax train sac --env Pendulum-v1 ARGS`` as a whole process from an empty compilation
    cache: ``(seconds, eval.json, config.json)``."""
    with tempfile.TemporaryDirectory() as out:
        command = [sys.executable, "-m", "agentax.cli", "train", "sac", "--env", "Pendulum-v1", *args]
        command += ["--out", out + "/run", "--no-progress", "--stop-at-return", "none"]
        env = {**os.environ, "AGENTAX_JAX_CACHE": out + "/cache"}
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True, timeout=3600, env=env)
        seconds = time.perf_counter() - start
        evaluation = json.loads((Path(out) / "run" / "eval.json").read_text())
        config = json.loads((Path(out) / "run" / "config.json").read_text())
    return seconds, evaluation, config


def seeds_row() -> list:
    """The whole ``agentax train sac --env Pendulum-v1 --seeds 8 --precision auto`` command."""
    seconds, evaluation, config = process(["--seeds", str(SEEDS), "--precision", "auto"])
    per_seed = np.array([seed["mean_return"] for seed in evaluation["per_seed"]])
    workers = config["runner"].get("workers", 1)
    return [
        f"`agentax train sac --env Pendulum-v1 --seeds {SEEDS} --precision auto` process",
        SEEDS,
        f"{int(np.sum(per_seed >= SOLVED))}/{SEEDS}",
        f"{per_seed.min():.1f} … {per_seed.max():.1f}",
        round(seconds, 1),
        round(PENDULUM_STEPS * SEEDS / seconds, 1),
        f"{config['precision']}, {workers} worker process{'es' if workers > 1 else ''}",
    ]


def process_row() -> list:
    """The whole ``agentax train sac --env Pendulum-v1`` process, one seed (its defaults there)."""
    seconds, evaluation, config = process([])
    mean = evaluation["mean_return"]
    return [
        f"`agentax train sac --env Pendulum-v1` process ({config.get('runner_kind', '?')} runner)",
        1,
        f"{int(mean >= SOLVED)}/1",
        f"{mean:.1f}",
        round(seconds, 1),
        round(PENDULUM_STEPS / seconds, 1),
        config["precision"],
    ]


def sb3_threads() -> int | None:
    """torch's faster thread count for SB3's SAC update on this machine (1, or torch's default of
    every core: on a busy machine one thread can be several times faster), from 300 learning steps
    on Pendulum each; None where ``.bench-venv`` has no stable-baselines3 with mujoco."""
    python = BENCH_VENV / "bin" / "python"
    probe = [str(python), "-c", "import stable_baselines3, torch, gymnasium.envs.mujoco"]  # its imageio too
    if not python.exists() or subprocess.run(probe, capture_output=True).returncode != 0:
        return None
    seconds = {n: sb3("sac", "Pendulum-v1", 400, 100, n)["train_seconds"] for n in (1, 0)}
    return min(seconds, key=seconds.get)


def sb3(algo: str, env_id: str, steps: int, learning_starts: int, threads: int, mark: int = 0) -> dict | None:
    """SB3's run (``SB3_SCRIPT``) in ``.bench-venv``; ``threads`` 0: torch's default; ``mark``: the env
    step from which ``after_mark_seconds`` times the rest of the run."""
    python = BENCH_VENV / "bin" / "python"
    command = [str(python), "-c", SB3_SCRIPT, algo, env_id, str(steps), str(learning_starts), str(threads)]
    command.append(str(mark))
    done = subprocess.run(command, capture_output=True, text=True, timeout=3600)
    if done.returncode != 0:
        print(done.stderr[-2000:], file=sys.stderr)
        return None
    return json.loads(done.stdout.strip().splitlines()[-1])


def run() -> dict:
    headers = ["run", "seeds", "final eval ≥ -200", "final eval (10 episodes)", "wall-clock s", "env steps/s"]
    headers.append("precision, processes")
    rows = [seeds_row(), process_row()]
    threads = sb3_threads()
    reference = sb3("sac", "Pendulum-v1", PENDULUM_STEPS, 100, threads) if threads is not None else None
    if reference is not None:
        mean = reference["mean_return"]
        rows.append(
            [
                "SB3 SAC, RL Zoo settings, whole process",
                1,
                f"{int(mean >= SOLVED)}/1",
                f"{mean:.1f}",
                round(reference["total_seconds"], 1),
                round(PENDULUM_STEPS / reference["total_seconds"], 1),
                f"f32, torch threads: {threads or 'every core'}",
            ]
        )
    for row in rows:
        row.append(round(row[4] / reference["total_seconds"], 3) if reference is not None else None)
    headers.append("wall-clock ÷ SB3's")

    notes = (
        f"SAC's `pendulum` preset: the RL Zoo's Pendulum-v1 SAC (SB3's defaults: 256-256 networks, batch "
        f"256, one update per env step after 100 random steps, τ 0.005, automatic entropy, lr 1e-3), "
        f"{PENDULUM_STEPS:,} env steps; the final evaluation is 10 greedy episodes per seed. The agentax "
        f"rows are whole `python -m agentax.cli train sac --env Pendulum-v1` processes with an empty "
        f"compilation cache: {SEEDS} seeds on the compiled runner at `--precision auto` (split over the "
        "cores by the programs' cost), and one seed with the defaults. SB3 (stable-baselines3 + torch "
        "in `.bench-venv`) runs the same settings and steps as one whole process, with torch's faster "
        "thread count measured first; the last column divides each wall-clock by SB3's."
    )
    if threads is not None:
        notes += f" torch threads: {threads or 'every core (default)'}."
    if reference is None:
        notes += " `.bench-venv` holds no stable-baselines3 with mujoco here, so there is no SB3 row."
    return {
        "name": "sac",
        "title": "SAC on Pendulum-v1: 8 seeds, and the whole process against SB3",
        "headers": headers,
        "rows": rows,
        "notes": notes,
    }
