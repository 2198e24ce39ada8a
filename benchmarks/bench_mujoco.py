"""SAC and TD3 on HalfCheetah-v5: agent steps per second on agentax's runners beside Stable-Baselines3's.

Both sides run the RL Zoo's MuJoCo settings (SAC: SB3's defaults, 256-256 networks, batch 256, one
learning step per env step; TD3: SB3's defaults with Gaussian exploration noise 0.1) on Gymnasium's
HalfCheetah-v5 for the same short run: ``RANDOM`` env steps of uniform actions, then learning until
``STEPS``. agentax's figure is its training loop's wall-clock (compilation included, the final
evaluation not), SB3's that of ``model.learn``; SB3 (``.bench-venv``) takes torch's faster thread
count (1 or every core, measured first), agentax one core.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from bench_sac import sb3, sb3_threads  # benchmarks/ is on sys.path (run.py)

RANDOM, STEPS = 1_000, 4_000
RUNNERS = ("host", "parallel")


def steps_per_second(algo: str, runner: str) -> float:
    import agentax

    with tempfile.TemporaryDirectory() as out:
        run = agentax.train(
            algo, env="HalfCheetah-v5", preset="mujoco", runner=runner, total_steps=STEPS,
            learning_starts=RANDOM, out=Path(out) / "run", progress=False, stop_at_return=None,
        )  # fmt: skip
    return STEPS / run.result.train_seconds


def run() -> dict:
    os.environ.setdefault("MUJOCO_GL", "egl")
    rows = []
    threads = sb3_threads()
    for algo in ("sac", "td3"):
        reference = sb3(algo, "HalfCheetah-v5", STEPS, RANDOM, threads) if threads is not None else None
        theirs = STEPS / reference["train_seconds"] if reference is not None else None
        for runner in RUNNERS:
            ours = steps_per_second(algo, runner)
            rows.append([algo.upper(), f"agentax, {runner} runner", round(ours, 1),
                         round(ours / theirs, 2) if theirs else None])  # fmt: skip
        if theirs is not None:
            rows.append([algo.upper(), f"Stable-Baselines3 (torch, {threads or 'every core'} thread(s))",
                         round(theirs, 1), 1.0])  # fmt: skip
    notes = (
        f"Gymnasium's HalfCheetah-v5, one env, {RANDOM:,} random steps then one learning step per env "
        f"step until {STEPS:,}: the RL Zoo's MuJoCo settings on both sides (agentax's `mujoco` presets). "
        "The host runner steps the env and learns one after the other; the parallel runner's actor "
        "threads step it beside the learner. Steps/s are env steps (= agent steps: one env) per second "
        "of the training loop, compilation included."
    )
    if not any(row[1].startswith("Stable") for row in rows):
        notes += " `.bench-venv` holds no stable-baselines3 with mujoco here, so there are no SB3 rows."
    return {
        "name": "mujoco",
        "title": "SAC and TD3 on HalfCheetah-v5: agent steps/s against SB3",
        "headers": ["agent", "runner", "agent steps/s", "÷ SB3's"],
        "rows": rows,
        "notes": notes,
    }
