"""Memory over a chain: PPO with an LSTM core against feed-forward PPO on bsuite's MemoryChain.

``gymnax/MemoryChain-bsuite`` (gymnax's port of bsuite's ``memory_chain``, its default memory length
of 5): the first observation shows a context bit, the following ones only the time, and the last
step's action earns +1 if it names the bit and -1 if not, so a policy without memory is right half
the time (a mean return of 0, chance) and one that remembers the bit earns 1. Both agents train with
PPO's ``memory`` preset's settings at a learning rate of 3e-3 (8 envs × 32 steps, 10 epochs × 2
minibatches, γ 0.98, λ 0.8; the feed-forward one without the core), the same env steps, 8 seeds
vmapped into one program on the compiled runner. The figure is the final evaluation: 100 greedy
episodes per seed (the context bit drawn at random in each), the recurrent policy carrying its
memory through each episode. Rows: mean return over the seeds, the worst and best seed's mean,
compile and training seconds.
"""

from __future__ import annotations

import dataclasses

SEEDS = 8
ENV = "gymnax/MemoryChain-bsuite"
STEPS = 40_960  # per seed: 160 updates of 8 envs × 32 steps
LEARNING_RATE = 3e-3  # the short chain's: at the preset's 2e-3 (tuned on CartPoleNoVel's 204,800 steps) 0.74


def train(cfg, name: str) -> list:
    """One row: 8 seeds of PPO with ``cfg`` on the compiled runner, evaluated at the end."""
    from bench_memory import seeds_trained  # beside this file: run.py puts benchmarks/ on the path

    result, per_seed = seeds_trained(ENV, cfg, SEEDS, updates_per_chunk=20, eval_episodes=100)
    row = [name, int(result.env_steps), round(float(per_seed.mean()), 3), round(float(per_seed.min()), 3)]
    row += [round(float(per_seed.max()), 3), round(result.compile_seconds, 1), round(result.train_seconds, 1)]
    print(row, flush=True)
    return row


def run() -> dict:
    from agentax.agents import presets

    memory = presets.preset("ppo", "memory").config
    recurrent = dataclasses.replace(memory, total_steps=STEPS, learning_rate=LEARNING_RATE)
    rows = [
        train(recurrent, "PPO + LSTM 64"),
        train(dataclasses.replace(recurrent, core="none"), "PPO feed-forward"),
    ]
    return {
        "name": "memory_chain",
        "title": f"Memory: PPO with an LSTM core on {ENV} ({SEEDS} seeds vmapped, compiled runner)",
        "headers": ["agent", "env steps per seed", "eval mean", "worst seed", "best seed"]
        + ["compile s", "train s"],
        "rows": rows,
        "notes": __doc__.split("\n\n", 1)[1].strip(),
    }


if __name__ == "__main__":
    print(run())
