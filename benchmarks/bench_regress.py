"""Nothing slower: this checkout's training speed beside an earlier commit's, at ``--precision f32``.

An earlier commit (``AGENTAX_BENCH_AGAINST``, default ``HEAD~1``) is checked out into a temporary
git worktree (the oneDNN kernel copied in where it is not built there) and each workload below runs
as the same ``agentax train`` command in both checkouts, from the same Python, alternating
earlier, this, earlier, this, ... ``REPEATS`` times; a row is the median of each.

- PPO, CartPole-v1, ``cartpole-fast``, 8 seeds vmapped, compiled runner, no early stop;
- DQN, CartPole-v1, ``default``, 8 seeds vmapped, compiled runner, 20k steps, no early stop;
- PQN, Breakout (EnvPool), ``breakout-hour``, compiled Atari runner, 8 updates.

The rate is agent steps per second of training from the run's metrics rows: from the first row to
the last, so the compilation and the first row fall outside (each checkout has its own compilation
cache).
"""

from __future__ import annotations

import csv
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
KERNEL = Path("src/agentax/_onednn_conv.so")
REPEATS = 3
WORKLOADS = {
    "PPO CartPole-v1, cartpole-fast, 8 seeds, compiled": (
        "ppo --env CartPole-v1 --preset cartpole-fast --seeds 8 --total-steps 102400"
    ),
    "DQN CartPole-v1, default, 8 seeds, compiled": (
        "dqn --env CartPole-v1 --preset default --seeds 8 --total-steps 20000"
    ),
    "PQN Breakout, breakout-hour, compiled Atari runner": (
        "pqn --env ALE/Breakout-v5 --preset breakout-hour --runner compiled --sticky-actions 0 "
        "--total-steps 16384"
    ),
}


def against() -> str:
    """The earlier commit, as ``git rev-parse --short`` names it."""
    rev = os.environ.get("AGENTAX_BENCH_AGAINST", "HEAD~1")
    return subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", rev], check=True, capture_output=True, text=True
    ).stdout.strip()


def steps_per_second(metrics: Path) -> float:
    """Agent steps per second of training, from the first metrics row to the last."""
    with metrics.open() as file:
        rows = list(csv.DictReader(file))
    first, last = rows[0], rows[-1]
    steps = float(last["env_steps"]) - float(first["env_steps"])
    return steps / (float(last["wall_seconds"]) - float(first["wall_seconds"]))


def train(checkout: Path, args: str, cache: Path, folder: Path) -> float:
    """One ``agentax train`` in ``checkout`` at ``--precision f32``; its training rate."""
    out = folder / "run"
    shutil.rmtree(out, ignore_errors=True)
    command = [sys.executable, "-m", "agentax.cli", "train", *args.split(), "--precision", "f32"]
    command += ["--stop-at-return", "none", "--out", str(out), "--no-progress"]
    env = {**os.environ, "PYTHONPATH": str(checkout / "src"), "AGENTAX_JAX_CACHE": str(cache)}
    subprocess.run(command, check=True, capture_output=True, env=env, timeout=900, cwd=checkout)
    return steps_per_second(out / "metrics.csv")


def run() -> dict:
    rev = against()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        earlier = Path(folder) / "earlier"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(earlier), rev], check=True
        )
        try:
            if (ROOT / KERNEL).exists() and not (earlier / KERNEL).exists():
                shutil.copy2(ROOT / KERNEL, earlier / KERNEL)
            checkouts = {"earlier": earlier, "this": ROOT}
            for label, args in WORKLOADS.items():
                rates: dict[str, list[float]] = {name: [] for name in checkouts}
                for _ in range(REPEATS):
                    for name, checkout in checkouts.items():
                        cache = Path(folder) / f"cache-{name}"
                        rates[name].append(train(checkout, args, cache, Path(folder)))
                old, new = (statistics.median(rates[name]) for name in checkouts)
                rows.append([label, round(old), round(new), round(new / old, 3)])
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(earlier)])
    return {
        "name": "regress",
        "title": f"Nothing slower: this checkout against {rev}, --precision f32",
        "headers": ["workload", f"{rev} steps/s", "this checkout steps/s", "this ÷ earlier"],
        "rows": rows,
        "notes": (
            f"Each workload is the same `agentax train ... --precision f32 --stop-at-return none` "
            f"command in a worktree of {rev} and in this checkout, from the same Python, alternating, "
            f"{REPEATS} times each (the median); agent steps per second of training "
            "from the first metrics row to the last (compilation and the first row outside). "
            + "; ".join(f"{label}: `agentax train {args}`" for label, args in WORKLOADS.items())
            + ". A ratio under 0.95 is a slowdown."
        ),
    }
