"""Memory (issue 42): PPO with a recurrent core against feed-forward PPO on CartPoleNoVel-v1, beside
SB3-Contrib's RecurrentPPO, and the throughput of PureJaxRL's ``ppo_rnn.py`` settings.

CartPoleNoVel-v1 is CartPole-v1 with the velocities hidden (observation: cart position and pole
angle only, RL Zoo's CartPoleNoVel), so a policy must infer them from what it saw before. The first
three rows train with the ``memory`` preset's settings (8 envs × 32 steps, lr 2e-3, 10 epochs × 2
minibatches, γ 0.98, λ 0.8, clip annealed, no entropy bonus), the same env steps, 8 seeds vmapped
into one program on the compiled runner: with an LSTM core of 64 units, with a GRU of 64, and
feed-forward (``core="none"``, its MLP of 64 units). The figure is the final evaluation: 20 greedy
episodes per seed, the recurrent policy carrying its memory through each episode; the worst and best
seed's mean; compile and training seconds.

Beside SB3-Contrib: the RL Zoo's ``hyperparams/ppo_lstm.yml`` settings for CartPoleNoVel-v1 (8 envs,
n_steps 32, batch 256, 20 epochs, γ 0.98, λ 0.8, no entropy bonus, lr 1e-3 and clip 0.2 both decayed
linearly to 0, observations normalised (VecNormalize, rewards not), the policy an LSTM of 64 units
on the observation for the actor and another for the critic, each followed by a ReLU layer of 64),
seed 0, about 1e5 steps (391 iterations of 256). agentax runs them as the whole ``agentax train
ppo`` command (one seed, one LSTM of 64 units on the normalised observation that actor and critic
share, each head a ReLU layer of 64, a fresh compilation cache, as on a new machine), SB3-Contrib its
script in ``.bench-venv`` (torch on one thread), each timed as a whole process; each row's score is
its final greedy evaluation (agentax: its run's, SB3: 20 episodes). SB3 trains after the agentax processes,
each alone on the machine. SB3's full run takes over ten minutes here: by default it runs
SB3_STEPS and the table compares seconds per 1,000 steps; ``AGENTAX_MEMORY_SB3_FULL=1`` runs the
Zoo's steps (``AGENTAX_MEMORY_SB3=0`` skips SB3). ``AGENTAX_MEMORY_ROWS_ONLY=1`` trains the first three
rows only and keeps this part and the next as results/memory.json has them, each with its ``measured``
date.

PureJaxRL's ``ppo_rnn.py`` settings (4 envs × 128 steps, 4 epochs × 4 minibatches, GRU of 128 after a
128-unit layer, lr 2.5e-4 annealed, γ 0.99, λ 0.95, entropy 0.01; CartPole-v1 there, CartPoleNoVel-v1
here) on the compiled runner at 8 and 64 seeds vmapped: env steps per second per seed, measured over
PUREJAXRL_UPDATES updates (its own runs are 5e5 steps, 976 updates).
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SEEDS = 8
ENV = "CartPoleNoVel-v1"
ZOO_STEPS = 391 * 256  # the Zoo's 1e5 steps in whole iterations of 8 envs × 32 steps (SB3 runs as many)
FULL = os.environ.get("AGENTAX_MEMORY_SB3_FULL") == "1"
SB3_STEPS = ZOO_STEPS if FULL else 10_240
"""SB3's steps: the Zoo's with AGENTAX_MEMORY_SB3_FULL=1, else fewer (seconds per step compared)"""
RUN_SB3 = os.environ.get("AGENTAX_MEMORY_SB3", "1") != "0"
ROWS_ONLY = os.environ.get("AGENTAX_MEMORY_ROWS_ONLY") == "1"
"""train the first three rows only, keeping the SB3 and PureJaxRL parts of results/memory.json as
they are (each with the date it was measured)"""
STORED = Path(__file__).resolve().parent / "results" / "memory.json"
PUREJAXRL_UPDATES = 10
ZOO_ARGS = [
    "--num-envs", "8", "--num-steps", "32", "--num-minibatches", "1", "--update-epochs", "20",
    "--discount-factor", "0.98", "--gae-lambda", "0.8", "--ent-coef", "0", "--learning-rate", "1e-3",
    "--anneal-lr", "--clip-eps", "0.2", "--anneal-clip", "--core", "lstm", "--core-size", "64",
    "--hidden", "--activation", "relu", "--normalize-observations",
]  # fmt: skip
"""``agentax train ppo`` with the Zoo's CartPoleNoVel-v1 settings (1 minibatch: batch 256 of 8 × 32;
no layer before the core, as SB3's MlpLstmPolicy; heads of 64 units, ReLU; observations normalised)"""

