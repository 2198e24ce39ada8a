"""Mixed precision: one learning step of three agents in float32 against bfloat16 products.

Rows, all measured in this run, each pair interleaved (one batch of f32 calls, then one of bf16,
round after round, so another process's load falls on both alike; the fastest round of each kept):

- SAC's learning step at the RL Zoo's HalfCheetah sizes (256-256 actor and twin critics, batch 256,
  17 observations, 6 actions): critics, actor and α, one ``learn`` call;
- PPO's update on CartPole-v1 (its ``cartpole-fast`` preset: the whole rollout's epochs of
  minibatch SGD, one ``learn`` call);
- PQN's update on Breakout-MinAtar (its ``minatar`` preset: MinAtar's conv torso, 128 envs × 32
  steps, its epochs of minibatches, one ``learn`` call);

and a learning check: SAC on Pendulum-v1 (64-64 networks, 5,000 env steps), a few seeds vmapped
on the compiled runner in each precision, the seeds' final greedy evaluations side by side.

``python benchmarks/bench_precision.py`` prints the JSON alone (``benchmarks/run.py precision``
stores it as the other sections).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

PRECISIONS = ("f32", "bf16", "bf16-onednn")
ROUNDS = 6
LEARNING_SEEDS = 3
LEARNING_STEPS = 5_000


def precisions() -> tuple[str, ...]:
    """The precisions this machine runs: ``bf16-onednn`` only where the oneDNN kernel is built."""
    from agentax import kernels

    return PRECISIONS if kernels.available() else PRECISIONS[:2]


def timed_each(make: Callable[[str], tuple[Callable, Any]], rounds: int = ROUNDS, calls: int = 5) -> dict:
    """ms per call of ``step(state) -> state`` (``make(precision) -> (step, state)``) in each
    precision: compiled first, then ``rounds`` interleaved rounds of ``calls`` calls, the fastest round
    of each kept (and the median, to show the noise)."""
    steps = {p: make(p) for p in precisions()}
    for step, state in steps.values():
        jax.block_until_ready(step(state))
    times = {p: [] for p in PRECISIONS}
    for _ in range(rounds):
        for p, (step, state) in steps.items():
            start = time.perf_counter()
            for _ in range(calls):
                state = step(state)
            jax.block_until_ready(state)
            times[p].append((time.perf_counter() - start) / calls * 1e3)
    return {p: {"best": min(t), "median": float(np.median(t))} for p, t in times.items()}


def sac_step(precision: str) -> tuple[Callable, Any]:
    """SAC's ``learn`` at HalfCheetah's sizes on a random replayed batch of 256."""
    from agentax.agents import sac
    from agentax.agents.protocol import EnvSpec
    from agentax.envs.core import Box
    from agentax.replay import ReplaySample, Transition

    spec = EnvSpec((17,), Box(np.full(6, -1.0, np.float32), np.full(6, 1.0, np.float32), (6,)))
    agent = sac.make_agent(spec, sac.SACConfig(hidden=(256, 256), batch_size=256), precision=precision)
    k = jax.random.split(jax.random.key(0), 5)
    transition = Transition(
        obs=jax.random.normal(k[0], (256, 17)),
        action=jax.random.uniform(k[1], (256, 6), minval=-1, maxval=1),
        reward=jax.random.normal(k[2], (256,)),
        next_obs=jax.random.normal(k[3], (256, 17)),
        terminated=jnp.zeros(256),
        truncated=jnp.zeros(256, bool),
        num_steps=jnp.ones(256, jnp.int32),
    )
    sample = ReplaySample(transition, jnp.arange(256), jnp.ones(256))
    learn = jax.jit(lambda state: agent.learn(state, sample, k[4])[0])
    return learn, agent.init(jax.random.key(1))


def on_policy_step(algo: str, env_id: str, preset: str, precision: str) -> tuple[Callable, Any]:
    """``algo``'s ``learn`` (its ``preset`` for ``env_id``) on one rollout collected by its own ``act``
    from random observations of the env's shape."""
    from agentax.agents import algorithm, presets
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_jax
    from agentax.replay import Transition

    spec = EnvSpec.of(make_jax(env_id))
    cfg = presets.preset(algo, preset).config
    agent = algorithm(algo).make_agent(spec, cfg, precision=precision)
    state = agent.init(jax.random.key(0))
    steps, envs = cfg.num_steps, cfg.num_envs
    k = jax.random.split(jax.random.key(1), 4)
    obs = jax.random.bernoulli(k[0], 0.1, (steps, envs, *spec.obs_shape)).astype(jnp.float32)
    action, info = jax.vmap(lambda o, key: agent.act(state, o, key, jnp.int32(0)))(
        obs, jax.random.split(k[1], steps)
    )
    rollout = Transition(
        obs=obs,
        action=action,
        reward=jax.random.normal(k[2], (steps, envs)),
        next_obs=jnp.roll(obs, -1, axis=0),
        terminated=jax.random.bernoulli(k[3], 0.02, (steps, envs)),
        truncated=jnp.zeros((steps, envs), bool),
        num_steps=jnp.ones((steps, envs), jnp.int32),
        info=info,
    )
    learn = jax.jit(lambda state: agent.learn(state, rollout, k[3])[0])
    return learn, state


