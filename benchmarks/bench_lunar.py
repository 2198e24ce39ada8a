"""LunarLander-v3 (issue 41): PPO and DQN, seed 0, on the host runner (Gymnasium steps the Box2D envs,
agentax's jitted ``act``/``learn``), each toward the solved mark of 200, its greedy policy evaluated on
100 Gymnasium episodes, beside SB3's time (and score) for the same RL-Zoo settings.

RL-Baselines3-Zoo, hyperparams/ppo.yml (LunarLander-v2, the same env as v3 to the policy): 16 envs,
n_steps 1024, batch 64 (256 minibatches), 4 epochs, GAE 0.98, γ 0.999, entropy 0.01, lr 3e-4 constant,
1e6 steps (the ``lunar`` PPO preset). hyperparams/dqn.yml: lr 6.3e-4, batch 128, buffer 50,000, learning
from the start, γ 0.99, target every 250 steps, train every 4 steps with as many learning steps, ε from 1
to 0.1 over 12 % of 1e5 steps, [256, 256]; SB3's DQN is not double and takes one-step targets. With seed
0 the Zoo's DQN does not solve it; the ``lunar`` DQN preset, the same made Double with 3-step returns and
the step size decayed linearly to 0 over 150k steps, is the row that does (SB3 is not run with it).

SB3 (``.bench-venv``, bench_atari's) trains in a subprocess with the Zoo's settings, torch on one thread
(two spin on two busy cores: 500 DQN steps took 103 s against 8.5 s on one), at the same time as
agentax trains. SB3's PPO at 1M steps takes longer than this bench can: by default SB3 runs fewer steps
(SB3_STEPS) and the table compares steps/s; ``AGENTAX_LUNAR_SB3_FULL=1`` runs the Zoo's steps. Long
(minutes each), so it runs apart: ``python benchmarks/run.py lunar``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from agentax.agents import dqn, ppo, presets
from agentax.agents.protocol import EnvSpec
from agentax.envs import make, make_host_env
from agentax.evaluate import evaluate
from agentax.runners import host

ENV = "LunarLander-v3"
SOLVED = 200.0
EVAL_EPISODES = 100
FULL = os.environ.get("AGENTAX_LUNAR_SB3_FULL") == "1"
SB3_STEPS = {"ppo": 1_000_000 if FULL else 32_768, "dqn": 100_000 if FULL else 10_000}
"""SB3's steps: RL-Zoo's with AGENTAX_LUNAR_SB3_FULL=1, else fewer (steps/s compared, not scores)"""

PPO_ZOO = presets.LUNAR_PPO
DQN_ZOO = dataclasses.replace(
    presets.LUNAR_DQN, total_steps=100_000, double=False, n_step=1, anneal_learning_rate=False
)
"""RL-Zoo's own DQN: the preset's settings, 100k steps, one-step, not Double, a constant step size"""


DQN_SOLVED = presets.LUNAR_DQN
"""the Zoo's DQN, Double with 3-step returns, the step size decayed linearly to 0, 150k steps"""
SOLVED_SETTINGS = "Zoo + Double, 3-step, lr → 0, 150k steps (preset lunar)"

SB3_SCRIPT = """
import json, sys, time
import torch
torch.set_num_threads(1)  # 2 (bench_atari's) spin on 2 busy cores: 12x slower here
import gymnasium as gym
import stable_baselines3
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.env_util import make_vec_env

algo, total, episodes = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
if algo == "ppo":  # hyperparams/ppo.yml's LunarLander: SB3's defaults elsewhere (lr 3e-4, clip 0.2)
    env = make_vec_env("LunarLander-v3", n_envs=16, seed=0)
    model = PPO("MlpPolicy", env, n_steps=1024, batch_size=64, n_epochs=4, gae_lambda=0.98, gamma=0.999,
                ent_coef=0.01, seed=0, verbose=0, device="cpu")
else:  # hyperparams/dqn.yml's LunarLander
    env = make_vec_env("LunarLander-v3", n_envs=1, seed=0)
    model = DQN("MlpPolicy", env, learning_rate=6.3e-4, batch_size=128, buffer_size=50_000,
                learning_starts=0, gamma=0.99, target_update_interval=250, train_freq=4, gradient_steps=-1,
                exploration_fraction=0.12, exploration_final_eps=0.1,
                policy_kwargs=dict(net_arch=[256, 256]), seed=0, verbose=0, device="cpu")
start = time.perf_counter()
model.learn(total_timesteps=total)
seconds = time.perf_counter() - start
eval_env, returns = gym.make("LunarLander-v3"), []
for seed in range(1, episodes + 1):
    obs, _ = eval_env.reset(seed=seed)
    done, total_reward = False, 0.0
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, _ = eval_env.step(action)
        total_reward, done = total_reward + reward, terminated or truncated
    returns.append(total_reward)
mean = sum(returns) / len(returns)
std = (sum((r - mean) ** 2 for r in returns) / len(returns)) ** 0.5
print(json.dumps({"steps": total, "seconds": seconds, "mean": mean, "std": std, "torch": torch.__version__,
                  "sb3": stable_baselines3.__version__}))
"""


