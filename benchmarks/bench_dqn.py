"""DQN on CartPole-v1: wall-clock to solve and learner updates per second, on every runner.

Rows, all measured in this run:

- the compiled runner (``agentax.runners.compiled``, the JAX CartPole, DQN's ``default`` preset) with
  1 and with 8 seeds vmapped into one program: compile time, wall-clock from the start of training
  to the first evaluation (20 greedy episodes per seed) whose mean reaches 475, learner updates
  (gradient steps, summed over seeds) per second of training, and the final per-seed evaluation;
- the host runner (``agentax.runners.host.train``) on Gymnasium's own CartPole-v1, same preset: the
  greedy policy is evaluated on 10 Gymnasium episodes every 2,048 env steps;
- the whole ``agentax train dqn --env CartPole-v1`` process (start-up, compile, training until
  solved, final evaluation, run folder), with an empty and with a warm compilation cache;
- Stable-Baselines3 DQN with RL-Zoo's CartPole-v1 settings (5e4 steps, the whole process), only if
  ``.bench-venv`` holds stable-baselines3 (the policy-gradient benchmark creates it); the last
  column is its wall-clock divided by each row's.
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
SOLVED = 475.0
WARM_REPEATS = 3  # warm-cache whole-process runs; the median is reported

SB3_SCRIPT = """
import json, time
start = time.perf_counter()
import gymnasium as gym
from stable_baselines3 import DQN
from stable_baselines3.common.evaluation import evaluate_policy
# RL-Baselines3-Zoo, hyperparams/dqn.yml, CartPole-v1
model = DQN("MlpPolicy", gym.make("CartPole-v1"), learning_rate=2.3e-3, batch_size=64, buffer_size=100_000,
            learning_starts=1_000, gamma=0.99, target_update_interval=10, train_freq=256, gradient_steps=128,
            exploration_fraction=0.16, exploration_final_eps=0.04, policy_kwargs=dict(net_arch=[256, 256]),
            seed=0, verbose=0)
train_start = time.perf_counter()
model.learn(total_timesteps=50_000)
train_seconds = time.perf_counter() - train_start
mean, std = evaluate_policy(model, gym.make("CartPole-v1"), n_eval_episodes=20)
print(json.dumps({"train_seconds": train_seconds, "total_seconds": time.perf_counter() - start,
                  "mean_return": float(mean), "updates": int(model._n_updates)}))
