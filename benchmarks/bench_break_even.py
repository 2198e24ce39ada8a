"""Where every core starts to pay: ``agentax train --seeds N`` in one process against over
``--workers 2``, the whole command, as the run grows.

A worker is a spawned process that imports jax and loads (or compiles) its program before it
trains, so a split run pays that start-up once more; it gains once the training it halves is
longer. The rows run PPO on CartPole (the cheapest agent step agentax has, so a costlier one gains
sooner) with 64 seeds (vmapped, the cheapest per seed) and 8, over growing numbers of steps. From
the first size where two workers are faster at both seed counts, ``agentax train`` and
``agentax sweep`` split by themselves (``agentax.runners.workers.BREAK_EVEN_AGENT_STEPS``, turned
into the program's cost: the split goes by it, not by steps). The last rows run a costly program,
SAC on Pendulum-v1 with 8 seeds (its preset ``pendulum``: 256-unit networks, a learning step each
agent step), once each, at step counts far below PPO's break-even. Each
command runs in a fresh process, its programs from a warm compilation cache (filled by an untimed
run of each shape first), the fastest of ``REPEATS``, the cases interleaved.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

SIZES = [(64, 4_000), (64, 16_000), (64, 64_000), (8, 32_000), (8, 125_000)]
"""(seeds, total steps of each): agent steps 256k, 1M, 4M with 64 seeds; 256k, 1M with 8"""
REPEATS = 2
HEAVY = [(8, 500), (8, 2_000)]
"""SAC's (seeds, total steps of each): agent steps 4k and 16k, each run once"""
ENVS = {"ppo": "CartPole-v1", "sac": "Pendulum-v1"}
PRESETS = {"ppo": "default", "sac": "pendulum"}


def whole_command(seeds: int, steps: int, workers: int, folder: Path, algo: str = "ppo") -> float:
    """Seconds of the whole ``agentax train`` of PPO CartPole (or SAC Pendulum)."""
    command = [sys.executable, "-m", "agentax.cli", "train", algo, "--env", ENVS[algo]]
    command += ["--preset", PRESETS[algo], "--seeds", str(seeds), "--total-steps", str(steps)]
    command += ["--stop-at-return", "none", "--no-progress", "--workers", str(workers)]
    start = time.perf_counter()
    subprocess.run([*command, "--out", str(folder)], check=True, capture_output=True)
    return time.perf_counter() - start


def run_label(seeds: int, steps: int, algo: str = "ppo") -> str:
    """The row's name: PPO's as it has always been, another algorithm's with its name and env first."""
    prefix = "" if algo == "ppo" else f"{algo} {ENVS[algo]} "
    return f"{prefix}--seeds {seeds} --total-steps {steps:,}"


def run() -> dict:
    from agentax.runners.workers import BREAK_EVEN_AGENT_STEPS

    with tempfile.TemporaryDirectory() as tmp:
        folders = iter(Path(tmp) / f"run-{i}" for i in range(10_000))
        for seeds in sorted({seeds for seeds, _ in SIZES}):  # the programs of both splits, cached
            for workers in (1, 2):
                whole_command(seeds, 512, workers, next(folders))
        times = {(size, w): [] for size in SIZES for w in (1, 2)}
        for _ in range(REPEATS):
            for (seeds, steps), workers in times:
                times[(seeds, steps), workers].append(whole_command(seeds, steps, workers, next(folders)))
        for workers in (1, 2):  # SAC's programs, cached
            whole_command(*HEAVY[0], workers, next(folders), "sac")
        heavy = {(size, w): whole_command(*size, w, next(folders), "sac") for size in HEAVY for w in (1, 2)}
    rows = []
    for seeds, steps in SIZES:
        one, two = min(times[(seeds, steps), 1]), min(times[(seeds, steps), 2])
        rows.append([run_label(seeds, steps), seeds * steps, round(one, 1), round(two, 1), one / two])
    gains = {row[1] for row in rows if row[2] > row[3]}
    everywhere = sorted(n for n in gains if all(r[2] > r[3] for r in rows if r[1] >= n))
    for seeds, steps in HEAVY:
        one, two = heavy[(seeds, steps), 1], heavy[(seeds, steps), 2]
        rows.append([run_label(seeds, steps, "sac"), seeds * steps, round(one, 1), round(two, 1), one / two])
    found = (
        f"PPO: two workers are faster from {everywhere[0]:,} agent steps on (at every size from there);"
        if everywhere
        else "PPO: two workers were faster at no size measured;"
    )
    return {
        "name": "break_even",
        "title": "Every core by default: one process against --workers 2 as the run grows (PPO, SAC)",
        "headers": [
            "run",
            "agent steps",
            "one process (s)",
            "2 workers (s)",
            "speed-up",
        ],
        "rows": rows,
        "notes": __doc__.split("\n\n", 1)[1].strip() + f"\n\n{found} the default split starts at "
        f"{BREAK_EVEN_AGENT_STEPS:,} (``BREAK_EVEN_AGENT_STEPS``).",
    }


if __name__ == "__main__":
    print(run())
