"""Every core for many seeds: ``agentax train --seeds 64 --workers 2`` against the same command
confined to one core (``taskset -c 0``), and one process.

The compiled runner runs its vmapped program on a one-CPU XLA client (the cure for the CPU hang,
design page); ``--workers N`` splits the seeds over N spawned processes, one per core. The issue's
target: ``--seeds 64`` at least 1.7× faster than the same command confined to one core, in one run,
with the same numbers per seed. Each row is the whole command (``python -m agentax.cli train``:
start-up, compiles, training, final evaluation) in a fresh process, its programs from a warm
compilation cache (filled by an untimed run first), the fastest of ``REPEATS``; the per-seed final
evaluations of all rows are compared.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SEEDS, STEPS, REPEATS = 64, 50_000, 2
COMMAND = ["ppo", "--env", "CartPole-v1", "--preset", "default", "--seeds", str(SEEDS)]
COMMAND += ["--total-steps", str(STEPS), "--stop-at-return", "none", "--no-progress"]


def whole_command(prefix: list[str], workers: int, folder: Path) -> tuple[float, list[float]]:
    """Seconds of the whole ``agentax train`` and its per-seed final mean returns."""
    shutil.rmtree(folder, ignore_errors=True)
    start = time.perf_counter()
    command = [*prefix, sys.executable, "-m", "agentax.cli", "train", *COMMAND, "--workers", str(workers)]
    subprocess.run([*command, "--out", str(folder)], check=True, capture_output=True)
    seconds = time.perf_counter() - start
    per_seed = json.loads((folder / "eval.json").read_text())["per_seed"]
    return seconds, [s["mean_return"] for s in per_seed]


def run() -> dict:
    cases = {
        "1 process (--workers 1)": ([], 1),
        "2 workers, confined to one core (taskset -c 0)": (["taskset", "-c", "0"], 2),
        "2 workers, both cores": ([], 2),
    }
    with tempfile.TemporaryDirectory() as tmp:
        whole_command([], 2, Path(tmp) / "warm")  # fills the compilation cache for both slices
        whole_command([], 1, Path(tmp) / "warm")
        times: dict[str, list[float]] = {name: [] for name in cases}
        scores = {}
        for _ in range(REPEATS):  # interleaved, so a change of load touches every case alike
            for name, (prefix, workers) in cases.items():
                seconds, scores[name] = whole_command(prefix, workers, Path(tmp) / "run")
                times[name].append(seconds)
    fastest = {name: min(t) for name, t in times.items()}
    confined = fastest["2 workers, confined to one core (taskset -c 0)"]
    alone = np.asarray(scores["1 process (--workers 1)"])
    rows = [
        [
            name,
            f"{seconds:.1f}",
            f"{confined / seconds:.2f}×",
            f"{int((np.asarray(scores[name]) == alone).sum())} of {SEEDS}",
            f"{np.mean(scores[name]):.1f}",
        ]
        for name, seconds in fastest.items()
    ]
    ratio = confined / fastest["2 workers, both cores"]
    return {
        "name": "workers",
        "title": f"Every core: --seeds {SEEDS} of PPO CartPole over 2 worker processes",
        "headers": [
            "command",
            "whole command (s)",
            "speed-up over one core",
            "seeds whose final evaluation equals one process's",
            "mean final evaluation",
        ],
        "rows": rows,
        "notes": __doc__.split("\n\n", 1)[1].strip()
        + f"\n\n`agentax train {' '.join(COMMAND)} --workers N`. Target ≥ 1.7×: "
        + ("met" if ratio >= 1.7 else "missed")
        + f" ({ratio:.2f}×). All times: "
        + "; ".join(f"{name}: {', '.join(f'{t:.1f}' for t in ts)} s" for name, ts in times.items())
        + ".",
    }


if __name__ == "__main__":
    print(run())
