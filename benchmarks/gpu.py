"""agentax on a GPU beside this machine's CPU: run by ``benchmarks/gpu.sh`` (see there).

Each case is the whole ``agentax train`` command, timed as a process, once as it runs by default
(on the GPU where JAX has one: no flag) and once with ``JAX_PLATFORMS=cpu`` (every core of this
machine): PPO on CartPole-v1 with 1, 64 and 1,024 seeds vmapped, PQN on MinAtar Breakout with 8
seeds and SAC on Pendulum-v1 with 8 seeds, each with its preset, on the compiled runner. A row:
the case, each device's seconds, env steps per second and final evaluation (the mean over seeds
of their greedy returns), and the CPU's time over the GPU's. ``AGENTAX_GPU_SCALE`` (default 1)
scales every case's steps; the defaults fit 10 minutes on one GPU and 16 cores.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SCALE = float(os.environ.get("AGENTAX_GPU_SCALE", "1"))
CASES = [  # (name, agentax train arguments, env steps per seed)
    ("PPO CartPole-v1, 1 seed", ["ppo", "--env", "CartPole-v1", "--seeds", "1"], 100_000),
    ("PPO CartPole-v1, 64 seeds", ["ppo", "--env", "CartPole-v1", "--seeds", "64"], 100_000),
    ("PPO CartPole-v1, 1,024 seeds", ["ppo", "--env", "CartPole-v1", "--seeds", "1024"], 20_000),
    ("PQN Breakout-MinAtar, 8 seeds", ["pqn", "--env", "gymnax/Breakout-MinAtar", "--seeds", "8"], 500_000),
    ("SAC Pendulum-v1, 8 seeds", ["sac", "--env", "Pendulum-v1", "--seeds", "8"], 5_000),
]
FIXED = ["--runner", "compiled", "--stop-at-return", "none", "--no-progress"]


def device(env: dict[str, str]) -> str:
    """What JAX runs on under ``env``: its default backend and first device's kind."""
    probe = "import jax; d = jax.devices()[0]; print(jax.default_backend(), '/', d.device_kind)"
    done = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=120)
    return done.stdout.strip() or f"none ({done.stderr.strip().splitlines()[-1:]})"


def timed_run(args: list[str], steps: int, env: dict[str, str], out: Path) -> tuple[float, float]:
    """``agentax train ARGS`` as a process: (seconds, final mean greedy return over the seeds)."""
    command = [sys.executable, "-m", "agentax.cli", "train", *args, "--total-steps", str(steps), *FIXED]
    start = time.perf_counter()
    subprocess.run([*command, "--out", str(out)], env=env, check=True, stdout=subprocess.DEVNULL)
    seconds = time.perf_counter() - start
    return seconds, json.loads((out / "eval.json").read_text())["mean_return"]


def main() -> None:
    accelerated, on_cpu = dict(os.environ), {**os.environ, "JAX_PLATFORMS": "cpu"}
    devices = {"default": device(accelerated), "cpu": device(on_cpu)}
    print(f"default device: {devices['default']}; CPU: {devices['cpu']}, {os.cpu_count()} cores", flush=True)
    if devices["default"].startswith("cpu"):
        print("no GPU here: JAX's default backend is the CPU, so both columns run on it", flush=True)
    header = "| case | env steps | default s | steps/s | eval | CPU s | steps/s | eval | CPU ÷ default |"
    print(header + "\n" + "| --- " * 9 + "|", flush=True)
    with tempfile.TemporaryDirectory(prefix="agentax-gpu-") as tmp:
        for index, (name, args, per_seed) in enumerate(CASES):
            seeds = int(args[args.index("--seeds") + 1])
            steps = max(int(per_seed * SCALE), 1_000)
            first = timed_run(args, steps, accelerated, Path(tmp) / f"{index}-default")
            second = timed_run(args, steps, on_cpu, Path(tmp) / f"{index}-cpu")
            total = steps * seeds
            cells = [name, f"{total:,}"]
            for seconds, score in (first, second):
                cells += [f"{seconds:.1f}", f"{total / seconds:,.0f}", f"{score:.1f}"]
            print("| " + " | ".join(cells) + f" | {second[0] / first[0]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
