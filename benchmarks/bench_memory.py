"""Memory (issue 42): PPO with an LSTM core against feed-forward PPO on CartPoleNoVel-v1.

CartPoleNoVel-v1 is CartPole-v1 with the velocities hidden (observation: cart position and pole
angle only, RL Zoo's CartPoleNoVel), so a policy must infer them from what it saw before. Both agents
train with the ``memory`` preset's settings (8 envs × 32 steps, lr 3e-3, 10 epochs × 2 minibatches,
γ 0.98, λ 0.8, clip annealed, no entropy bonus), the same env steps, 8 seeds vmapped into one
program on the compiled runner; the feed-forward one without the core (``core="none"``, its MLP
of 64 units). The figure is the final evaluation: 20 greedy episodes per seed, the recurrent policy
carrying its memory through each episode. Rows: mean return over the seeds, the worst and best seed's
mean, compile and training seconds.
"""

from __future__ import annotations

import dataclasses

import numpy as np

SEEDS = 8
ENV = "CartPoleNoVel-v1"


def train(cfg) -> list:
    """One row: 8 seeds of PPO with ``cfg`` on the compiled runner, evaluated at the end."""
    from agentax.agents import ppo
    from agentax.api import compiled_program
    from agentax.envs import make_jax
    from agentax.runners.compiled import RunnerConfig, train_program

    env = make_jax(ENV)
    runner = RunnerConfig(num_seeds=SEEDS, updates_per_chunk=10, eval_every_chunks=1000, eval_episodes=20)
    result = train_program(compiled_program(ppo, env, cfg), env, runner)
    per_seed = np.asarray(result.final_returns[0]).mean(axis=-1)  # (seeds,)
    name = f"PPO + {cfg.core.upper()} {cfg.core_size}" if cfg.core != "none" else "PPO feed-forward"
    return [
        name,
        int(result.env_steps),
        round(float(per_seed.mean()), 1),
        round(float(per_seed.min()), 1),
        round(float(per_seed.max()), 1),
        round(result.compile_seconds, 1),
        round(result.train_seconds, 1),
    ]


def run() -> dict:
    from agentax.agents import presets

    recurrent = presets.preset("ppo", "memory").config
    rows = [train(recurrent), train(dataclasses.replace(recurrent, core="none"))]
    return {
        "name": "memory",
        "title": f"Memory: PPO with an LSTM core on {ENV} ({SEEDS} seeds vmapped, compiled runner)",
        "headers": [
            "agent",
            "env steps per seed",
            "eval mean",
            "worst seed",
            "best seed",
            "compile s",
            "train s",
        ],
        "rows": rows,
        "notes": __doc__.split("\n\n", 1)[1].strip(),
    }
