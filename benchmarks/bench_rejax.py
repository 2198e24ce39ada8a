"""Many small agents: 64 PPO seeds on CartPole-v1 at Rejax's own settings, agentax beside Rejax.

Rejax's ``configs/gymnax/cartpole.yaml`` PPO (5 envs × 100 steps, 5 epochs × 5 minibatches, lr 7.5e-4
not annealed, clip 0.2, entropy 0.01, grad norm 0.5, γ 0.99, λ 0.95, 64-64 tanh, 100k env steps per
seed), 64 seeds vmapped into one program in each library, each timed as a whole process with an
empty compilation cache, one after the other with nothing else running:

- the whole ``agentax train ppo`` command (the compiled runner: its default ~10 evaluations of 20
  greedy episodes per seed during training and a final one; the every-core rule chooses the
  processes);
- Rejax 0.1.3 (with gymnax 0.0.9, in ``.rejax-venv``: ``jax.jit(jax.vmap(PPO.train))`` over 64
  keys) with its yaml's ``eval_freq`` of 1,000 steps (101 evaluations of 128 episodes per seed, as
  its config trains), and again with ``eval_freq`` 100,000 (an evaluation at the start and one at
  the end), which leaves its training nearly alone.

Each row: the seconds of the whole process, the evaluations of the run, the mean over the seeds of
the final evaluation, and agentax's time ÷ that row's. Rejax's evaluations are part of its
program, so the second Rejax row is the fairer measure of its training.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REJAX_VENV = ROOT / ".rejax-venv"
REJAX_REQUIREMENTS = ("rejax==0.1.3", "gymnax==0.0.9")  # rejax 0.1.3 fails with gymnax 1.0's step API
SEEDS = 64
SETTINGS = {
    "num_envs": 5, "num_steps": 100, "num_epochs": 5, "num_minibatches": 5, "learning_rate": 0.00075,
    "max_grad_norm": 0.5, "total_timesteps": 100_000, "gamma": 0.99, "gae_lambda": 0.95,
    "clip_eps": 0.2, "ent_coef": 0.01, "vf_coef": 0.5,
}  # fmt: skip
"""Rejax's configs/gymnax/cartpole.yaml, PPO (its eval_freq set per row)"""
AGENTAX_ARGS = [
    "--num-envs", "5", "--num-steps", "100", "--update-epochs", "5", "--num-minibatches", "5",
    "--learning-rate", "0.00075", "--no-anneal-lr", "--clip-eps", "0.2", "--no-anneal-clip",
    "--ent-coef", "0.01", "--vf-coef", "0.5", "--max-grad-norm", "0.5", "--discount-factor", "0.99",
    "--gae-lambda", "0.95", "--hidden", "64", "64", "--activation", "tanh", "--total-steps", "100000",
]  # fmt: skip

REJAX_SCRIPT = """
import json, sys
import jax, numpy as np
from rejax import PPO
settings, seeds, eval_freq = json.loads(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
algo = PPO.create(env="CartPole-v1", agent_kwargs={"activation": "tanh"}, eval_freq=eval_freq, **settings)
keys = jax.random.split(jax.random.PRNGKey(0), seeds)
_, (lengths, returns) = jax.jit(jax.vmap(algo.train))(keys)
returns = np.asarray(returns)  # [seeds, evaluations, episodes]
print(json.dumps({"evaluations": returns.shape[1], "episodes": returns.shape[2],
                  "final": float(returns[:, -1].mean()), "jax": jax.__version__}))
"""


def rejax_python() -> tuple[Path | None, str]:
    """``.rejax-venv``'s python with Rejax (made here the first time), or None and why not."""
    from bench_atari import bench_venv_python

    return bench_venv_python(REJAX_VENV, list(REJAX_REQUIREMENTS), "import rejax, gymnax")


def rejax(python: Path, eval_freq: int) -> list:
    """Rejax's 64 seeds with ``eval_freq``, timed as a whole process: a row."""
    command = [str(python), "-c", REJAX_SCRIPT, json.dumps(SETTINGS), str(SEEDS), str(eval_freq)]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, timeout=1_800, check=True)
    seconds = time.perf_counter() - start
    out = json.loads(done.stdout.strip().splitlines()[-1])
    name = f"Rejax 0.1.3 PPO, eval_freq {eval_freq:,} (jax {out['jax']})"
    evaluations = f"{out['evaluations']} × {out['episodes']} episodes"
    print(f"{name}: {seconds:.1f} s, final {out['final']:.1f}", flush=True)
    return [name, evaluations, round(seconds, 1), round(out["final"], 1)]


def agentax() -> list:
    """The whole ``agentax train ppo --seeds 64`` command: a row."""
    from bench_memory import first_train

    args = ["ppo", "--env", "CartPole-v1", *AGENTAX_ARGS, "--seeds", str(SEEDS), "--stop-at-return", "none"]
    seconds, evaluation, metrics = first_train(args, timeout=1_800)
    header = metrics[0].split(",")
    evals = sum(1 for line in metrics[1:] if line.split(",")[header.index("eval_return")] != "")
    final = float(np.mean([seed["mean_return"] for seed in evaluation["per_seed"]]))
    print(f"agentax: {seconds:.1f} s, final {final:.1f}", flush=True)
    name = f"agentax train ppo --seeds {SEEDS} (compiled runner)"
    return [name, f"{evals} + final × 20 episodes", round(seconds, 1), round(final, 1)]


def run() -> dict:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    rows = [agentax()]
    python, why = rejax_python()
    if python is not None:
        rows += [rejax(python, 1_000), rejax(python, 100_000)]
    for row in rows:
        row.append(round(rows[0][2] / row[2], 3))
    return {
        "name": "rejax",
        "title": f"Many small agents: {SEEDS} PPO seeds on CartPole-v1 at Rejax's settings, whole process",
        "headers": [
            "run",
            "evaluations (per seed)",
            "seconds",
            "final eval, mean of seeds",
            "agentax ÷ this",
        ],
        "rows": rows,
        "rejax": why or "ran",
        "notes": __doc__.split("\n\n", 1)[1].strip(),
    }
