"""Collection and learning in parallel: the parallel runner against its parts and the sequential runner;
and what logging, evaluation and checkpoints cost each runner.

**Overlap.** On the same work (same env steps, same learning steps), measured one after the other in
this process:

- *collect alone*: an :class:`agentax.runners.host.Actor` fills a replay buffer (DQN) or collects
  rollouts (PPO) with fixed parameters, no learning;
- *learn alone*: the same learning steps with no env: DQN's ``OffPolicyLearner.phase`` on the buffer
  that collect-alone filled, PPO's jitted ``learn`` on one collected rollout, over and over;
- *sequential*: ``agentax.runners.host.train`` (collect, then learn, then collect ...);
- *parallel*: ``agentax.runners.parallel.train`` with 1 and with 2 actor threads (DQN: rate limiter;
  PPO: policy lag 1).

Every timing includes the same one-off costs (a fresh learner's jitted programs retraced, their
compiled code from the warm compilation cache); the runs' own timings stop at their last metrics row,
before the final evaluation. The targets (the issue's "Measured" section): parallel ≤ 1.1 ×
max(collect alone, learn alone), and ≥ 1.6 × faster than sequential on a workload where collecting
and learning cost about the same. That workload is named in ``DQN_WORKLOAD``.

**Overhead.** Each runner with its defaults and a run folder (``Run.create``: metrics.csv,
TensorBoard, checkpoints, eval.json, curve.png) against a bare program of the same work, on
PureJaxRL's PPO CartPole-v1 settings (``presets.preset('ppo', 'default')``). Compiled: the same updates as
jitted ``lax.scan`` calls between the runner's evaluation points and the same in-program greedy
evaluations (PureJaxRL style, one call per segment, nothing else); host: the same actor and jitted
``learn`` calls in a plain loop (no rows, no evaluation, no files). Both compare the training loop
(``TrainResult.train_seconds``, against the bare loop); the notes give the whole calls too.
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

ENV_ID = "CartPole-v1"
QUICK = os.environ.get("AGENTAX_BENCH_QUICK", "") not in ("", "0")
"""smaller runs (a busy machine, a smoke test); the notes say so"""

DQN_STEPS = 5_120 if QUICK else 15_360
PPO_STEPS = 7_680 if QUICK else 20_480
HOST_OVERHEAD_STEPS = 10_240 if QUICK else 30_720
OVERHEAD_REPEATS = int(os.environ.get("AGENTAX_BENCH_REPEATS", 1 if QUICK else 3))
"""alternating bare/runner runs of each overhead pair; the fastest of each is kept"""
DQN_WORKLOAD = dict(
    num_envs=4,
    train_frequency=64,  # 256 env steps between learning phases (RL-Zoo's train_freq 256)
    gradient_steps=64,
    batch_size=64,
    hidden=(256, 256),  # RL-Zoo's DQN net for CartPole-v1
    learning_starts=1_000,
)
"""RL-Zoo's DQN CartPole-v1 net and batch (256-256, 64) with 4 envs and 64 learning steps per 256 env
steps (RL-Zoo: 128): collecting 256 steps (~28 ms) and a phase of 64 learning steps (~31 ms) cost
about the same here (measured 2026-11-29, one core each)"""


class Clock:
    """Wall and process CPU seconds of a block (CPU/wall > 1: more than one core busy)."""

    def __enter__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall, self.cpu = time.perf_counter() - self.wall, time.process_time() - self.cpu


def run_seconds(result) -> float:
    """A host or parallel run's training seconds: up to its last metrics row (no final evaluation)."""
    return float(result.rows[-1]["wall_seconds"])


def _mean_of(rows: list[dict], name: str) -> float:
    values = [row[name] for row in rows if name in row and np.isfinite(row[name])]
    return float(np.mean(values)) if values else float("nan")


# ---------------------------------------------------------------- the overlap


def dqn_agent(total_steps: int):
    from agentax.agents import dqn, presets
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_host_env

    cfg = dataclasses.replace(
        presets.preset("dqn", "default").config, total_steps=total_steps, **DQN_WORKLOAD
    )
    env = make_host_env(ENV_ID, 1)
    agent = dqn.make_agent(EnvSpec.of(env), cfg.validate())
    env.close()
    return agent