SB3_SCRIPT = """
import json, sys, time
import numpy as np
import torch
torch.set_num_threads(1)  # two threads spin on two busy cores (bench_lunar)
import gymnasium as gym
import sb3_contrib
from sb3_contrib import RecurrentPPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize


class NoVelocity(gym.ObservationWrapper):  # RL Zoo's CartPoleNoVel-v1: position and angle only
    def __init__(self, env):
        super().__init__(env)
        high = env.observation_space.high[[0, 2]]
        self.observation_space = gym.spaces.Box(-high, high, dtype=np.float32)

    def observation(self, obs):
        return obs[[0, 2]]


def novel():
    return NoVelocity(gym.make("CartPole-v1"))


total, episodes = int(sys.argv[1]), int(sys.argv[2])
env = VecNormalize(make_vec_env(novel, n_envs=8, seed=0), norm_obs=True, norm_reward=False)
policy = dict(ortho_init=False, activation_fn=torch.nn.ReLU, lstm_hidden_size=64, enable_critic_lstm=True,
              net_arch=dict(pi=[64], vf=[64]))
model = RecurrentPPO("MlpLstmPolicy", env, n_steps=32, batch_size=256, gae_lambda=0.8, gamma=0.98,
                     n_epochs=20, ent_coef=0.0, learning_rate=lambda left: 1e-3 * left,
                     clip_range=lambda left: 0.2 * left, policy_kwargs=policy, seed=0, verbose=0,
                     device="cpu")
start = time.perf_counter()
model.learn(total_timesteps=total)
seconds = time.perf_counter() - start
eval_env, returns = novel(), []
for seed in range(1, episodes + 1):
    obs, _ = eval_env.reset(seed=seed)
    state, first, done, total_reward = None, np.ones(1, bool), False, 0.0
    while not done:
        seen = env.normalize_obs(obs)  # the training's statistics, as the Zoo's evaluation uses them
        action, state = model.predict(seen, state=state, episode_start=first, deterministic=True)
        obs, reward, terminated, truncated, _ = eval_env.step(int(action))
        first, total_reward, done = np.zeros(1, bool), total_reward + reward, terminated or truncated
    returns.append(total_reward)
print(json.dumps({"steps": int(model.num_timesteps), "learn_seconds": seconds,
                  "mean": float(np.mean(returns)), "sb3_contrib": sb3_contrib.__version__,
                  "torch": torch.__version__}))
"""


def seeds_trained(env_id: str, cfg, seeds: int, updates_per_chunk: int, eval_episodes: int):
    """PPO with ``cfg`` on ``env_id``, ``seeds`` vmapped on the compiled runner and evaluated at the
    end: the runner's result and each seed's mean greedy return ``[seeds]``."""
    from agentax.agents import ppo
    from agentax.api import compiled_program
    from agentax.envs import make_jax
    from agentax.runners.compiled import RunnerConfig, train_program

    env = make_jax(env_id)
    runner = RunnerConfig(
        num_seeds=seeds,
        updates_per_chunk=updates_per_chunk,
        eval_every_chunks=1000,
        eval_episodes=eval_episodes,
    )
    result = train_program(compiled_program(ppo, env, cfg), env, runner)
    return result, np.asarray(result.final_returns[0]).mean(axis=-1)


def train(cfg, name: str) -> list:
    """One row: 8 seeds of PPO with ``cfg`` on the compiled runner, evaluated at the end."""
    result, per_seed = seeds_trained(ENV, cfg, SEEDS, updates_per_chunk=10, eval_episodes=20)
    row = [name, int(result.env_steps), round(float(per_seed.mean()), 1), round(float(per_seed.min()), 1)]
    row += [round(float(per_seed.max()), 1), int((per_seed >= 475).sum()), round(result.compile_seconds, 1)]
    print(row + [round(result.train_seconds, 1)], flush=True)
    return row + [round(result.train_seconds, 1)]


def sb3(out: dict) -> None:
    """SB3-Contrib's RecurrentPPO with the Zoo's settings in ``.bench-venv``, timed as a process."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_atari import bench_venv_python

    python, why = bench_venv_python()
    if python is None:
        out["sb3"] = why
        return
    start = time.perf_counter()
    done = subprocess.run(
        [str(python), "-c", SB3_SCRIPT, str(SB3_STEPS), "20"], capture_output=True, text=True, timeout=7_200
    )
    if done.returncode != 0:
        out["sb3"] = f"SB3-Contrib failed: {done.stderr.strip()[-300:]}"
        return
    out["sb3"] = {**json.loads(done.stdout.strip().splitlines()[-1]), "seconds": time.perf_counter() - start}
    print(f"sb3: {out['sb3']}", flush=True)


def first_train(args: list[str], timeout: float = 3_600) -> tuple[float, dict, list[str]]:
    """The whole ``agentax train ARGS`` process compiling from an empty cache, as a new machine's
    first run: ``(seconds, its eval.json, its metrics.csv lines)``."""
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        command = [sys.executable, "-m", "agentax.cli", "train", *args, "--out", str(run), "--no-progress"]
        fresh = {**os.environ, "AGENTAX_JAX_CACHE": f"{tmp}/jax-cache"}
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True, text=True, timeout=timeout, env=fresh)
        seconds = time.perf_counter() - start
        evaluation = json.loads((run / "eval.json").read_text())
        return seconds, evaluation, (run / "metrics.csv").read_text().splitlines()


def agentax_zoo() -> dict:
    """The whole ``agentax train ppo`` process with the Zoo's settings, one seed: seconds and score."""
    args = ["ppo", "--env", ENV, *ZOO_ARGS, "--total-steps", str(ZOO_STEPS), "--seed", "0"]
    seconds, evaluation, _ = first_train([*args, "--stop-at-return", "none"])
    result = {"steps": ZOO_STEPS, "seconds": seconds, "mean": evaluation["mean_return"]}
    print(f"agentax zoo: {result}", flush=True)
    return result


