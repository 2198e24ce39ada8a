"""PPO on CartPole-v1: wall-clock to solve (the whole process), compile time, env steps per second.

Rows, all measured in this run:

- the whole ``agentax train ppo --env CartPole-v1`` process (start-up, compile, training until the
  first evaluation — 20 greedy episodes per seed — reaches a mean of 475, the final evaluation and
  the run folder), with an empty and with a warm compilation cache, for 1 seed and for 8 seeds
  vmapped into one program (every seed's evaluation must reach 475);
- the compiled runner's throughput (``cartpole-fast`` preset, 51,200 steps per seed, no early
  stop): env steps per second of training (all seeds), compile apart;
- the reference that installs everywhere: the same PPO on Gymnasium's own CartPole-v1 through the
  host runner (``agentax.runners.host.train``: Gymnasium steps the envs, the same jitted ``act``/``learn``),
  evaluated every 2,560 steps on 10 Gymnasium episodes;
- Stable-Baselines3 PPO with RL-Zoo's CartPole-v1 settings (8 envs, n_steps 32, batch 256, GAE 0.8,
  γ 0.98, 20 epochs, no entropy bonus, lr and clip linear from 1e-3 and 0.2, 1e5 steps; the whole
  process), only if stable-baselines3 and torch install into ``.bench-venv`` (created here).

The last column is SB3's whole-process wall-clock divided by each row's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCH_VENV = ROOT / ".bench-venv"
TORCH = "torch==2.13.0"
SOLVED = 475.0
WARM_REPEATS = 3  # warm-cache whole-process runs; the median is reported

SB3_SCRIPT = """
import json, time
start = time.perf_counter()
import gymnasium as gym
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
# RL-Baselines3-Zoo, hyperparams/ppo.yml, CartPole-v1
linear = lambda start: (lambda progress: progress * start)
model = PPO("MlpPolicy", make_vec_env("CartPole-v1", n_envs=8, seed=0), n_steps=32, batch_size=256,
            gae_lambda=0.8, gamma=0.98, n_epochs=20, ent_coef=0.0, learning_rate=linear(1e-3),
            clip_range=linear(0.2), seed=0, verbose=0, device="cpu")
train_start = time.perf_counter()
model.learn(total_timesteps=100_000)
train_seconds = time.perf_counter() - train_start
mean, std = evaluate_policy(model, gym.make("CartPole-v1"), n_eval_episodes=20)
print(json.dumps({"train_seconds": train_seconds, "total_seconds": time.perf_counter() - start,
                  "mean_return": float(mean)}))
"""


def sb3_python() -> Path | None:
    """The benchmark venv's python with stable-baselines3 and torch, or None if they do not install."""
    python = BENCH_VENV / "bin" / "python"
    check = [str(python), "-c", "import stable_baselines3, torch"]
    try:
        if python.exists() and subprocess.run(check, capture_output=True).returncode == 0:
            return python
        if not python.exists():
            subprocess.run([sys.executable, "-m", "venv", str(BENCH_VENV)], check=True, capture_output=True)
        install = [str(python), "-m", "pip", "install", "-q", "stable-baselines3", TORCH]
        if Path("/opt/wheels").is_dir():
            install += ["--find-links", "/opt/wheels"]
        subprocess.run(install, check=True, capture_output=True, timeout=900)
        return python if subprocess.run(check, capture_output=True).returncode == 0 else None
    except (subprocess.SubprocessError, OSError):
        return None


def _all_cpus() -> None:
    """Undo agentax's one-CPU pin (inherited by child processes) for a reference run."""
    try:
        os.sched_setaffinity(0, range(os.cpu_count() or 1))
    except OSError:
        pass


def whole_process(seeds: int, cache: Path) -> dict:
    """Run ``agentax train ppo --env CartPole-v1`` as a subprocess; its wall-clock and eval.json."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "run"
        command = [sys.executable, "-m", "agentax.cli", "train", "ppo", "--env", "CartPole-v1"]
        command += ["--seeds", str(seeds), "--out", str(out), "--no-progress"]
        env = {**os.environ, "AGENTAX_JAX_CACHE": str(cache)}
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True, env=env, timeout=600, preexec_fn=_all_cpus)
        wall = time.perf_counter() - start
        return {"wall": wall, **json.loads((out / "eval.json").read_text())}


def throughput(seeds: int) -> tuple[float, float]:
    """Env steps per second of the compiled runner (all seeds), and its compile seconds."""
    from _pin import pinned_to_one_cpu  # benchmarks/_pin.py: run.py puts this folder on sys.path

    from agentax.agents import ppo, presets
    from agentax.api import compiled_program
    from agentax.envs import make_jax
    from agentax.runners.compiled import RunnerConfig, train_program

    env, preset = make_jax("CartPole-v1"), presets.preset("ppo", "cartpole-fast")
    runner = RunnerConfig(num_seeds=seeds, updates_per_chunk=preset.updates_per_chunk, eval_every_chunks=1000)
    with pinned_to_one_cpu():
        result = train_program(compiled_program(ppo, env, preset.config), env, runner)
    return result.env_steps * seeds / result.train_seconds, result.compile_seconds


def host_reference() -> dict:
    """The same PPO preset on Gymnasium's CartPole-v1 through the host loop, stopping when solved."""
    from agentax.agents import ppo, presets
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_host_env
    from agentax.runners.host import HostRunnerConfig, train

    cfg = presets.preset("ppo", "cartpole-fast").config
    env = make_host_env("CartPole-v1", 1)
    agent = ppo.make_agent(EnvSpec.of(env), cfg)
    env.close()
    every = 10 * cfg.num_envs * cfg.num_steps  # 2,560 env steps
    runner = HostRunnerConfig(log_every_steps=every, eval_episodes=10, stop_at_return=SOLVED)
    start = time.perf_counter()
    result = train(agent, "CartPole-v1", runner, run=None)
    wall = time.perf_counter() - start
    solved = [r for r in result.rows if r["eval_return"] >= SOLVED]
    steps = result.env_steps
    train_seconds = result.rows[-1]["wall_seconds"] if result.rows else wall
    return {
        "wall": wall,
        "solved_env_steps": solved[0]["env_steps"] if solved else None,
        "solved_seconds": solved[0]["wall_seconds"] if solved else None,
        "steps_per_second": steps / train_seconds,
        "mean_return": result.eval["mean_return"],
    }