def ppo_agent(total_steps: int, preset: str = "cartpole-fast"):
    from agentax.agents import ppo, presets
    from agentax.agents.protocol import EnvSpec
    from agentax.api import agent_maker
    from agentax.envs import make_host_env

    cfg = dataclasses.replace(presets.preset("ppo", preset).config, total_steps=total_steps)
    env = make_host_env(ENV_ID, 1)
    agent = agent_maker(ppo, EnvSpec.of(env), cfg)()
    env.close()
    return agent


def _actor(agent, num_envs: int):
    from agentax.envs import make_host_env
    from agentax.runners import host, session

    init_key, _, actors_key = session.agent_keys(0)
    env = make_host_env(ENV_ID, num_envs, training=True)
    actor = host.Actor(agent, env, host.actor_seed(0, 0, 0), host.fold_actor_key(actors_key, 0, 0))
    return actor, agent.init(init_key)


def collect_alone_off_policy(agent):
    """The actor alone: ``total_steps`` env steps into a replay buffer with fixed parameters."""
    from agentax.runners import host
    from agentax.runners.driver import ReplayObserver

    experience = agent.experience
    actor, state = _actor(agent, experience.num_envs)
    replay = host.replay_for(agent, actor.obs_shape, 0)
    observer = ReplayObserver(replay, experience.n_step, experience.discount_factor)
    with Clock() as clock:
        while actor.steps.count < agent.total_steps:
            actor.collect(state, observer, experience.train_frequency)
    actor.close()
    return clock, replay, actor.steps.count


def learn_alone_off_policy(agent, replay, phases: int):
    """The learner alone: ``phases`` learning phases on a filled buffer, no env."""
    import jax

    from agentax.runners import host, session

    init_key, learner_key, _ = session.agent_keys(0)
    state = agent.init(init_key)
    with Clock() as clock:
        learner = host.OffPolicyLearner(agent, replay)
        for _ in range(phases):
            learner_key, key = jax.random.split(learner_key)
            state, _ = learner.phase(state, key, agent.total_steps)
        jax.block_until_ready(state)
    return clock


def collect_alone_on_policy(agent, iterations: int):
    experience = agent.experience
    actor, state = _actor(agent, experience.num_envs)
    with Clock() as clock:
        for _ in range(iterations):
            trajectory = actor.rollout(state, experience.num_steps)
    steps = actor.steps.count
    actor.close()
    return clock, trajectory, steps


def learn_alone_on_policy(agent, trajectory, iterations: int):
    import jax

    from agentax.runners import session

    init_key, learner_key, _ = session.agent_keys(0)
    state = agent.init(init_key)
    with Clock() as clock:
        learn = jax.jit(agent.learn)
        for _ in range(iterations):
            learner_key, key = jax.random.split(learner_key)
            state, _ = learn(state, trajectory, key)
        jax.block_until_ready(state)
    return clock


def sequential(agent):
    from agentax.runners import host

    with Clock() as clock:
        result = host.train(agent, ENV_ID, host.HostRunnerConfig())
    return result, clock


def parallel_run(agent, actors: int):
    from agentax.runners import parallel

    with Clock() as clock:
        result = parallel.train(agent, ENV_ID, parallel.ParallelRunnerConfig(actors=actors, policy_lag=1))
    return result, clock


def warm_up(agent, small_steps: int) -> None:
    """Compile every program once (shapes of 1 and 2 actors), so the timed runs find them cached."""
    small = dataclasses.replace(agent, total_steps=small_steps)
    sequential(small)
    for actors in (1, 2):
        parallel_run(small, actors)


