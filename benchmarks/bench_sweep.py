"""Hyperparameter sweeps in one compiled program: 8 learning rates × 8 seeds against one agent.

The issue's target: 64 agents (8 learning rates × 8 seeds of PPO on CartPole-v1) in at most 8× the
time of one agent's run of the same env steps; the same for DQN. Both sides are
``compiled.train``'s training loop (``TrainResult.train_seconds``: chunks, rows, in-program
evaluations; compile apart), measured one after the other in this process, the fastest of 2 runs.
"""

from __future__ import annotations

import numpy as np

LEARNING_RATES = {"ppo": np.geomspace(3e-4, 1e-2, 8), "dqn": np.geomspace(1e-4, 3e-3, 8)}
STEPS = {"ppo": ("default", 100_352), "dqn": ("default", 20_480)}
SEEDS = 8
REPEATS = 2


def timed(algo: str) -> dict:
    from agentax.agents import presets
    from agentax.api import algorithm, compiled_program
    from agentax.envs import make_jax
    from agentax.runners import compiled
    from agentax.runners.sweep import sweep_program

    env = make_jax("CartPole-v1")
    name, steps = STEPS[algo]
    chosen = presets.preset(algo, name, total_steps=steps)
    cfg = chosen.config
    module = algorithm(algo)

    def make(config):
        return compiled_program(module, env, config)

    rates = LEARNING_RATES[algo]
    table = {"learning_rate": np.repeat(rates, SEEDS).astype(np.float32)}
    runner = dict(updates_per_chunk=chosen.updates_per_chunk, eval_episodes=chosen.eval_episodes)
    one = compiled.RunnerConfig(num_seeds=1, **runner)
    many = compiled.RunnerConfig(num_seeds=SEEDS, num_settings=len(rates), **runner)
    alone, swept = [], []
    for _ in range(REPEATS):
        result = compiled.train(make(cfg), env, one)
        alone.append(result.train_seconds)
        result = compiled.train(sweep_program(make, cfg, table), env, many)
        swept.append(result.train_seconds)
    per_rate = np.asarray(result.eval["per_seed_mean"]).reshape(len(rates), SEEDS).mean(axis=1)
    return {
        "algo": algo,
        "preset": name,
        "steps": steps,
        "alone": min(alone),
        "swept": min(swept),
        "best_rate": float(rates[int(np.argmax(per_rate))]),
        "per_rate": per_rate.tolist(),
    }


def run() -> dict:
    from agentax import _xla

    _xla.enable_compilation_cache()
    rows, notes = [], []
    for algo in ("ppo", "dqn"):
        f = timed(algo)
        ratio = f["swept"] / f["alone"]
        rows.append(
            [
                f"{algo.upper()} {f['preset']}, {f['steps']:,} env steps per agent",
                f"{f['alone']:.2f}",
                f"{f['swept']:.2f}",
                f"{ratio:.1f}×",
                "met" if ratio <= 8 else "missed",
            ]
        )
        notes.append(
            f"{algo.upper()}: final evaluation by learning rate (mean over {SEEDS} seeds): "
            + ", ".join(f"{r:.1e}: {s:.0f}" for r, s in zip(LEARNING_RATES[algo], f["per_rate"], strict=True))
        )
    return {
        "name": "sweep",
        "title": "Sweeps: 8 learning rates × 8 seeds in one program against one agent",
        "headers": ["workload", "1 agent (s)", "64 agents, one program (s)", "ratio", "target ≤ 8×"],
        "rows": rows,
        "notes": __doc__.split("\n\n", 1)[1].strip() + "\n\n" + "; ".join(notes) + ".",
    }


if __name__ == "__main__":
    print(run())
