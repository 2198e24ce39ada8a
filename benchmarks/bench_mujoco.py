"""SAC and TD3 on HalfCheetah-v5: agent steps per second on agentax's runners beside Stable-Baselines3
(torch) and SBX (Stable Baselines Jax).

Every side runs the RL Zoo's MuJoCo settings (SAC: SB3's defaults, 256-256 networks, batch 256, one
learning step per env step; TD3: SB3's defaults with Gaussian exploration noise 0.1) on Gymnasium's
HalfCheetah-v5 for the same short run: ``RANDOM`` env steps of uniform actions, then learning until
``STEPS``. Two rates for each: the whole loop's (agentax's training loop, compilation included, the
final evaluation not; SB3's and SBX's ``model.learn``, SBX's compilation included), and the learning
phase's, from env step ``MARK`` to the end (agentax's first metrics row to its last; a callback's
time at that step for SB3 and SBX), which a 1M-step run spends nearly all its time in. agentax runs
in float32 (``--precision f32``) and as ``--precision auto`` chooses on this machine; SB3
(``.bench-venv``) takes torch's faster thread count (1 or every core, measured first); SBX
(``.sbx-venv``, made here the first time: ``sbx-rl`` 0.28 over jax 0.10.2) runs with XLA's defaults.
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
from pathlib import Path

from bench_sac import MARK_CALLBACK, ROOT, sb3, sb3_threads  # benchmarks/ is on sys.path (run.py)

RANDOM, STEPS = 1_000, 4_000
MARK = 2_048
"""The learning phase's rate counts the steps after this one: agentax's host runner's first row."""
RUNS = (("host", "f32"), ("host", "auto"), ("parallel", "auto"), ("compiled", "auto"))
"""agentax's rows: runner and ``--precision``."""
SBX_VENV = ROOT / ".sbx-venv"
SBX_REQUIREMENTS = ["sbx-rl==0.28.0", "jax==0.10.2", "jaxlib==0.10.2", "mujoco==4.0.0", "gymnasium==1.4.0"]
SBX_REQUIREMENTS += ["imageio", "packaging"]  # what sbx imports without declaring it

SBX_SCRIPT = (
    """
import json, sys, time
import gymnasium as gym, numpy as np
from sbx import SAC, TD3
from stable_baselines3.common.noise import NormalActionNoise
algo, steps, learning_starts, mark = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
"""
    + MARK_CALLBACK
    + """
env = gym.make("HalfCheetah-v5")
if algo == "sac":  # the RL Zoo's MuJoCo settings: SB3's defaults, learning_starts as agentax's run
    model = SAC("MlpPolicy", env, learning_starts=learning_starts, seed=0, verbose=0)
else:
    noise = NormalActionNoise(np.zeros(env.action_space.shape), 0.1 * np.ones(env.action_space.shape))
    model = TD3("MlpPolicy", env, learning_starts=learning_starts, action_noise=noise, seed=0, verbose=0)
callback, start = Mark(mark), time.perf_counter()
model.learn(total_timesteps=steps, callback=callback)
end = time.perf_counter()
print(json.dumps({"train_seconds": end - start, "after_mark_seconds": end - callback.seen}))
"""
)


def steps_per_second(algo: str, runner: str, precision: str) -> tuple[float, float, str]:
    """agentax's agent steps/s, the whole loop's and the learning phase's, and the precision its
    networks ran in."""
    import agentax

    with tempfile.TemporaryDirectory() as out:
        run = agentax.train(
            algo, env="HalfCheetah-v5", preset="mujoco", runner=runner, total_steps=STEPS,
            learning_starts=RANDOM, out=Path(out) / "run", progress=False, stop_at_return=None,
            precision=precision,
        )  # fmt: skip
        chosen = json.loads((Path(out) / "run" / "config.json").read_text())["precision"]
    rows = [row for row in run.result.rows if row["env_steps"] >= MARK]
    first, last = rows[0], rows[-1]
    learning = (last["env_steps"] - first["env_steps"]) / (last["wall_seconds"] - first["wall_seconds"])
    return STEPS / run.result.train_seconds, learning, chosen