def sb3(algo: str, out: dict) -> None:
    """SB3's ``algo`` with RL-Zoo's settings in ``.bench-venv`` (bench_atari's), into ``out[algo]``."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_atari import bench_venv_python

    python, why = bench_venv_python()
    if python is None:
        out[algo] = why
        return
    command = [str(python), "-c", SB3_SCRIPT, algo, str(SB3_STEPS[algo]), str(EVAL_EPISODES)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=3_600)
    if done.returncode != 0:
        out[algo] = f"SB3's {algo} failed: {done.stderr.strip()[-300:]}"
        return
    out[algo] = json.loads(done.stdout.strip().splitlines()[-1])
    print(f"sb3 {algo}: {out[algo]}")


def one(algo: str, settings: str, make_agent, cfg) -> tuple[list, str]:
    """agentax's ``algo`` trained on the host runner, seed 0: its table row (without SB3's) and curve."""
    env = make_host_env(ENV, 1)
    spec = EnvSpec.of(env)
    env.close()
    agent = make_agent(spec, cfg)
    start = time.perf_counter()
    runner = host.HostRunnerConfig(seed=0, log_every_steps=cfg.total_steps // 20, eval_episodes=10)
    result = host.train(agent, ENV, runner)
    seconds = time.perf_counter() - start
    stats = evaluate(make(ENV, num_envs=16), agent.greedy_policy(result.state), EVAL_EPISODES, seed=1)
    curve = " ".join(f"{row['mean_return']:.0f}" for row in result.rows)
    print(
        f"{algo} ({settings}): {stats.mean_return:.1f} ± {stats.std_return:.1f} after {seconds:.0f} s; "
        f"training returns {curve}"
    )
    row = [
        algo,
        settings,
        cfg.total_steps,
        round(seconds, 1),
        round(cfg.total_steps / seconds),
        round(stats.mean_return, 1),
        round(stats.std_return, 1),
        stats.mean_return >= SOLVED,
    ]
    return row, curve


def sb3_columns(row: list, result) -> list:
    """SB3's steps, time, steps/s, evaluation and agentax's steps/s over SB3's, or dashes and why not."""
    if not isinstance(result, dict):
        return ["—"] * 4 + [result or "—"]
    rate = result["steps"] / result["seconds"]
    return [
        result["steps"],
        round(result["seconds"], 1),
        round(rate),
        f"{result['mean']:.1f} ± {result['std']:.1f}",
        round(row[4] / rate, 2),
    ]


def run() -> dict:
    sb3_results: dict = {}

    def sb3_both() -> None:
        for algo in ("ppo", "dqn"):
            sb3(algo, sb3_results)

    # SB3 trains beside agentax (the time it takes): both under each other's load, said in the notes
    thread = threading.Thread(target=sb3_both)
    thread.start()
    runs = [
        ("RL Zoo", one("ppo", "RL Zoo", ppo.make_agent, PPO_ZOO)),
        ("RL Zoo", one("dqn", "RL Zoo", dqn.make_agent, DQN_ZOO)),
        (None, one("dqn", SOLVED_SETTINGS, dqn.make_agent, DQN_SOLVED)),
    ]
    thread.join()
    rows = []
    for zoo, (row, curve) in runs:
        sb3_result = sb3_results.get(row[0]) if zoo else "SB3's DQN: not run with these settings"
        rows.append(row + sb3_columns(row, sb3_result) + [curve])
    versions = next(
        (f"SB3 {r['sb3']} (torch {r['torch']})" for r in sb3_results.values() if isinstance(r, dict)), "SB3"
    )
    sb3_steps = (
        "RL-Zoo's steps"
        if FULL
        else (
            f"fewer steps than agentax ({SB3_STEPS['ppo']:,} PPO, {SB3_STEPS['dqn']:,} DQN) to fit the run: "
            "its steps/s is compared, its score is not comparable (AGENTAX_LUNAR_SB3_FULL=1 runs RL-Zoo's)"
        )
    )
    return {
        "name": "lunar",
        "title": "LunarLander-v3: PPO and DQN, agentax (host runner) and SB3 (seed 0)",
        "headers": [
            "algo",
            "settings",
            "env steps",
            "train s",
            "steps/s",
            "eval mean",
            "eval std",
            "solved (≥ 200)",
            "SB3 env steps",
            "SB3 train s",
            "SB3 steps/s",
            "SB3 eval",
            "agentax / SB3 steps/s",
            "training returns",
        ],
        "rows": rows,
        "notes": (
            f"Greedy policy over {EVAL_EPISODES} Gymnasium episodes after training (agentax: 16 envs "
            "seeded 1..16 playing episodes in turn; SB3: one env, episodes seeded 1..100); training "
            "returns are agentax's host-runner rows (every 1/20 of the run). Settings as in "
            "benchmarks/bench_lunar.py's docstring; the last DQN row is the `lunar` preset. "
            f"{versions} on 1 thread ran {sb3_steps}. SB3 trained in a subprocess at the same time "
            "as agentax, on the same 2 cores, which other jobs shared too: every time here is noisy "
            "and slowed by the others."
        ),
    }