def run() -> dict:
    from agentax import _xla

    _xla.enable_compilation_cache()
    sb3 = None
    python = sb3_python()
    if python is not None:
        done = subprocess.run(
            [str(python), "-c", SB3_SCRIPT],
            capture_output=True,
            text=True,
            timeout=900,
            preexec_fn=_all_cpus,  # agentax pinned this process to one CPU; SB3 gets them all
        )
        if done.returncode == 0:
            sb3 = json.loads(done.stdout.strip().splitlines()[-1])

    def ratio(seconds):
        return round(sb3["total_seconds"] / seconds, 1) if sb3 and seconds else None

    rows = []
    with tempfile.TemporaryDirectory() as cache_folder:
        cache = Path(cache_folder)
        for seeds in (1, 8):
            for label in ("empty", "warm"):
                repeats = WARM_REPEATS if label == "warm" else 1
                runs = [whole_process(seeds, cache / f"seeds{seeds}") for _ in range(repeats)]
                result = sorted(runs, key=lambda r: r["wall"])[repeats // 2]  # the median
                rows.append(
                    [
                        f"agentax train ppo (whole process, {label} cache)",
                        seeds,
                        result.get("solved_env_steps"),
                        round(result["compile_seconds"], 2),
                        round(result["wall"], 2),
                        round(result["mean_return"], 1),
                        None,
                        ratio(result["wall"]),
                    ]
                )
    for seeds in (1, 8):
        speed, compile_seconds = throughput(seeds)
        rows.append(
            [
                "compiled runner, 51,200 steps/seed",
                seeds,
                None,
                round(compile_seconds, 2),
                None,
                None,
                round(speed),
                None,
            ]
        )
    host = host_reference()
    rows.append(
        [
            "host loop on Gymnasium CartPole-v1 (reference)",
            1,
            host["solved_env_steps"],
            None,
            round(host["wall"], 2),
            round(host["mean_return"], 1),
            round(host["steps_per_second"]),
            ratio(host["wall"]),
        ]
    )
    if sb3:
        rows.append(
            [
                "Stable-Baselines3 PPO, RL-Zoo settings, 1e5 steps",
                1,
                None,
                None,
                round(sb3["total_seconds"], 2),
                round(sb3["mean_return"], 1),
                round(100_000 / sb3["train_seconds"]),
                1.0,
            ]
        )
        sb3_note = (
            f" SB3 ran in `.bench-venv` (stable-baselines3 with {TORCH} on CPU): "
            f"{sb3['train_seconds']:.1f} s of training, {sb3['total_seconds']:.1f} s the whole process."
        )
    else:
        sb3_note = (
            " stable-baselines3/torch could not be installed in `.bench-venv` here, so there is no SB3 row."
        )
    notes = (
        "Solving = the first evaluation (20 greedy episodes per seed on fresh seeds) "
        "in which every seed's mean return is ≥ 475, checked every 2,560 env steps per seed; "
        "the runs stop there. "
        "The `cartpole-fast` preset: 8 envs × 32 steps, lr 3e-3 and clip 0.2 annealed, "
        "10 epochs × 2 minibatches, γ 0.98, GAE 0.8. 'Whole process' is the wall-clock of "
        "`agentax train ppo --env CartPole-v1 [--seeds 8]` as a subprocess, start-up and run folder "
        "included; 'empty cache' traces and compiles, 'warm cache' loads the stored programs "
        "(agentax.runners.programs: no tracing) and their compiled code (the persistent JAX cache); warm "
        "rows are the median of 3 runs. The host-loop reference runs inside this process (imports "
        "done, its small act/learn programs from the warm cache), so its wall-clock has no start-up in "
        "it. Env steps/s counts all seeds, training only." + sb3_note
    )
    return {
        "name": "ppo",
        "title": "PPO on CartPole-v1: time to solve, compile time, env steps/s",
        "headers": [
            "run",
            "seeds",
            "solved at env steps (per seed)",
            "compile s",
            "whole process s",
            "final eval mean",
            "env steps/s",
            "SB3 s ÷ this",
        ],
        "rows": rows,
        "notes": notes,
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
