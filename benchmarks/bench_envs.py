"""CartPole env steps per second: agentax's JAX CartPole against Gymnasium's, all in this process.

agentax: a jitted ``lax.scan`` of ``vmap(env.step)`` (auto-reset included) over 1 to 8,192 envs,
random actions drawn inside the scan, compile time measured apart. Gymnasium: ``CartPole-v1`` in a
plain Python loop, as a ``SyncVectorEnv`` of 64, and as its NumPy-vectorized ``CartPoleVectorEnv``
(``make_vec(..., vectorization_mode="vector_entry_point")``) at the same batch sizes. Also: the time
``agentax.evaluate`` takes for 500 episodes of the basic policy once compiled.

Run: ``python benchmarks/run.py envs``.
"""

from __future__ import annotations

import math
import os
import time

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from agentax.envs.cartpole import cartpole_v1
from agentax.evaluate import evaluate
from agentax.policies import basic_policy

BATCH_SIZES = (1, 64, 1024, 8192)
SYNC_VECTOR_ENVS = 64
REPEATS = 3  # best of
MIN_SECONDS = 1.0  # each timed measurement lasts at least this long
EVAL_EPISODES = 500


def best_rate(run_once, steps_per_call: int) -> float:
    """Steps/s of ``run_once`` (``steps_per_call`` steps): best of ``REPEATS`` runs of ≥ ``MIN_SECONDS``."""
    start = time.perf_counter()
    run_once()
    calls = max(1, math.ceil(MIN_SECONDS / max(time.perf_counter() - start, 1e-9)))
    best = math.inf
    for _ in range(REPEATS):
        start = time.perf_counter()
        for _ in range(calls):
            run_once()
        best = min(best, time.perf_counter() - start)
    return calls * steps_per_call / best


def agentax_rollout(num_envs: int, num_steps: int):
    """A jitted ``key -> checksum`` stepping ``num_envs`` CartPole-v1 envs ``num_steps`` times."""
    env = cartpole_v1()
    params = env.default_params()
    batch_reset = jax.vmap(env.reset, in_axes=(0, None))
    batch_step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def rollout(key):
        reset_key, key = jax.random.split(key)
        _, state = batch_reset(jax.random.split(reset_key, num_envs), params)

        def body(carry, _):
            state, key = carry
            key, action_key, step_key = jax.random.split(key, 3)
            actions = jax.random.bernoulli(action_key, 0.5, (num_envs,)).astype(jnp.int32)
            ts, state = batch_step(jax.random.split(step_key, num_envs), state, actions, params)
            return (state, key), ts.done.sum() + ts.obs.sum()  # outputs keep the work from being elided

        (state, _), checksums = jax.lax.scan(body, (state, key), None, num_steps)
        return checksums.sum() + state.x.sum()

    return jax.jit(rollout)


