"""SAC and TD3 on HalfCheetah-v5: agent steps per second on agentax's runners beside Stable-Baselines3
(torch) and SBX (Stable Baselines Jax).

Every side runs the RL Zoo's MuJoCo settings (SAC: SB3's defaults, 256-256 networks, batch 256, one
learning step per env step; TD3: SB3's defaults with Gaussian exploration noise 0.1) on Gymnasium's
HalfCheetah-v5 for the same short run: ``RANDOM`` env steps of uniform actions, then learning until
``STEPS``. agentax's figure is its training loop's wall-clock (compilation included, the final
evaluation not), SB3's and SBX's that of ``model.learn`` (SBX's compilation included). agentax runs
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

from bench_sac import ROOT, sb3, sb3_threads  # benchmarks/ is on sys.path (run.py)

RANDOM, STEPS = 1_000, 4_000
RUNS = (("host", "f32"), ("host", "auto"), ("parallel", "auto"), ("compiled", "auto"))
"""agentax's rows: runner and ``--precision``."""
SBX_VENV = ROOT / ".sbx-venv"
SBX_REQUIREMENTS = ["sbx-rl==0.28.0", "jax==0.10.2", "jaxlib==0.10.2", "mujoco==4.0.0", "gymnasium==1.4.0"]
SBX_REQUIREMENTS += ["imageio", "packaging"]  # what sbx imports without declaring it

SBX_SCRIPT = """
import json, sys, time
import gymnasium as gym, numpy as np
from sbx import SAC, TD3
from stable_baselines3.common.noise import NormalActionNoise
algo, steps, learning_starts = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
env = gym.make("HalfCheetah-v5")
if algo == "sac":  # the RL Zoo's MuJoCo settings: SB3's defaults, learning_starts as agentax's run
    model = SAC("MlpPolicy", env, learning_starts=learning_starts, seed=0, verbose=0)
else:
    noise = NormalActionNoise(np.zeros(env.action_space.shape), 0.1 * np.ones(env.action_space.shape))
    model = TD3("MlpPolicy", env, learning_starts=learning_starts, action_noise=noise, seed=0, verbose=0)
start = time.perf_counter()
model.learn(total_timesteps=steps)
print(json.dumps({"train_seconds": time.perf_counter() - start}))
"""


def steps_per_second(algo: str, runner: str, precision: str) -> tuple[float, str]:
    """agentax's agent steps/s, and the precision its networks ran in."""
    import agentax

    with tempfile.TemporaryDirectory() as out:
        run = agentax.train(
            algo, env="HalfCheetah-v5", preset="mujoco", runner=runner, total_steps=STEPS,
            learning_starts=RANDOM, out=Path(out) / "run", progress=False, stop_at_return=None,
            precision=precision,
        )  # fmt: skip
        chosen = json.loads((Path(out) / "run" / "config.json").read_text())["precision"]
    return STEPS / run.result.train_seconds, chosen


def sbx(algo: str) -> float | None:
    """SBX's agent steps/s, or None where ``.sbx-venv`` cannot be made."""
    from bench_atari import bench_venv_python

    python, why = bench_venv_python(SBX_VENV, SBX_REQUIREMENTS, "import sbx, mujoco")
    if python is None:
        print(f"no SBX rows: {why}")
        return None
    command = [str(python), "-c", SBX_SCRIPT, algo, str(STEPS), str(RANDOM)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=1_800)
    if done.returncode != 0:
        print(f"no SBX row: {done.stderr.strip()[-400:]}")
        return None
    return STEPS / json.loads(done.stdout.strip().splitlines()[-1])["train_seconds"]


def run() -> dict:
    os.environ.setdefault("MUJOCO_GL", "egl")
    rows = []
    threads = sb3_threads()
    for algo in ("sac", "td3"):
        reference = sb3(algo, "HalfCheetah-v5", STEPS, RANDOM, threads) if threads is not None else None
        theirs = STEPS / reference["train_seconds"] if reference is not None else None
        jax_peer = sbx(algo)
        for runner, precision in RUNS:
            ours, chosen = steps_per_second(algo, runner, precision)
            rows.append([algo.upper(), f"agentax, {runner} runner, --precision {precision}", chosen,
                         round(ours, 1), _ratio(ours, theirs), _ratio(ours, jax_peer)])  # fmt: skip
        if theirs is not None:
            torch_threads = f"{threads or 'every core'} thread(s)"
            rows.append([algo.upper(), f"Stable-Baselines3 (torch, {torch_threads})", "f32", round(theirs, 1),
                         1.0, _ratio(theirs, jax_peer)])  # fmt: skip
        if jax_peer is not None:
            rows.append([algo.upper(), "SBX 0.28 (jax 0.10.2)", "f32", round(jax_peer, 1),
                         _ratio(jax_peer, theirs), 1.0])  # fmt: skip
    notes = (
        f"Gymnasium's HalfCheetah-v5, one env, {RANDOM:,} random steps then one learning step per env "
        f"step until {STEPS:,}: the RL Zoo's MuJoCo settings on every side (agentax's `mujoco` presets). "
        "The host runner steps the env and learns one after the other; the parallel runner's actor "
        "threads step it beside the learner; the compiled runner steps EnvPool's HalfCheetah-v5 inside "
        "one program with acting, the replay and learning, a row's steps per call. Steps/s are env "
        "steps (= agent steps: one env) per second of the training loop, compilation included. The "
        "precision is what the networks' products ran in (`bf16-onednn`: oneDNN's matmul with bfloat16 "
        "arithmetic; `bf16`: XLA's bfloat16 products)."
    )
    if not any(row[1].startswith("Stable") for row in rows):
        notes += " `.bench-venv` holds no stable-baselines3 with mujoco here, so there are no SB3 rows."
    return {
        "name": "mujoco",
        "title": "SAC and TD3 on HalfCheetah-v5: agent steps/s against SB3 and SBX",
        "headers": ["agent", "runner", "precision", "agent steps/s", "÷ SB3's", "÷ SBX's"],
        "rows": rows,
        "notes": notes,
    }


def _ratio(ours: float, theirs: float | None) -> float | None:
    return round(ours / theirs, 2) if theirs else None