def purejaxrl(seeds: int) -> float:
    """PureJaxRL ``ppo_rnn.py``'s settings on CartPoleNoVel, ``seeds`` vmapped: env steps/s per seed."""
    from agentax.agents import ppo
    from agentax.api import compiled_program
    from agentax.envs import make_jax
    from agentax.runners.compiled import RunnerConfig, train_program

    cfg = ppo.PPOConfig(
        total_steps=PUREJAXRL_UPDATES * 512,
        num_envs=4,
        num_steps=128,
        update_epochs=4,
        num_minibatches=4,
        learning_rate=2.5e-4,
        discount_factor=0.99,
        gae_lambda=0.95,
        ent_coef=0.01,
        hidden=(128,),
        activation="relu",
        core="gru",
        core_size=128,
    )
    env = make_jax(ENV)
    runner = RunnerConfig(
        num_seeds=seeds, updates_per_chunk=PUREJAXRL_UPDATES, eval_every_chunks=1000, eval_episodes=1
    )
    result = train_program(compiled_program(ppo, env, cfg), env, runner)
    return float(result.env_steps) / result.train_seconds


def rows_only(rows: list) -> dict:
    """The first three rows beside the stored SB3 and PureJaxRL parts (AGENTAX_MEMORY_ROWS_ONLY=1)."""
    stored = json.loads(STORED.read_text())
    kept = {}
    for part in ("beside_sb3", "purejaxrl_settings"):
        kept[part] = {**stored[part], "measured": stored[part].get("measured", stored["machine"]["date"])}
    result = {key: value for key, value in stored.items() if key not in ("machine", "wall_seconds")}
    result.update(kept, rows=rows, notes=__doc__.split("\n\n", 1)[1].strip())
    return result


def run() -> dict:
    from agentax.agents import presets

    recurrent = presets.preset("ppo", "memory").config
    rows = [
        train(recurrent, "PPO + LSTM 64"),
        train(dataclasses.replace(recurrent, core="gru"), "PPO + GRU 64"),
        train(dataclasses.replace(recurrent, core="none"), "PPO feed-forward"),
    ]
    if ROWS_ONLY:
        return rows_only(rows)
    zoo = agentax_zoo()
    throughput = {seeds: purejaxrl(seeds) for seeds in (8, 64)}
    sb3_result: dict = {}
    if RUN_SB3:
        sb3(sb3_result)  # after agentax's processes, alone on the machine as they were
    sb3_row = sb3_result.get("sb3", "not run (AGENTAX_MEMORY_SB3=0)")
    beside = [["agentax train ppo --core lstm (whole process)", zoo["steps"], round(zoo["seconds"], 1)]]
    beside[0] += [round(1000 * zoo["seconds"] / zoo["steps"], 2), round(zoo["mean"], 1)]
    if isinstance(sb3_row, dict):
        name = f"SB3-Contrib {sb3_row['sb3_contrib']} RecurrentPPO (whole process, torch {sb3_row['torch']})"
        per_k = 1000 * sb3_row["seconds"] / sb3_row["steps"]
        beside.append([name, sb3_row["steps"], round(sb3_row["seconds"], 1), round(per_k, 2)])
        beside[-1].append(round(sb3_row["mean"], 1))
        beside[0].append(round(zoo["seconds"] / zoo["steps"] / (sb3_row["seconds"] / sb3_row["steps"]), 3))
        beside[-1].append(1.0)
    return {
        "name": "memory",
        "title": f"Memory: PPO with a recurrent core on {ENV} ({SEEDS} seeds vmapped, compiled runner)",
        "headers": [
            "agent",
            "env steps per seed",
            "eval mean",
            "worst seed",
            "best seed",
            "seeds ≥ 475",
            "compile s",
            "train s",
        ],
        "rows": rows,
        "beside_sb3": {
            "headers": [
                "run",
                "env steps",
                "seconds",
                "s per 1,000 steps",
                "eval mean",
                "time per step ÷ SB3's",
            ],
            "rows": beside,
            "sb3": sb3_row,
        },
        "purejaxrl_settings": {
            "headers": ["seeds vmapped", "env steps/s per seed", "env steps/s, all seeds"],
            "rows": [[seeds, round(rate), round(rate * seeds)] for seeds, rate in throughput.items()],
        },
        "notes": __doc__.split("\n\n", 1)[1].strip(),
    }