def measure_agentax(num_envs: int) -> tuple[float, float]:
    """(steps/s, compile seconds) of ``agentax_rollout`` over ``num_envs`` envs."""
    num_steps = max(256, 250_000 // num_envs)  # one call: 0.1-1 s; best_rate repeats it
    key = jax.random.key(0)
    start = time.perf_counter()
    compiled = agentax_rollout(num_envs, num_steps).lower(key).compile()
    compile_seconds = time.perf_counter() - start
    rate = best_rate(lambda: compiled(key).block_until_ready(), num_envs * num_steps)
    return rate, compile_seconds


def measure_gymnasium_loop(num_steps: int = 50_000) -> float:
    """One ``gym.make("CartPole-v1")`` stepped in Python, reset when an episode ends."""
    env = gym.make("CartPole-v1")
    actions = np.random.default_rng(0).integers(0, 2, num_steps).tolist()

    def run_once():
        env.reset(seed=0)
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()

    return best_rate(run_once, num_steps)


def measure_gymnasium_vector(envs: gym.vector.VectorEnv, num_steps: int) -> float:
    """A Gymnasium vector env (it auto-resets) stepped ``num_steps`` times with random actions."""
    actions = np.random.default_rng(0).integers(0, 2, (num_steps, envs.num_envs))
    envs.reset(seed=0)

    def run_once():
        for batch in actions:
            envs.step(batch)

    rate = best_rate(run_once, num_steps * envs.num_envs)
    envs.close()
    return rate


def measure_evaluate() -> tuple[float, float, int]:
    """(seconds, compile seconds, env steps) of 500 episodes of ``basic_policy`` via ``agentax.evaluate``."""
    env = cartpole_v1()
    start = time.perf_counter()
    stats = evaluate(env, basic_policy, num_episodes=EVAL_EPISODES)
    first_call = time.perf_counter() - start
    best = math.inf
    for _ in range(REPEATS):
        start = time.perf_counter()
        evaluate(env, basic_policy, num_episodes=EVAL_EPISODES)
        best = min(best, time.perf_counter() - start)
    return best, first_call - best, round(stats.mean_length * stats.episodes)


def run() -> dict:
    loop = measure_gymnasium_loop()
    sync = measure_gymnasium_vector(
        gym.vector.SyncVectorEnv([lambda: gym.make("CartPole-v1")] * SYNC_VECTOR_ENVS), num_steps=200
    )
    numpy_vec, agentax, compile_seconds = {}, {}, {}
    for num_envs in BATCH_SIZES:  # interleaved, so a change of machine load hits both sides alike
        envs = gym.make_vec("CartPole-v1", num_envs=num_envs, vectorization_mode="vector_entry_point")
        numpy_vec[num_envs] = measure_gymnasium_vector(
            envs, num_steps=max(100, min(5_000, 200_000 // num_envs))
        )
        agentax[num_envs], compile_seconds[num_envs] = measure_agentax(num_envs)
    eval_seconds, eval_compile, eval_steps = measure_evaluate()

    rows = [
        ["Gymnasium, Python loop", 1, loop, None, None, 1.0],
        ["Gymnasium SyncVectorEnv", SYNC_VECTOR_ENVS, sync, None, None, sync / loop],
    ]
    rows += [
        ["Gymnasium NumPy-vectorized", n, numpy_vec[n], None, 1.0, numpy_vec[n] / loop] for n in BATCH_SIZES
    ]
    rows += [
        [
            "agentax (jit + vmap + scan)",
            n,
            agentax[n],
            compile_seconds[n],
            agentax[n] / numpy_vec[n],
            agentax[n] / loop,
        ]
        for n in BATCH_SIZES
    ]
    rows.append(
        [
            f"agentax.evaluate, {EVAL_EPISODES} episodes",
            EVAL_EPISODES,
            eval_steps / eval_seconds,
            eval_compile,
            None,
            eval_steps / eval_seconds / loop,
        ]
    )
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    cpus = "one CPU" if usable == 1 else f"{usable} CPUs"
    notes = (
        "Env steps per second of CartPole-v1 with random actions (auto-reset on), best of "
        f"{REPEATS} runs of ≥ {MIN_SECONDS:g} s each, all measured in one process on {cpus} "
        "(`import agentax` pins a process to one CPU, the cure for the XLA CPU hang; Gymnasium is "
        "single-threaded anyway; two cores with `AGENTAX_PIN_CPU=0`, or "
        "`XLA_FLAGS=--xla_cpu_multi_thread_eigen=false`, showed no consistent gain when tried). "
        "agentax: one jitted `lax.scan` of `vmap(env.step)`; the random actions are drawn inside the scan "
        "and each step splits a key per env, both counted; compile time (s) is measured apart. "
        "Gymnasium gets its random actions drawn in advance (not counted). "
        "`÷ NumPy-vectorized` is agentax ÷ Gymnasium's `CartPoleVectorEnv` "
        '(`gymnasium.make_vec("CartPole-v1", num_envs=N, vectorization_mode="vector_entry_point")`) '
        "at the same N; `÷ Python loop` is ÷ one Gymnasium env stepped in a Python loop. "
        f"`agentax.evaluate`: {EVAL_EPISODES} episodes of the lecture's basic policy ({eval_steps:,} steps) "
        f"took {eval_seconds:.3f} s once compiled (compiling: {eval_compile:.1f} s)."
    )
    return {
        "name": "envs",
        "title": "CartPole env steps per second: agentax vs Gymnasium",
        "headers": [
            "implementation",
            "envs",
            "steps/s",
            "compile (s)",
            "÷ NumPy-vectorized",
            "÷ Python loop",
        ],
        "rows": rows,
        "notes": notes,
    }
