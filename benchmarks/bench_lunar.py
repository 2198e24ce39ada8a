"""LunarLander-v3 (issue 41): PPO and DQN with RL-Zoo's LunarLander settings, seed 0, on the host runner
(Gymnasium steps the Box2D envs, agentax's jitted ``act``/``learn``), each toward the solved mark of
200, its greedy policy evaluated on 100 Gymnasium episodes.

RL-Baselines3-Zoo, hyperparams/ppo.yml (LunarLander-v2, the same env as v3 to the policy): 16 envs,
n_steps 1024, batch 64 (256 minibatches), 4 epochs, GAE 0.98, γ 0.999, entropy 0.01, lr 3e-4 constant,
1e6 steps. hyperparams/dqn.yml: lr 6.3e-4, batch 128, buffer 50,000, learning from the start, γ 0.99,
target every 250 steps, train every 4 steps with as many learning steps, ε from 1 to 0.1 over 12 % of
1e5 steps, [256, 256]; SB3's DQN is not double and takes one-step targets. Long (minutes each), so
it runs apart: ``python benchmarks/run.py lunar``. SB3's time for the same is not measured here yet.
"""

from __future__ import annotations

import dataclasses
import time

from agentax.agents import dqn, ppo
from agentax.agents.protocol import EnvSpec
from agentax.envs import make, make_host_env
from agentax.evaluate import evaluate
from agentax.runners import host

ENV = "LunarLander-v3"
SOLVED = 200.0
EVAL_EPISODES = 100

PPO_ZOO = dataclasses.replace(
    ppo.PPOConfig(),
    total_steps=1_000_000,
    num_envs=16,
    num_steps=1024,
    num_minibatches=256,
    update_epochs=4,
    gae_lambda=0.98,
    discount_factor=0.999,
    ent_coef=0.01,
    learning_rate=3e-4,
    anneal_lr=False,
)
DQN_ZOO = dqn.DQNConfig(
    total_steps=100_000,
    num_envs=1,
    hidden=(256, 256),
    double=False,
    n_step=1,
    learning_rate=6.3e-4,
    batch_size=128,
    buffer_size=50_000,
    learning_starts=128,
    target_update_period=250,
    train_frequency=4,
    gradient_steps=4,
    epsilon_start=1.0,
    epsilon_end=0.1,
    exploration_duration=12_000,
    discount_factor=0.99,
)


def one(algo: str, make_agent, cfg) -> list:
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
        f"{algo}: {stats.mean_return:.1f} ± {stats.std_return:.1f} after {seconds:.0f} s; "
        f"training returns {curve}"
    )
    return [
        algo,
        cfg.total_steps,
        round(seconds, 1),
        round(stats.mean_return, 1),
        round(stats.std_return, 1),
        stats.mean_return >= SOLVED,
        curve,
    ]


def run() -> dict:
    rows = [one("ppo", ppo.make_agent, PPO_ZOO), one("dqn", dqn.make_agent, DQN_ZOO)]
    return {
        "name": "lunar",
        "title": "LunarLander-v3: PPO and DQN with RL-Zoo settings (seed 0, host runner)",
        "headers": [
            "algo",
            "env steps",
            "train s",
            "eval mean",
            "eval std",
            "solved (≥ 200)",
            "training returns",
        ],
        "rows": rows,
        "notes": (
            f"Greedy policy over {EVAL_EPISODES} Gymnasium episodes (seeds 1..100) after training; "
            "training returns are the host runner's rows (every 1/20 of the run). RL-Zoo settings as in "
            "benchmarks/bench_lunar.py's docstring; SB3's time for the same is not measured here yet."
        ),
    }
