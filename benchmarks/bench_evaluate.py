"""Evaluating a policy: 500 CartPole episodes in agentax (one compiled call) against Gymnasium loops.

All in this process, same policy, same number of episodes: agentax's ``evaluate`` on its JAX
CartPole (compilation timed apart), agentax's host evaluation of Gymnasium's CartPole
(``GymnasiumEnv``, 16 sub-envs), and a plain Python loop over ``gymnasium.make("CartPole-v1")``.
A second table compares single steps through ``gymnasium.make``: agentax's JAX CartPole behind
the Gymnasium API (``agentax/CartPole-v1``) against Gymnasium's own.
"""

from __future__ import annotations

import time

import gymnasium
import numpy as np

import agentax  # noqa: F401  (registers agentax/CartPole-v1)
from agentax.envs import GymnasiumEnv, make
from agentax.evaluate import evaluate
from agentax.policies import basic_policy, random_policy

EPISODES = 500
REPEATS = 7


def _median_seconds(fn, repeats: int = REPEATS) -> float:
    times = []
    for seed in range(1, repeats + 1):
        start = time.perf_counter()
        fn(seed)
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def _gymnasium_loop(seed: int, policy) -> tuple[float, int]:
    """``EPISODES`` episodes of Gymnasium's CartPole-v1, one after another; returns (seconds, steps)."""
    env, rng, steps = gymnasium.make("CartPole-v1"), np.random.default_rng(seed), 0
    start = time.perf_counter()
    for episode in range(EPISODES):
        obs, _ = env.reset(seed=seed * EPISODES + episode)
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy(obs, rng))
            done, steps = terminated or truncated, steps + 1
    return time.perf_counter() - start, steps


def _steps_per_second(env_id: str, num_steps: int = 20_000) -> float:
    env = gymnasium.make(env_id)
    env.reset(seed=0)
    env.step(0)  # compiles agentax's step
    start = time.perf_counter()
    for t in range(num_steps):
        _, _, terminated, truncated, _ = env.step(t % 2)
        if terminated or truncated:
            env.reset()
    return num_steps / (time.perf_counter() - start)


def run() -> dict:
    rows = []
    numpy_policies = {
        "basic": lambda obs, rng: int(obs[2] >= 0),
        "random": lambda obs, rng: int(rng.integers(2)),
    }
    for name in ("basic", "random"):
        env = make("CartPole-v1")
        policy = basic_policy if name == "basic" else random_policy(env.action_space())
        start = time.perf_counter()
        stats = evaluate(env, policy, EPISODES, seed=0)
        first_call = time.perf_counter() - start
        compiled = _median_seconds(lambda seed: evaluate(env, policy, EPISODES, seed=seed))  # noqa: B023
        steps = stats.mean_length * EPISODES
        host_env = GymnasiumEnv("CartPole-v1", num_envs=16)
        host = _median_seconds(lambda seed: evaluate(host_env, policy, EPISODES, seed=seed), repeats=3)  # noqa: B023
        loop, loop_steps = _gymnasium_loop(1, numpy_policies[name])
        rows.append(
            [
                name,
                round(stats.mean_return, 1),
                round(first_call, 2),
                round(compiled * 1000, 1),
                f"{steps / compiled:.3g}",
                round(host * 1000, 0),
                round(loop * 1000 * steps / loop_steps, 0),
                round(loop * steps / loop_steps / compiled, 1),
            ]
        )
    ours, theirs = _steps_per_second("agentax/CartPole-v1"), _steps_per_second("CartPole-v1")
    rows.append(
        ["gymnasium.make steps/s", "", "", "", f"{ours:.3g}", "", f"{theirs:.3g}", round(ours / theirs, 2)]
    )
    return {
        "name": "evaluate",
        "title": f"Evaluating a policy over {EPISODES} CartPole-v1 episodes",
        "headers": [
            "policy",
            "mean return",
            "agentax first call, s (compile + run)",
            "agentax compiled, ms",
            "agentax env steps/s",
            "agentax host eval of Gymnasium (16 sub-envs), ms",
            "Gymnasium Python loop, ms (scaled to the same steps)",
            "ratio: loop / agentax compiled",
        ],
        "rows": rows,
        "notes": (
            f"`agentax.evaluate(env, policy, {EPISODES})` on agentax's JAX CartPole plays all episodes "
            "side by side in one jitted `while_loop` (compilation is the first call's; the median of "
            f"{REPEATS} later calls with new seeds is reported). The reference is a plain Python loop "
            "over `gymnasium.make('CartPole-v1')` with the same policy written in NumPy, scaled to the "
            "same number of env steps; agentax's host evaluation of Gymnasium's CartPole "
            "(`GymnasiumEnv`, a SAME_STEP SyncVectorEnv of 16, JAX policy) is shown beside it. Last row: "
            "single steps through the Gymnasium API, `gymnasium.make('agentax/CartPole-v1')` (one jitted "
            "step, NumPy out) against Gymnasium's own CartPole; the ratio is agentax's steps/s over "
            "Gymnasium's."
        ),
    }