def sbx(algo: str) -> tuple[float, float] | None:
    """SBX's agent steps/s, the whole loop's and the learning phase's, or None where ``.sbx-venv``
    cannot be made."""
    from bench_atari import bench_venv_python

    python, why = bench_venv_python(SBX_VENV, SBX_REQUIREMENTS, "import sbx, mujoco")
    if python is None:
        print(f"no SBX rows: {why}")
        return None
    command = [str(python), "-c", SBX_SCRIPT, algo, str(STEPS), str(RANDOM), str(MARK)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=1_800)
    if done.returncode != 0:
        print(f"no SBX row: {done.stderr.strip()[-400:]}")
        return None
    return rates(json.loads(done.stdout.strip().splitlines()[-1]))


def rates(timed: dict) -> tuple[float, float]:
    """A peer's agent steps/s from its ``train_seconds`` and ``after_mark_seconds``."""
    return STEPS / timed["train_seconds"], (STEPS - MARK) / timed["after_mark_seconds"]


def run() -> dict:
    os.environ.setdefault("MUJOCO_GL", "egl")
    rows = []
    threads = sb3_threads()
    for algo in ("sac", "td3"):
        reference = sb3(algo, "HalfCheetah-v5", STEPS, RANDOM, threads, MARK) if threads is not None else None
        sides = {"SB3": rates(reference) if reference is not None else None, "SBX": sbx(algo)}
        runs = [
            (f"agentax, {runner} runner, --precision {precision}", *steps_per_second(algo, runner, precision))
            for runner, precision in RUNS
        ]
        if sides["SB3"] is not None:
            torch_threads = f"{threads or 'every core'} thread(s)"
            runs.append((f"Stable-Baselines3 (torch, {torch_threads})", *sides["SB3"], "f32"))
        if sides["SBX"] is not None:
            runs.append(("SBX 0.28 (jax 0.10.2)", *sides["SBX"], "f32"))
        for label, whole, learning, chosen in runs:
            row = [algo.upper(), label, chosen, round(whole, 1), round(learning, 1)]
            row += [_ratio(whole, sides[peer] and sides[peer][0]) for peer in sides]
            row += [_ratio(learning, sides[peer] and sides[peer][1]) for peer in sides]
            rows.append(row)
    notes = (
        f"Gymnasium's HalfCheetah-v5, one env, {RANDOM:,} random steps then one learning step per env "
        f"step until {STEPS:,}: the RL Zoo's MuJoCo settings on every side (agentax's `mujoco` presets). "
        "The host runner steps the env and learns one after the other; the parallel runner's actor "
        "threads step it beside the learner; the compiled runner steps EnvPool's HalfCheetah-v5 inside "
        "one program with acting, the replay and learning, a row's steps per call. Steps/s are env "
        "steps (= agent steps: one env) per second: of the whole training loop, compilation included, and "
        f"of its learning phase, env steps {MARK:,} to {STEPS:,} (compilation outside). The "
        "precision is what the networks' products ran in (`bf16-onednn`: oneDNN's matmul with bfloat16 "
        "arithmetic; `bf16`: XLA's bfloat16 products)."
    )
    if not any(row[1].startswith("Stable") for row in rows):
        notes += " `.bench-venv` holds no stable-baselines3 with mujoco here, so there are no SB3 rows."
    return {
        "name": "mujoco",
        "title": "SAC and TD3 on HalfCheetah-v5: agent steps/s against SB3 and SBX",
        "headers": ["agent", "runner", "precision", "agent steps/s", "learning steps/s", "÷ SB3's", "÷ SBX's"]
        + ["learning ÷ SB3's", "learning ÷ SBX's"],
        "rows": rows,
        "notes": notes,
    }


def _ratio(ours: float, theirs: float | None) -> float | None:
    return round(ours / theirs, 2) if theirs else None