def overlap_rows(label: str, agent, on_policy: bool) -> tuple[list[list], dict]:
    """Collect alone, learn alone, sequential, parallel with 1 and 2 actors on the same work."""
    seq, seq_clock = sequential(agent)
    if on_policy:
        iterations = seq.updates
        collect, trajectory, collect_steps = collect_alone_on_policy(agent, iterations)
        learn = learn_alone_on_policy(agent, trajectory, iterations)
        learning = f"{iterations} learn calls"
    else:
        gradient_steps = agent.experience.gradient_steps
        collect, replay, collect_steps = collect_alone_off_policy(agent)
        learn = learn_alone_off_policy(agent, replay, seq.updates // gradient_steps)
        learning = f"{seq.updates // gradient_steps} phases"
    runs = {actors: parallel_run(agent, actors) for actors in (1, 2)}
    slower_part = max(collect.wall, learn.wall)
    seq_seconds = run_seconds(seq)

    def row(what, seconds, cpu, env_steps, updates, parallel_seconds=None):
        over_part = seconds / slower_part if parallel_seconds else None
        speedup = seq_seconds / seconds if parallel_seconds else None
        return [
            label,
            what,
            env_steps,
            updates,
            round(seconds, 2),
            round(cpu / seconds, 2),
            over_part,
            speedup,
        ]

    rows = [
        row("collect alone", collect.wall, collect.cpu, collect_steps, 0),
        row(f"learn alone ({learning})", learn.wall, learn.cpu, 0, seq.updates),
        row(
            "sequential (host.train)",
            seq_seconds,
            seq_clock.cpu * seq_seconds / seq_clock.wall,
            seq.env_steps,
            seq.updates,
        ),
    ]
    detail = {"collect": collect.wall, "learn": learn.wall, "sequential": seq_seconds}
    for actors, (result, clock) in runs.items():
        seconds = run_seconds(result)
        rows.append(
            row(
                f"parallel, {actors} actor{'s' if actors > 1 else ''}"
                + (", policy lag 1" if on_policy else ""),
                seconds,
                clock.cpu * seconds / clock.wall,  # the run's CPU share, scaled to its training seconds
                result.env_steps,
                result.updates,
                parallel_seconds=seconds,
            )
        )
        detail[f"parallel{actors}"] = {
            "seconds": seconds,
            "updates_equal": result.updates == seq.updates,
            "actor_wait": _mean_of(result.rows, "actor_wait_fraction"),
            "learner_wait": _mean_of(result.rows, "learner_wait_fraction"),
            "policy_lag": _mean_of(result.rows, "policy_lag"),
        }
    for r in rows:
        r[6] = round(r[6], 2) if r[6] is not None else None
        r[7] = round(r[7], 2) if r[7] is not None else None
    return rows, detail


def collection_breakdown(agent) -> dict:
    """Microseconds per env step of DQN collection's parts: Gymnasium's step, the jitted act call
    (dispatch, run, device_get), the NumPy n-step push; the rest is the Driver and observers."""
    import jax

    from agentax.envs import make_host_env
    from agentax.replay.host import NStepAccumulator
    from agentax.runners.driver import first_time_step

    experience = agent.experience
    envs = experience.num_envs
    env = make_host_env(ENV_ID, envs)
    first_time_step(env, 0)
    state = agent.init(jax.random.key(0))
    act = jax.jit(agent.act)
    obs = np.zeros((envs, 4), np.float32)
    actions = np.zeros(envs, np.int64)
    n = 400

    def per_step(call) -> float:
        call()
        start = time.perf_counter()
        for _ in range(n):
            call()
        return (time.perf_counter() - start) / (n * envs) * 1e6

    key = jax.random.key(1)
    gym_us = per_step(lambda: env.step(actions))
    act_us = per_step(lambda: jax.device_get(act(state, obs, key, 0)))
    step = first_time_step(env, 0)
    from agentax.replay import Transition

    transition = Transition(
        obs=step.obs,
        action=actions,
        reward=np.zeros(envs, np.float32),
        next_obs=step.obs,
        terminated=np.zeros(envs, bool),
        truncated=np.zeros(envs, bool),
        num_steps=np.ones(envs, np.int32),
        info=None,
    )
    accumulator = NStepAccumulator(experience.n_step, experience.discount_factor)
    push_us = per_step(lambda: accumulator.push(transition))
    env.close()
    return {"gym": gym_us, "act": act_us, "push": push_us}


# ---------------------------------------------------------------- the overhead


def compiled_overhead() -> dict:
    """PPO default preset, 500k steps: the runner with defaults and a run folder vs a bare program of
    the same work (the same updates and the same in-program evaluations, in the fewest calls)."""
    import jax

    from agentax.agents import ppo, presets
    from agentax.api import compiled_program
    from agentax.envs import make_jax
    from agentax.envs.core import episode_returns
    from agentax.runners import compiled
    from agentax.runners.rollout import SEED_AXIS
    from agentax.runners.session import EVAL_KEY_OFFSET
    from agentax.runs import Run

    env, preset = make_jax(ENV_ID), presets.preset("ppo", "default")
    algorithm = compiled_program(ppo, env, preset.config)
    runner = compiled.RunnerConfig(updates_per_chunk=preset.updates_per_chunk)
    seeds = compiled.seeds_of(runner)
    total, per_chunk = algorithm.num_updates, runner.updates_per_chunk
    every = compiled.eval_every_chunks(runner, total)
    chunks = -(-total // per_chunk)
    points = sorted({min(c * per_chunk, total) for c in range(every, chunks + 1, every)} | {total})
    """the updates after which the runner evaluates (every ``every`` chunks, and after the last)"""

    init = jax.jit(compiled.init_from_seeds(algorithm))

    def updates(length: int):
        def run(state):
            def scan(state):
                return jax.lax.scan(lambda s, _: algorithm.update(s), state, None, length)[0]

            return jax.vmap(scan, axis_name=SEED_AXIS)(state)

        program = jax.jit(run, donate_argnums=0).lower(init(seeds))
        return program.compile(compiled.CHUNK_COMPILER_OPTIONS)

    def evaluate(state, evaluation):
        def one(state, seed):
            key = jax.random.fold_in(jax.random.key(seed), EVAL_KEY_OFFSET + evaluation)
            return episode_returns(env, algorithm.greedy_policy(state), key, runner.eval_episodes)

        return jax.vmap(one)(state, seeds)

    start = time.perf_counter()
    segments = {
        length: updates(length) for length in {b - a for a, b in zip([0, *points[:-1]], points, strict=True)}
    }
    evaluation = jax.jit(evaluate).lower(init(seeds), 0).compile(compiled.CHUNK_COMPILER_OPTIONS)
    every_update = updates(total)
    bare_compile = time.perf_counter() - start

    def bare() -> float:
        """PureJaxRL's loop with the runner's evaluations: a scan to each evaluation point, then it."""
        state = jax.block_until_ready(init(seeds))
        start, done = time.perf_counter(), 0
        for n, point in enumerate(points):
            state, done = segments[point - done](state), point
            returns, _ = evaluation(state, n)
        jax.block_until_ready(returns)
        return time.perf_counter() - start

    def bare_updates() -> float:
        state = jax.block_until_ready(init(seeds))
        start = time.perf_counter()
        jax.block_until_ready(every_update(state))
        return time.perf_counter() - start

    figures = {"bare": [], "bare_updates": [], "runner": [], "runner_whole": [], "runner_no_folder": []}
    bare()  # the first calls of each program
    for _ in range(OVERHEAD_REPEATS):
        figures["bare_updates"].append(bare_updates())
        figures["bare"].append(bare())
        with tempfile.TemporaryDirectory() as folder:
            run = Run.create(Path(folder) / "run", {"algo": "ppo", "env": ENV_ID, "preset": "default"})
            start = time.perf_counter()
            result = compiled.train_program(algorithm, env, runner, run=run)
            whole = time.perf_counter() - start
            figures["runner"].append(result.train_seconds)
            figures["runner_whole"].append(whole - result.compile_seconds)
            figures["runner_compile"] = result.compile_seconds
            figures["rows"] = len(result.rows)
        figures["runner_no_folder"].append(compiled.train_program(algorithm, env, runner).train_seconds)
    figures["bare_compile"] = bare_compile
    figures["evaluations"] = len(points)
    figures["num_updates"] = total
    figures["updates_per_chunk"] = per_chunk
    figures["env_steps"] = total * algorithm.steps_per_update
    return figures


def compiled_overhead_as_trained() -> dict:
    """:func:`compiled_overhead` in a process of its own, as ``agentax train`` runs the compiled
    runner: jax's CPU client made on one CPU (``agentax._xla``). This process gave XLA every CPU for
    the parallel runner, and there the long scans of the bare program ran ~15 % slower than the
    runner's chunks (measured: 4.55 s against 4.05 s; on one CPU both ~3.7 s), which would flatter
    the runner; the vmapped program is also the one the one-CPU client guards against a hang."""
    done = subprocess.run(
        [sys.executable, __file__, "--compiled-overhead"],
        capture_output=True,
        text=True,
        check=True,
        timeout=600,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def host_overhead() -> dict:
    """PPO default preset on Gymnasium's CartPole-v1: host.train with a run folder vs a plain loop of
    the same actor and learning calls."""
    import jax

    from agentax.envs import make_host_env
    from agentax.runners import host
    from agentax.runners.session import agent_keys
    from agentax.runs import Run

    agent = ppo_agent(HOST_OVERHEAD_STEPS, "default")
    runner = host.HostRunnerConfig()
    learn = jax.jit(agent.learn)

    def bare() -> float:
        """The host runner's work and nothing else: rollouts and learning steps, keyed as it keys them."""
        init_key, learner_key, actors_key = agent_keys(runner.seed)
        env = make_host_env(ENV_ID, agent.experience.num_envs, training=True)
        actor = host.Actor(
            agent, env, host.actor_seed(runner.seed, 0, 0), host.fold_actor_key(actors_key, 0, 0)
        )
        state = agent.init(init_key)
        start = time.perf_counter()
        for _ in range(host.num_updates(agent)):
            learner_key, learn_key = jax.random.split(learner_key)
            state, _ = learn(state, actor.rollout(state, agent.experience.num_steps), learn_key)
        jax.block_until_ready(state)
        seconds = time.perf_counter() - start
        actor.close()
        return seconds

    figures = {"bare": [], "run": [], "run_whole": [], "no_folder_whole": []}
    host.train(dataclasses.replace(agent, total_steps=2_048), ENV_ID, runner)  # compile
    bare()
    for _ in range(OVERHEAD_REPEATS):
        figures["bare"].append(bare())
        start = time.perf_counter()
        host.train(agent, ENV_ID, runner)
        figures["no_folder_whole"].append(time.perf_counter() - start)
        with tempfile.TemporaryDirectory() as folder:
            run = Run.create(Path(folder) / "run", {"algo": "ppo", "env": ENV_ID, "preset": "default"})
            start = time.perf_counter()
            result = host.train(agent, ENV_ID, runner, run=run)
            figures["run_whole"].append(time.perf_counter() - start)
            figures["run"].append(result.train_seconds)
    figures["env_steps"] = result.env_steps
    figures["updates"] = result.updates
    figures["rows"] = len(result.rows)
    return figures


# ---------------------------------------------------------------- the section


def run() -> dict:
    from agentax import _xla

    _xla.enable_compilation_cache()
    _xla.let_xla_use_every_cpu()  # as the host and parallel runners do (this process makes no other kind)
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()

    dqn = dqn_agent(DQN_STEPS)
    warm_up(dqn, 1_536)
    dqn_rows, dqn_detail = overlap_rows("DQN, RL-Zoo schedule, net 256-256", dqn, on_policy=False)
    breakdown = collection_breakdown(dqn)

    ppo = ppo_agent(PPO_STEPS)
    warm_up(ppo, 2 * ppo.experience.num_envs * ppo.experience.num_steps)
    ppo_rows, ppo_detail = overlap_rows("PPO cartpole-fast", ppo, on_policy=True)
    del dqn, ppo

    host_figures = host_overhead()
    compiled_figures = compiled_overhead_as_trained()

    headers = [
        "workload",
        "run",
        "env steps",
        "learning steps",
        "seconds",
        "CPU / wall",
        "÷ max(collect, learn) (target ≤ 1.1)",
        "sequential ÷ this (target ≥ 1.6)",
        "over the bare run (target ≤ +5 %)",
    ]
    bare, runner = min(compiled_figures["bare"]), min(compiled_figures["runner"])
    bare_updates, runner_whole = min(compiled_figures["bare_updates"]), min(compiled_figures["runner_whole"])
    runner_no_folder = min(compiled_figures["runner_no_folder"])
    host_bare, host_run = min(host_figures["bare"]), min(host_figures["run"])
    host_whole, host_no_folder = min(host_figures["run_whole"]), min(host_figures["no_folder_whole"])
    compiled_label, host_label = (
        "PPO default, compiled (JAX CartPole)",
        "PPO default, host (Gymnasium CartPole)",
    )
    c_steps, c_updates = compiled_figures["env_steps"], compiled_figures["num_updates"]
    h_steps, h_updates = host_figures["env_steps"], host_figures["updates"]
    overhead_rows = [
        [compiled_label, "bare program: updates, one scan (no evaluations)", c_steps, c_updates]
        + [round(bare_updates, 2), None, None, None, None],
        [compiled_label, f"bare program: the same updates and {compiled_figures['evaluations']} evaluations"]
        + [c_steps, c_updates, round(bare, 2), None, None, None, None],
        [compiled_label, "compiled runner, defaults + run folder", c_steps, c_updates, round(runner, 2)]
        + [None, None, None, f"{runner / bare - 1:+.1%}"],
        [host_label, "bare loop: the same rollouts and learn calls", h_steps, h_updates, round(host_bare, 2)]
        + [None, None, None, None],
        [host_label, "host runner, defaults + run folder", h_steps, h_updates, round(host_run, 2)]
        + [None, None, None, f"{host_run / host_bare - 1:+.1%}"],
    ]
    for row in dqn_rows + ppo_rows:
        row.append(None)
    rows = dqn_rows + ppo_rows + overhead_rows

    def verdict(detail: dict, actors: int) -> str:
        p = detail[f"parallel{actors}"]
        over = p["seconds"] / max(detail["collect"], detail["learn"])
        speedup = detail["sequential"] / p["seconds"]
        return (
            f"{actors} actor{'s' if actors > 1 else ''}: {over:.2f} × the slower part "
            f"({'met' if over <= 1.1 else 'missed'}), {speedup:.2f} × faster than sequential "
            f"({'met' if speedup >= 1.6 else 'missed'}); actors waited {p['actor_wait']:.0%} of their time, "
            f"the learner {p['learner_wait']:.0%}; learning steps equal to sequential: {p['updates_equal']}"
        )

    collect_us = dqn_detail["collect"] / DQN_STEPS * 1e6
    parts = breakdown["gym"] + breakdown["act"] + breakdown["push"]
    notes = (
        f"**Overlap** (first {len(dqn_rows) + len(ppo_rows)} rows). The balanced workload is "
        f"**DQN on Gymnasium's CartPole-v1 with RL-Zoo's schedule and net**: 4 envs, 256 env steps "
        f"(train_frequency 64 per env) between learning phases of 64 learning steps on batches of 64, "
        f"a 256-256 Q-network, Double DQN, 3-step returns, learning from 1,000 env steps, "
        f"{DQN_STEPS:,} env steps in all. Collect alone, learn alone, sequential and parallel do the "
        "same work (same env steps; the learning steps column checks the learning steps), measured one "
        "after the other in this process; seconds are training only (a run's last metrics row, before "
        "its final evaluation), every program compiled beforehand (warm-up runs, persistent cache) except "
        "that each run retraces its learner once, as collect/learn alone do. CPU / wall is the "
        f"process's CPU seconds over wall seconds ({cpus} CPUs usable here; above 1 means both busy). "
        f"PPO (`cartpole-fast`: 8 envs × 32 steps, 10 epochs × 2 minibatches, {PPO_STEPS:,} steps) is "
        "the on-policy case, policy lag 1: collection dominates it, so the most parallel can give is "
        "sequential ÷ collect alone.\n\n"
        f"DQN — {verdict(dqn_detail, 1)}. {verdict(dqn_detail, 2)}. "
        f"PPO — {verdict(ppo_detail, 1)}. {verdict(ppo_detail, 2)}.\n\n"
        f"**Where the time goes.** DQN collection costs {collect_us:.0f} µs per env step: Gymnasium's "
        f"vector step {breakdown['gym']:.0f} µs, the jitted ε-greedy act (dispatch, run, device_get) "
        f"{breakdown['act']:.0f} µs, the NumPy n-step push {breakdown['push']:.0f} µs per env step "
        f"(with 4 envs per call), the Driver, observers and replay writes the remaining "
        f"{max(collect_us - parts, 0):.0f} µs. All of it is Python or JAX dispatch on tiny programs, "
        "so an actor thread holds the GIL nearly all the time; the learner's phase is one compiled "
        "call (a `lax.scan` over 64 learning steps) during which JAX releases the GIL, so the two "
        "overlap on two cores, and what does not overlap is the learner's Python: the replay prefetch "
        "thread's NumPy sampling of 4,096 transitions per phase, dispatch, the rate limiter and "
        "rows (PPO: stacking the rollout and counting its returns step by step, on the learner's thread). "
        "Two actors share one GIL, so they collect no faster than one (each call steps half the envs "
        "for the same dispatch cost), and they contend with the learner's Python. XLA's CPU backend may "
        "also run a learning phase's larger matrix products on both cores, taking the actor's core. "
        "On a busy machine (other processes on the 2 cores) every figure moves; CPU / wall shows how "
        "much of the second core a run got.\n\n"
        f"**Overhead** (last 5 rows): each runner's training loop (`TrainResult.train_seconds`: from its "
        "first iteration to its last row and checkpoint) against a bare program of the same work. "
        "Compiled: PureJaxRL's PPO settings (`presets.preset('ppo', 'default')`: 4 envs × 128 steps, "
        f"4 epochs × 4 minibatches, {compiled_figures['env_steps']:,} env steps, "
        f"{compiled_figures['num_updates']} updates); the bare program is PureJaxRL's loop doing what "
        "the runner does: jitted `lax.scan`s "
        f"of `update` up to each of the runner's {compiled_figures['evaluations']} evaluation points, each "
        "followed by the same in-program evaluation (20 greedy episodes, the runner's keys), compiled "
        f"with the runner's options ({compiled_figures['bare_compile']:.1f} s apart); both measured in a "
        "process of their own, as `agentax train` runs the compiled runner (jax's CPU client on one "
        "CPU; in this process, whose client has every CPU for the parallel runner, the bare program's "
        "long scans ran ~15 % slower than the runner's chunks). `compiled.train` "
        f"with its defaults (a chunk of {compiled_figures['updates_per_chunk']} updates, a row per chunk "
        f"— {compiled_figures.get('rows', 0)} rows —, a checkpoint every 30 s and at the end) into a run "
        f"folder takes {runner / bare - 1:+.1%} over it (target ≤ +5 %; {runner / bare_updates - 1:+.1%} "
        f"over the updates alone in one scan, which skips the evaluations); "
        f"{runner_whole / bare - 1:+.1%} with its start (init) and end (final evaluation, eval.json, "
        f"curve.png), compile ({compiled_figures['runner_compile']:.1f} s) apart; without a run folder "
        f"the loop took {runner_no_folder:.2f} s ({runner_no_folder / bare - 1:+.1%}). The runner "
        "dispatches chunk k + 1 before it writes chunk k's row (the row's episode counters copied out "
        "first; not where chunk k's state is checkpointed or may stop the run), so its Python — rows, "
        "TensorBoard, the dispatch itself — runs while the next chunk computes. "
        f"Host: the same PPO settings for {host_figures['env_steps']:,} env steps on Gymnasium's "
        "CartPole-v1; the bare loop makes the runner's rollouts and jitted `learn` calls with its keys "
        "and nothing else; `host.train` with defaults (a row every 2,048 env steps — "
        f"{host_figures['rows']} rows —, a checkpoint every 30 s and at the end) into a run folder: "
        f"{host_run / host_bare - 1:+.1%} (target ≤ +5 %). Whole calls, the final evaluation "
        f"(10 episodes), eval.json and curve.png included: {host_whole:.2f} s into a run folder, "
        f"{host_no_folder:.2f} s with `run=None`. The first run folder of a process also pays "
        "matplotlib's import for curve.png (0.35 s, measured apart) and its first TensorBoard writer "
        "(~20 ms), which the fastest-of figures leave out."
        + (f" Fastest of {OVERHEAD_REPEATS} alternating runs each." if OVERHEAD_REPEATS > 1 else "")
    )
    if QUICK:
        notes += (
            "\n\n*Quick run (`AGENTAX_BENCH_QUICK=1`): fewer env steps than `make bench` uses, one run "
            "each, on a machine shared with other work at the time; treat these figures as a smoke test.*"
        )
    return {
        "name": "parallel",
        "title": "Parallel runner: collection and learning overlapped; runner overhead",
        "headers": headers,
        "rows": rows,
        "notes": notes,
    }


if __name__ == "__main__":
    if sys.argv[1:] == ["--compiled-overhead"]:
        from agentax import _xla

        _xla.enable_compilation_cache()
        print(json.dumps(compiled_overhead()))
    else:
        print(json.dumps(run(), indent=2))