"""


def compiled_row(num_seeds: int) -> list:
    from _pin import pinned_to_one_cpu  # benchmarks/_pin.py: run.py puts this folder on sys.path

    from agentax.agents import dqn, presets
    from agentax.api import compiled_program
    from agentax.envs import make_jax
    from agentax.runners.compiled import RunnerConfig, train_program

    preset = presets.preset("dqn", "default")
    env = make_jax("CartPole-v1")
    runner = RunnerConfig(
        seed=0,
        num_seeds=num_seeds,
        updates_per_chunk=preset.updates_per_chunk,
        eval_episodes=preset.eval_episodes,
        stop_at_return=SOLVED,
        freeze_at_return=preset.freeze_at_return,
    )
    with pinned_to_one_cpu():
        result = train_program(compiled_program(dqn, env, preset.config, runner), env, runner)
    learning_steps = float(np.sum(np.asarray(result.state.agent.step)))
    per_seed = np.asarray(result.eval["per_seed_mean"])
    solved_wall = result.solved_seconds if result.solved_seconds is not None else float("nan")
    return [
        "compiled (JAX CartPole)",
        num_seeds,
        f"{int(np.sum(per_seed >= SOLVED))}/{num_seeds}",
        result.solved_env_steps if result.solved_env_steps is not None else float("nan"),
        round(result.compile_seconds, 2),
        round(solved_wall, 2),
        learning_steps / result.train_seconds,
        result.env_steps * num_seeds / result.train_seconds,
    ]


def host_row() -> list:
    from agentax.agents import dqn, presets
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_host_env
    from agentax.runners.host import HostRunnerConfig, train

    cfg = presets.preset("dqn", "default").config
    env = make_host_env("CartPole-v1", 1)
    agent = dqn.make_agent(EnvSpec.of(env), cfg)
    env.close()
    runner = HostRunnerConfig(seed=0, log_every_steps=2_048, eval_episodes=10, stop_at_return=SOLVED)
    start = time.perf_counter()
    result = train(agent, "CartPole-v1", runner, run=None)
    seconds = time.perf_counter() - start
    last = result.rows[-1]
    solved = last["eval_return"] >= SOLVED
    return [
        "host runner (Gymnasium CartPole)",
        1,
        f"{int(result.eval['mean_return'] >= SOLVED)}/1",
        last["env_steps"] if solved else float("nan"),
        float("nan"),
        round(seconds, 2) if solved else float("nan"),
        last["updates"] / last["wall_seconds"],
        last["env_steps"] / last["wall_seconds"],
    ]


def cli_row(cache: str, algo: str = "dqn") -> list:
    """The whole ``agentax train ALGO --env CartPole-v1`` process; ``cache``: a compilation cache folder."""
    with tempfile.TemporaryDirectory() as out:
        env = dict(os.environ, AGENTAX_JAX_CACHE=cache)
        command = [
            sys.executable,
            "-m",
            "agentax.cli",
            "train",
            algo,
            "--env",
            "CartPole-v1",
            "--out",
            out + "/run",
        ]
        start = time.perf_counter()
        subprocess.run([*command, "--no-progress"], check=True, capture_output=True, env=env, timeout=600)
        seconds = time.perf_counter() - start
        evaluation = json.loads((Path(out) / "run" / "eval.json").read_text())
        rows = (Path(out) / "run" / "metrics.csv").read_text().splitlines()
    return [seconds, evaluation["mean_return"], len(rows) - 1]


def sb3_result() -> dict | None:
    python = BENCH_VENV / "bin" / "python"
    probe = [str(python), "-c", "import stable_baselines3, torch"]
    if not python.exists() or subprocess.run(probe, capture_output=True).returncode != 0:
        return None
    done = subprocess.run([str(python), "-c", SB3_SCRIPT], capture_output=True, text=True, timeout=900)
    if done.returncode != 0:
        return None
    return json.loads(done.stdout.strip().splitlines()[-1])


def run() -> dict:
    headers = [
        "runner",
        "seeds",
        "solved (final eval ≥ 475)",
        "env steps to solve",
        "compile s",
        "wall-clock to solve s",
        "learner updates/s",
        "env steps/s",
        "SB3 DQN ÷ this",
    ]
    rows = [compiled_row(1), compiled_row(8), host_row()]
    processes = []
    for algo in ("dqn", "pqn"):  # PQN: its default preset, Q(λ) from 16 envs' rollouts, no replay
        with tempfile.TemporaryDirectory() as cache:
            cold = cli_row(cache, algo)
            runs = sorted((cli_row(cache, algo) for _ in range(WARM_REPEATS)), key=lambda r: r[0])
            processes += [(algo, "cold", cold), (algo, "warm", runs[WARM_REPEATS // 2])]
    for algo, label, (seconds, mean_return, _) in processes:
        solved = "1/1" if mean_return >= SOLVED else "0/1"
        rows.append(
            [
                f"`agentax train {algo}` process, {label} compile cache",
                1,
                solved,
                None,
                None,
                round(seconds, 2),
                None,
                None,
            ]
        )
    sb3 = sb3_result()
    if sb3 is not None:
        solved = "1/1" if sb3["mean_return"] >= SOLVED else "0/1"
        sb3_row = [
            "SB3 DQN, RL-Zoo settings, whole process",
            1,
            solved,
            50_000,
            None,
            round(sb3["total_seconds"], 2),
        ]
        sb3_row += [sb3["updates"] / sb3["train_seconds"], 50_000 / sb3["train_seconds"]]
        rows.append(sb3_row)
    for row in rows:
        ratio = sb3["total_seconds"] / row[5] if sb3 is not None and row[5] and row[5] == row[5] else None
        row.append(round(ratio, 1) if ratio is not None else None)
    notes = (
        "DQN's `default` preset (RL-Zoo's CartPole-v1 DQN as the starting point — 2.3e-3 learning rate, "
        "batch 64, 128 learning steps per 256 env steps, ε to 0.04 — plus Double DQN, 3-step returns, a "
        "target network synced every 256 learning steps, a "
        "64-64 network, and "
        "per-seed freezing once 8 greedy side episodes each reach 475). The compiled rows time from "
        "the start of `train` (compile included; also shown apart) to the first evaluation in which every "
        "seed's mean reaches 475; "
        "'solved' counts seeds whose final evaluation (20 fresh episodes) is ≥ 475. Learner updates are "
        "gradient steps on a batch of 64, summed over seeds. The host row steps Gymnasium's CartPole "
        "(4 envs, SAME_STEP autoreset) through the host runner (`agentax.runners.host.train`: an Actor's "
        "Driver fills the replay, the same `dqn.learn` learns, 128 steps per compiled call); its "
        "wall-clock includes compilation and the periodic evaluations. The process rows run "
        "`python -m agentax.cli train dqn --env CartPole-v1` (and `train pqn`: PQN's default preset, "
        "16 envs × 32 steps, Q(λ), no replay, stopping when solved) in a subprocess: first with an empty "
        "cache (it traces and compiles), then with the cache the first run filled (stored programs and "
        "their compiled code: no tracing, no compiling; the median of 3 runs)."
    )
    if sb3 is None:
        notes += " Stable-Baselines3 is not installed in `.bench-venv` here, so there is no SB3 row."
    else:
        notes += (
            f" SB3 DQN (stable-baselines3 + torch in `.bench-venv`, RL-Zoo hyperparameters, 5e4 steps, "
            f"net 256-256) took {sb3['total_seconds']:.1f} s for the whole process and evaluated at "
            f"{sb3['mean_return']:.1f}; the last column is that time divided by each row's wall-clock."
        )
    return {
        "name": "dqn",
        "title": "DQN on CartPole-v1: time to solve, learner updates/s",
        "headers": headers,
        "rows": rows,
        "notes": notes,
    }