def learning_row() -> list:
    """SAC on Pendulum-v1, :data:`LEARNING_SEEDS` seeds vmapped, in each precision: the seeds' final
    greedy returns (10 episodes each) and their means, and the seconds of both trainings."""
    from agentax.agents import algorithm, presets
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_jax
    from agentax.runners.compiled import RunnerConfig, program_of, train_program
    from agentax.runners.launch import agent_maker

    overrides = {"hidden": (64, 64), "total_steps": LEARNING_STEPS, "learning_starts": 500}
    cfg = presets.preset("sac", "pendulum", **overrides).config
    runner = RunnerConfig(seed=0, num_seeds=LEARNING_SEEDS, updates_per_chunk=1_000, eval_episodes=10)
    env = make_jax("Pendulum-v1")
    finals, start = {}, time.perf_counter()
    for precision in precisions():
        agent = agent_maker(algorithm("sac"), EnvSpec.of(env), cfg, precision=precision)()
        result = train_program(program_of(agent, env, runner), env, runner)
        finals[precision] = [round(float(r), 1) for r in result.eval["per_seed_mean"]]
    means = {p: float(np.mean(f)) for p, f in finals.items()}
    shown = [f"{means[p]:.1f} (per seed {finals[p]})" for p in precisions()]
    name = f"SAC Pendulum-v1 final greedy return, {LEARNING_SEEDS} seeds, {LEARNING_STEPS:,} steps"
    return [name, *shown, *[None] * (len(precisions()) - 1), round(time.perf_counter() - start, 1), None]


def run() -> dict:
    from agentax import kernel_choice

    workloads = {
        "SAC learning step, HalfCheetah sizes (256-256, batch 256, obs 17, act 6)": sac_step,
        "PPO update, CartPole-v1 (cartpole-fast)": lambda p: on_policy_step(
            "ppo", "CartPole-v1", "cartpole-fast", p
        ),
        "PQN update, Breakout-MinAtar (minatar: conv torso, 128 envs × 32 steps)": lambda p: on_policy_step(
            "pqn", "gymnax/Breakout-MinAtar", "minatar", p
        ),
    }
    names, lower = precisions(), precisions()[1:]
    headers = ["workload", *[f"{p} ms (best; median)" for p in names], *[f"f32 ÷ {p}" for p in lower]]
    headers += ["s", "auto"]
    rows = []
    for name, make in workloads.items():
        start = time.perf_counter()
        ms = timed_each(make)
        shown = [f"{ms[p]['best']:.3f}; {ms[p]['median']:.3f}" for p in names]
        ratios = [round(ms["f32"]["best"] / ms[p]["best"], 3) for p in lower]
        auto = min(names, key=lambda p: ms[p]["best"])
        rows.append([name, *shown, *ratios, round(time.perf_counter() - start, 1), auto])
    for width in (64, 256):
        ms, errors = kernel_choice.time_precisions(list(names), kernel_choice.PRECISION_BATCH, width)
        rows.append([f"--precision auto's own measure: MLP step, 2 hidden layers of {width}, batch 256",
                     *[f"{ms[p]:.3f}" for p in names], *[round(ms["f32"] / ms[p], 3) for p in lower], None,
                     min(names, key=ms.get)])  # fmt: skip
    rows.append(learning_row())
    cpu = kernel_choice.cpu_info()[0]
    notes = (
        f"CPU: {cpu}. Each learning step compiled in each precision (bf16: bfloat16 operands into "
        "every dense product and MinAtar's matrix-product convolution, float32 sums, float32 "
        "parameters, Adam moments, targets and losses; bf16-onednn: the same products by oneDNN's "
        "matmul, bfloat16 arithmetic allowed, where the kernel is built), then timed in "
        f"{ROUNDS} interleaved rounds of 5 calls each; the best round and the median are shown, the "
        "ratios are of the best rounds (>1: the lower precision faster). The machine's 2 cores were "
        "shared with other processes, so the medians are noisy; the ratios are the figures to read. "
        "`auto` is what `--precision auto` would choose for that workload by this row's timing (the "
        "flag itself times the MLP step of the run's widest layer, the last rows). Learning rows: SAC "
        f"on Pendulum-v1 (64-64, 500 random steps, lr 1e-3) for {LEARNING_STEPS:,} env steps, "
        f"{LEARNING_SEEDS} seeds vmapped on the compiled runner; the final evaluation is 10 greedy "
        "episodes per seed (wall-clock includes compilation)."
    )
    return {
        "name": "precision",
        "title": "Mixed precision: f32 against bf16 products (XLA's and oneDNN's), per learning step",
        "headers": headers,
        "rows": rows,
        "notes": notes,
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
