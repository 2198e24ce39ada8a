"""Atari (Breakout) throughput: envs, the DQN learning step, the frame replay, DQN against
Stable-Baselines3, PPO and PQN on every runner that takes them.

Rows, all measured in this run, one after the other:

- **envs**: agent steps per second of 8 Breakout envs with random actions (drawn in advance): EnvPool's
  own host API (``envpool.make("Breakout-v5", num_envs=8, ...)``, the settings agentax's EnvPool backend
  passes, so only the adapter differs), agentax's ``AtariEnv`` on backend ``envpool`` and on ``ale``;
- **learning step**: updates per second of the Nature-CNN DQN learning step, batch 32 of ``uint8
  [4, 84, 84]`` stacks: agentax's ``dqn.make_learn`` with the ``nature`` preset's settings, jitted,
  against a bare JAX reference written here (a flax Nature CNN, Huber TD loss against a target
  network, Adam, jitted; same shapes); compile seconds apart;
- **frame replay**: ``FrameReplayBuffer`` at capacity 100k (8 env streams, 1-step): transitions
  added per second in 8-env batches, batches of 32 sampled per second, uniform and prioritized, and
  bytes per transition (``nbytes / capacity``);
- **DQN against Stable-Baselines3**: agent steps per second of a whole training process after
  learning starts, SB3's DQN (``.bench-venv``: torch on the CPU, its Atari wrappers) and
  ``agentax train dqn`` (host runner, parallel runner with one actor) at the same settings;
- **PPO and PQN**: agent steps per second of PPO's ``atari`` preset and PQN's ``breakout-hour`` on
  the host runner, the parallel runner (policy lag 1), the compiled Atari runner (EnvPool stepped
  inside the jitted rollout; policy lag 0 and 1) and the Ray runner, after the first update (which
  compiles), in a process of their own (jax's client for every CPU, as ``agentax train`` makes it).
  ``python benchmarks/bench_atari.py on-policy`` measures these rows alone and prints them.

``AGENTAX_BENCH_QUICK=1`` shortens every run (the notes say so).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
BENCH_VENV = ROOT / ".bench-venv"
QUICK = os.environ.get("AGENTAX_BENCH_QUICK", "") not in ("", "0")
"""smaller runs (a busy machine, a smoke test); the notes say so"""

ENV_ID = "ALE/Breakout-v5"
NUM_ENVS = 8
ENV_SECONDS = 1.5 if QUICK else 4.0  # per env implementation, after a short warm-up
LEARN_SECONDS = 2.0 if QUICK else 6.0  # per learning-step implementation, after compiling
LEARN_ROUNDS = 4  # the two learning steps are timed in turns
REPLAY_CAPACITY = 100_000
REPLAY_FILL = 25_000 if QUICK else 120_000  # transitions added (full: past capacity, so it overwrites)
SAMPLE_SECONDS = 1.0 if QUICK else 3.0
BATCH = 32

DQN_LEARNING_STARTS = 1_000
DQN_WARMUP = 2_048  # the first metrics row of agentax's runners: compilation and warm-up before it
DQN_STEPS = 4_096 if QUICK else 8_192
"""agent steps of each DQN run; steps/s are measured from step DQN_WARMUP to the end"""
UPDATES = 2 if QUICK else 4  # PPO's and PQN's, after the first (it compiles; not timed)
SB3_TARGET = 1.3  # the issue: agentax's DQN at >= 1.3 x SB3's agent steps/s

BENCH_REQUIREMENTS = ["stable-baselines3", "torch==2.13.0", "ale-py", "opencv-python-headless", "gymnasium"]
"""what SB3's Atari DQN needs in ``.bench-venv`` (torch==2.13.0: the CPU wheel on disk here)"""
BENCH_IMPORTS = "import stable_baselines3, torch, ale_py, cv2, gymnasium"


# ---------------------------------------------------------------- helpers


def _timed_loop(step, seconds: float, warmup: int = 3) -> tuple[int, float]:
    """Call ``step()`` ``warmup`` times, then until ``seconds`` have passed: ``(calls, seconds)``."""
    for _ in range(warmup):
        step()
    calls, start = 0, time.perf_counter()
    while True:
        step()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            return calls, elapsed


def _load() -> str:
    """The load averages and the CPUs, for the notes (the figures move with the machine's load)."""
    try:
        one, five, _ = os.getloadavg()
        return f"load average {one:.1f} (1 min), {five:.1f} (5 min) on {os.cpu_count()} CPUs"
    except OSError:
        return "load average unknown"


# ---------------------------------------------------------------- envs


def env_rates() -> list[tuple[str, float]]:
    """Agent steps/s of 8 Breakout envs, random actions: bare EnvPool, AtariEnv on envpool and ale."""
    from agentax.envs.atari import FRAME_SKIP, envpool_kwargs, make_atari

    rng = np.random.default_rng(0)
    actions = rng.integers(0, 4, size=(4_096, NUM_ENVS))
    results = []
    try:
        import envpool
    except ImportError:
        envpool = None
    if envpool is not None:
        pool = envpool.make(**envpool_kwargs("Breakout", NUM_ENVS, 0.0, 30, 108_000 // FRAME_SKIP, 0))
        pool.reset()
        i = iter(range(10**9))
        calls, seconds = _timed_loop(
            lambda: pool.step(actions[next(i) % len(actions)].astype(np.int32)), ENV_SECONDS
        )
        pool.close()
        results.append(("EnvPool host API (`envpool.make`, 8 envs)", calls * NUM_ENVS / seconds))
    if envpool is not None:
        results.append(("EnvPool XLA (`XlaAtari.step` in a jitted 128-step `lax.scan`)", xla_rate(actions)))
    for backend in ("envpool", "ale"):
        if backend == "envpool" and envpool is None:
            continue
        env = make_atari(ENV_ID, NUM_ENVS, backend=backend, sticky_actions=0.0, training=True)
        env.reset(seed=0)
        i = iter(range(10**9))
        calls, seconds = _timed_loop(
            lambda env=env, i=i: env.step(actions[next(i) % len(actions)]), ENV_SECONDS
        )
        env.close()
        results.append((f"agentax `AtariEnv`, backend {backend}", calls * NUM_ENVS / seconds))
    return results


def xla_rate(actions: np.ndarray) -> float:
    """Agent steps/s of 8 Breakout envs stepped by EnvPool's XLA interface inside one jitted program
    (``agentax.envs.envpool_xla``, as the compiled Atari runner steps them), 128 steps a call."""
    import jax
    import jax.numpy as jnp

    from agentax.envs.envpool_xla import XlaAtari

    env = XlaAtari(ENV_ID, NUM_ENVS, sticky_actions=0.0)
    handle, _ = env.reset()
    steps = jnp.asarray(actions[:128], jnp.int32)

    @jax.jit
    def rollout(handle):
        def step(handle, action):
            handle, result = env.step(handle, action)
            return handle, result.reward.sum()

        return jax.lax.scan(step, handle, steps)[0]

    box = {"handle": jax.block_until_ready(rollout(handle))}
    calls, seconds = _timed_loop(
        lambda: box.update(handle=jax.block_until_ready(rollout(box["handle"]))), ENV_SECONDS
    )
    env.close()
    return calls * len(steps) * NUM_ENVS / seconds


# ---------------------------------------------------------------- the learning step


def _batch(num_actions: int, seed: int):
    from agentax.replay import ReplaySample, Transition

    rng = np.random.default_rng(seed)
    transition = Transition(
        obs=rng.integers(0, 256, (BATCH, 4, 84, 84), dtype=np.uint8),
        action=rng.integers(0, num_actions, BATCH).astype(np.int32),
        reward=rng.choice(np.array([-1.0, 0.0, 1.0], np.float32), BATCH),
        next_obs=rng.integers(0, 256, (BATCH, 4, 84, 84), dtype=np.uint8),
        terminated=rng.random(BATCH) < 0.05,
        truncated=np.zeros(BATCH, bool),
        num_steps=np.ones(BATCH, np.int32),
    )
    return ReplaySample(transition=transition, indices=np.arange(BATCH), weights=np.ones(BATCH, np.float32))


def bare_learn_step(num_actions: int, samples: list):
    """``(step, compile seconds)``: one update of a minimal jitted Nature-CNN DQN (flax + optax, Huber,
    Adam) per ``step()`` call, waited for."""
    import flax.linen as nn
    import jax
    import jax.numpy as jnp
    import optax

    class QNet(nn.Module):
        @nn.compact
        def __call__(self, frames):
            x = jnp.transpose(frames.astype(jnp.float32) / 255.0, (0, 2, 3, 1))
            x = nn.relu(nn.Conv(32, (8, 8), (4, 4), padding="VALID")(x))
            x = nn.relu(nn.Conv(64, (4, 4), (2, 2), padding="VALID")(x))
            x = nn.relu(nn.Conv(64, (3, 3), (1, 1), padding="VALID")(x))
            x = nn.relu(nn.Dense(512)(x.reshape(x.shape[0], -1)))
            return nn.Dense(num_actions)(x)

    net = QNet()
    tx = optax.adam(1e-4)
    params = net.init(jax.random.key(0), jnp.zeros((1, 4, 84, 84), jnp.uint8))
    target = params
    opt_state = tx.init(params)

    def step(params, target, opt_state, obs, action, reward, next_obs, terminated):
        next_q = net.apply(target, next_obs).max(axis=-1)
        y = reward + 0.99 * (1.0 - terminated) * next_q

        def loss_fn(p):
            q = jnp.take_along_axis(net.apply(p, obs), action[:, None], axis=-1)[:, 0]
            return optax.huber_loss(q, jax.lax.stop_gradient(y)).mean()

        loss, grads = jax.value_and_grad(loss_fn)(params)
        updates, opt_state = tx.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, loss

    args = [
        tuple(
            jnp.asarray(x) for x in (t.obs, t.action, t.reward, t.next_obs, t.terminated.astype(np.float32))
        )
        for t in (s.transition for s in samples)
    ]
    start = time.perf_counter()
    compiled = jax.jit(step).lower(params, target, opt_state, *args[0]).compile()
    compile_seconds = time.perf_counter() - start
    state = {"params": params, "opt": opt_state, "n": 0}

    def one():
        n = state["n"]
        state["params"], state["opt"], loss = compiled(
            state["params"], target, state["opt"], *args[n % len(args)]
        )
        state["n"] = n + 1
        loss.block_until_ready()

    return one, compile_seconds


def agentax_learn_step(num_actions: int, samples: list):
    """``(step, compile seconds)``: one update of ``dqn.make_learn`` with the nature preset's settings,
    jitted, per ``step()`` call, waited for."""
    import jax

    from agentax.agents import dqn, presets

    cfg = presets.preset("dqn", "nature").config
    state = dqn.init(jax.random.key(0), samples[0].transition.obs[0], num_actions, cfg)
    placed = [jax.device_put(s) for s in samples]
    start = time.perf_counter()
    compiled = jax.jit(dqn.make_learn(cfg)).lower(state, placed[0]).compile()
    compile_seconds = time.perf_counter() - start
    box = {"state": state, "n": 0}

    def one():
        n = box["n"]
        box["state"], metrics = compiled(box["state"], placed[n % len(placed)])
        box["n"] = n + 1
        jax.block_until_ready(box["state"])

    return one, compile_seconds


def interleaved_rates(steps: list, seconds: float, rounds: int = LEARN_ROUNDS) -> list[float]:
    """Calls/s of each of ``steps``, measured in turns (``rounds`` turns of ``seconds / rounds`` each),
    so that a change in the machine's load falls on all of them alike."""
    calls, elapsed = [0] * len(steps), [0.0] * len(steps)
    for turn in range(rounds):
        for i, step in enumerate(steps):
            n, t = _timed_loop(step, seconds / rounds, warmup=3 if turn == 0 else 0)
            calls[i] += n
            elapsed[i] += t
    return [n / t for n, t in zip(calls, elapsed, strict=True)]


# ---------------------------------------------------------------- the frame replay


def replay_rates(prioritized: bool) -> dict:
    """Add and sample rates of a FrameReplayBuffer at capacity 100k, bytes per transition."""
    from agentax.replay import Transition
    from agentax.replay.frames import FrameReplayBuffer

    rng = np.random.default_rng(1)
    buffer = FrameReplayBuffer(REPLAY_CAPACITY, NUM_ENVS, n_step=1, prioritized=prioritized, seed=0)
    batches = []
    for _ in range(16):
        obs = rng.integers(0, 256, (NUM_ENVS, 4, 84, 84), dtype=np.uint8)
        batches.append(
            Transition(
                obs=obs,
                action=rng.integers(0, 4, NUM_ENVS).astype(np.int32),
                reward=np.zeros(NUM_ENVS, np.float32),
                next_obs=np.concatenate(
                    [obs[:, 1:], rng.integers(0, 256, (NUM_ENVS, 1, 84, 84), np.uint8)], 1
                ),
                terminated=rng.random(NUM_ENVS) < 1 / 200,  # episodes (lives) of ~200 agent steps
                truncated=np.zeros(NUM_ENVS, bool),
                num_steps=np.ones(NUM_ENVS, np.int32),
            )
        )
    calls = REPLAY_FILL // NUM_ENVS
    start = time.perf_counter()
    for k in range(calls):
        buffer.add_batch(batches[k % len(batches)])
    add_rate = calls * NUM_ENVS / (time.perf_counter() - start)
    sample_calls, seconds = _timed_loop(lambda: buffer.sample(BATCH), SAMPLE_SECONDS)
    result = {
        "add": add_rate,
        "sample": sample_calls / seconds,
        "bytes": buffer.nbytes / REPLAY_CAPACITY,
        "size": buffer.size,
    }
    if prioritized:
        td = rng.normal(size=BATCH)

        def sample_and_update():
            sample = buffer.sample(BATCH, beta=0.4)
            buffer.update_priorities(sample.indices, td)

        update_calls, seconds = _timed_loop(sample_and_update, SAMPLE_SECONDS)
        result["sample_update"] = update_calls / seconds
    return result


# ---------------------------------------------------------------- DQN: SB3 against agentax train dqn

SB3_SCRIPT = """
import json, sys, time
start = time.perf_counter()
import torch
torch.set_num_threads(2)
import ale_py, gymnasium as gym
gym.register_envs(ale_py)
from stable_baselines3 import DQN
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_atari_env
from stable_baselines3.common.vec_env import VecFrameStack

total, warmup, learning_starts = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
# frameskip=1: SB3's AtariWrapper skips 4 frames (max of the last two); no sticky actions
env = VecFrameStack(make_atari_env("ALE/Breakout-v5", n_envs=1, seed=0,
                                   env_kwargs=dict(frameskip=1, repeat_action_probability=0.0)), n_stack=4)

class Clock(BaseCallback):
    marks = {}
    def _on_step(self):
        if self.num_timesteps in (learning_starts, warmup, total):
            self.marks[self.num_timesteps] = time.perf_counter()
        return True

# the nature preset's settings: Adam 1e-4, Huber, batch 32 every 4 agent steps, target every 1,000
# learning steps, epsilon 1 -> 0.01 over 1M agent steps (the same schedule as agentax's run)
model = DQN("CnnPolicy", env, learning_rate=1e-4, buffer_size=100_000, learning_starts=learning_starts,
            batch_size=32, gamma=0.99, train_freq=4, gradient_steps=1, target_update_interval=1_000,
            exploration_initial_eps=1.0, exploration_final_eps=0.01, exploration_fraction=1_000_000 / total,
            optimize_memory_usage=True, replay_buffer_kwargs=dict(handle_timeout_termination=False),
            seed=0, verbose=0, device="cpu")
ready = time.perf_counter()
model.learn(total_timesteps=total, callback=Clock())
end = time.perf_counter()
m = Clock.marks
print(json.dumps({"steps_per_second": (total - warmup) / (m[total] - m[warmup]),
                  "startup_seconds": ready - start, "to_warmup_seconds": m[warmup] - ready,
                  "total_seconds": end - start, "updates": int(model._n_updates),
                  "torch": torch.__version__, "threads": torch.get_num_threads()}))
"""


def bench_venv_python(
    venv: Path = BENCH_VENV, requirements: list[str] = BENCH_REQUIREMENTS, imports: str = BENCH_IMPORTS
) -> tuple[Path | None, str]:
    """``venv``'s python where ``imports`` run in it (by default ``.bench-venv`` with SB3, torch, ale-py
    and OpenCV), the venv created or extended with ``requirements`` here (other benches' packages
    stay), or None and why not."""
    python = venv / "bin" / "python"
    check = [str(python), "-c", imports]
    try:
        if python.exists() and subprocess.run(check, capture_output=True).returncode == 0:
            return python, ""
        if not python.exists():
            subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, capture_output=True)
        install = [str(python), "-m", "pip", "install", "-q", *requirements]
        if Path("/opt/wheels").is_dir():
            install += ["--find-links", "/opt/wheels"]
        done = subprocess.run(install, capture_output=True, text=True, timeout=900)
        if done.returncode != 0:
            return None, f"pip install {' '.join(requirements)} failed: {done.stderr.strip()[-300:]}"
        probe = subprocess.run(check, capture_output=True, text=True)
        if probe.returncode != 0:
            return None, f"`{imports}` failed: {probe.stderr.strip()[-300:]}"
        return python, ""
    except (subprocess.SubprocessError, OSError) as error:
        return None, f"could not make {venv.name}: {error}"


def sb3_dqn(python: Path) -> tuple[dict | None, str]:
    command = [str(python), "-c", SB3_SCRIPT, str(DQN_STEPS), str(DQN_WARMUP), str(DQN_LEARNING_STARTS)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=1_200)
    if done.returncode != 0:
        return None, f"SB3's Atari DQN failed: {done.stderr.strip()[-400:]}"
    return json.loads(done.stdout.strip().splitlines()[-1]), ""


def agentax_dqn(runner: str, cache: str) -> dict:
    """``agentax train dqn`` on Breakout as a subprocess; agent steps/s from its metrics.csv rows."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "run"
        command = [sys.executable, "-m", "agentax.cli", "train", "dqn", "--env", ENV_ID, "--preset", "nature"]
        command += ["--sticky-actions", "0", "--learning-starts", str(DQN_LEARNING_STARTS)]
        command += ["--buffer-size", "100000", "--num-envs", "1", "--train-frequency", "4"]
        command += ["--gradient-steps", "1", "--total-steps", str(DQN_STEPS), "--runner", runner]
        if runner == "parallel":
            command += ["--actors", "1"]
        command += ["--no-checkpoint-replay", "--out", str(out), "--no-progress"]
        env = {**os.environ, "AGENTAX_JAX_CACHE": cache}
        start = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=1_200)
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(command[2:])} failed: {done.stderr.strip()[-600:]}")
        total = time.perf_counter() - start
        with open(out / "metrics.csv") as f:
            rows = [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(f)]
        backend = json.loads((out / "config.json").read_text()).get("runner", {}).get("env_backend", "?")
    first = next(row for row in rows if row["env_steps"] >= DQN_WARMUP)
    last = rows[-1]
    return {
        "steps_per_second": (last["env_steps"] - first["env_steps"])
        / (last["wall_seconds"] - first["wall_seconds"]),
        "to_warmup_seconds": first["wall_seconds"],
        "total_seconds": total,
        "updates": last["updates"],
        "backend": backend,
    }


# ---------------------------------------------------------------- PPO and PQN


RUNNERS = {
    "host": "host runner",
    "parallel": "parallel runner (1 actor, policy lag 1)",
    "compiled": "compiled Atari runner (EnvPool inside the program, policy lag 0)",
    "compiled-lag1": "compiled Atari runner (policy lag 1: collection beside learning)",
    "ray": "Ray runner (1 actor process, policy lag 1)",
}
ON_POLICY = (("ppo", "atari"), ("pqn", "breakout-hour"), ("pqn", "breakout-15min"))
"""the on-policy agents' rows: (algorithm, preset) (PPO's 8 envs × 128 steps, PQN's 64 × 32, with 2
epochs × 16 minibatches in breakout-hour, 1 epoch × 32 in breakout-15min)"""


def on_policy_rate(algo: str, preset: str, runner: str) -> dict:
    """``algo``'s ``preset`` on ``runner`` (a key of ``RUNNERS``) for ``UPDATES + 1`` updates: agent
    steps/s after the first update (it compiles)."""
    from agentax.agents import algorithm, presets
    from agentax.agents.protocol import EnvSpec
    from agentax.api import agent_maker
    from agentax.envs import make_host_env
    from agentax.runners import compiled_pool, host
    from agentax.runners import parallel as parallel_runner
    from agentax.runners import ray as ray_runner

    module = algorithm(algo)
    cfg = presets.preset(algo, preset).config
    per_update = cfg.num_envs * cfg.num_steps
    cfg = dataclasses.replace(cfg, total_steps=per_update * (UPDATES + 1))
    env = make_host_env(ENV_ID, cfg.num_envs, sticky_actions=0.0)
    make_agent = agent_maker(module, EnvSpec.of(env), cfg)
    agent = make_agent()
    env.close()
    options = dict(log_every_steps=per_update, eval_episodes=1, sticky_actions=0.0)
    start = time.perf_counter()
    if runner == "parallel":
        config = parallel_runner.ParallelRunnerConfig(actors=1, policy_lag=1, **options)
        result = parallel_runner.train(agent, ENV_ID, config)
    elif runner == "ray":
        config = ray_runner.RayRunnerConfig(actors=1, policy_lag=1, **options)
        result = ray_runner.train(agent, ENV_ID, config, make_agent=make_agent)
    elif runner.startswith("compiled"):
        config = compiled_pool.Config(policy_lag=int(runner == "compiled-lag1"), **options)
        result = compiled_pool.train(agent, ENV_ID, config)
    else:
        result = host.train(agent, ENV_ID, host.HostRunnerConfig(**options))
    total = time.perf_counter() - start
    first, last = result.rows[0], result.rows[-1]
    return {
        "steps_per_second": (last["env_steps"] - first["env_steps"])
        / (last["wall_seconds"] - first["wall_seconds"]),
        "first_update_seconds": first["wall_seconds"],
        "total_seconds": total,
        "updates": len(result.rows),
        "steps_per_update": per_update,
        "masked_fraction": float(np.mean([row.get("masked_fraction", 0.0) for row in result.rows])),
    }


def on_policy_rows() -> tuple[list[list], dict[str, dict[str, dict]]]:
    """The PPO and PQN rows (host, parallel, compiled runner, one after the other in this process)
    and the runs' figures by "algorithm preset" and runner."""
    rows, runs = [], {}
    for algo, preset in ON_POLICY:
        runs[f"{algo} {preset}"] = {}
        for runner, label in RUNNERS.items():
            runs[f"{algo} {preset}"][runner] = result = on_policy_rate(algo, preset, runner)
            ratio = result["steps_per_second"] / runs["ppo atari"]["host"]["steps_per_second"]
            rows.append(
                [
                    f"{algo.upper()} {preset} preset on Breakout",
                    label,
                    result["steps_per_second"],
                    "agent steps/s",
                    ratio,
                    round(result["first_update_seconds"], 1),
                    None,
                ]
            )
    return rows, runs


def on_policy_rows_in_a_fresh_process() -> tuple[list[list], dict[str, dict[str, dict]]]:
    """:func:`on_policy_rows` in a new process, as ``agentax train`` runs them: this one's jax client
    was made on one CPU for the learning-step rows, and on it XLA runs one program at a time, so the
    parallel runner and the compiled one at policy lag 1 could not overlap collection and learning."""
    command = [sys.executable, str(Path(__file__).resolve()), "on-policy", "--json"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=1_800)
    if done.returncode != 0:
        raise RuntimeError(f"the on-policy rows failed:\n{done.stderr[-2000:]}")
    table, runs = json.loads(done.stdout.strip().splitlines()[-1])
    return table, runs


# ---------------------------------------------------------------- the section


def run() -> dict:
    from _pin import pinned_to_one_cpu  # benchmarks/_pin.py: run.py puts this folder on sys.path

    headers = [
        "what",
        "implementation",
        "rate",
        "unit",
        "÷ reference",
        "compile / warm-up s",
        "bytes / transition",
    ]
    rows: list[list] = []
    notes_extra: list[str] = []
    load_before = _load()

    envs = env_rates()
    reference = envs[0][1] if envs and envs[0][0].startswith("EnvPool") else None
    for name, rate in envs:
        ratio = rate / reference if reference else None
        rows.append(["8 Breakout envs, random actions", name, rate, "agent steps/s", ratio, None, None])

    import jax

    from agentax.agents import dqn

    samples = [_batch(4, seed) for seed in range(4)]
    with pinned_to_one_cpu():
        bare_step, bare_compile = bare_learn_step(4, samples)
        ours_step, ours_compile = agentax_learn_step(4, samples)
        bare, ours = interleaved_rates([bare_step, ours_step], LEARN_SECONDS)
    step = "Nature-CNN DQN learning step, batch 32"
    rows.append(
        [step, "bare JAX (flax + optax, jitted)", bare, "updates/s", 1.0, round(bare_compile, 2), None]
    )
    rows.append(
        [
            step,
            "agentax `dqn.make_learn` (nature), jitted",
            ours,
            "updates/s",
            ours / bare,
            round(ours_compile, 2),
            None,
        ]
    )
    del jax, dqn

    for prioritized in (False, True):
        kind = "prioritized" if prioritized else "uniform"
        replay = replay_rates(prioritized)
        what = f"`FrameReplayBuffer` 100k, {kind}"
        per = round(replay["bytes"], 1)
        rows.append([what, "add (8-env batches)", replay["add"], "transitions/s", None, None, per])
        rows.append([what, "sample (batch 32)", replay["sample"], "batches/s", None, None, per])
        if prioritized:
            rows.append(
                [what, "sample + update_priorities", replay["sample_update"], "batches/s", None, None, per]
            )

    python, why = bench_venv_python()
    sb3, sb3_why = sb3_dqn(python) if python is not None else (None, why)
    what = f"DQN on Breakout, {DQN_STEPS:,} agent steps"
    if sb3 is not None:
        rows.append(
            [
                what,
                "Stable-Baselines3 DQN (torch, 2 threads)",
                sb3["steps_per_second"],
                "agent steps/s",
                1.0,
                round(sb3["startup_seconds"] + sb3["to_warmup_seconds"], 1),
                None,
            ]
        )
    else:
        notes_extra.append(f"No SB3 row: {sb3_why}")
    dqn_runs = {}
    with tempfile.TemporaryDirectory() as cache:
        for runner in ("host", "parallel"):
            dqn_runs[runner] = result = agentax_dqn(runner, cache)
            label = (
                "`agentax train dqn --runner host`"
                if runner == "host"
                else "`agentax train dqn --runner parallel --actors 1`"
            )
            ratio = result["steps_per_second"] / sb3["steps_per_second"] if sb3 else None
            rows.append(
                [
                    what,
                    label,
                    result["steps_per_second"],
                    "agent steps/s",
                    ratio,
                    round(result["to_warmup_seconds"], 1),
                    None,
                ]
            )

    more_rows, on_policy_runs = on_policy_rows_in_a_fresh_process()
    rows += more_rows

    notes = _notes(sb3, dqn_runs, on_policy_runs, load_before, notes_extra)
    return {
        "name": "atari",
        "title": "Atari (Breakout): envs, DQN learning step, frame replay, DQN vs SB3, PPO and PQN",
        "headers": headers,
        "rows": rows,
        "notes": notes,
    }


def _notes(sb3, dqn_runs, on_policy_runs, load_before, extra) -> str:
    host_backend = dqn_runs["host"]["backend"]
    parts = [
        "All Breakout, **no sticky actions** (`repeat_action_probability` 0) everywhere; one **agent "
        "step** is 4 emulator frames (action repeated, max of the last two, 84×84 grayscale, 4 stacked), "
        "so frames/s = 4 × agent steps/s. `÷ reference` is each row's rate over the first row of its "
        "group, measured in this run: bare EnvPool, the bare JAX step, SB3's DQN, the host runner's PPO.",
        f"**Envs**: 8 envs, random actions drawn in advance, {ENV_SECONDS:g} s each after 3 warm-up "
        "steps. The bare EnvPool pool gets the settings agentax's EnvPool backend passes (episodic life, "
        "FIRE reset, up to 30 no-ops, `num_threads` = min(8, CPUs)); `AtariEnv` adds the adapter (env-id "
        "order, the same-step auto-reset: ended envs are stepped once more at once, reward clipping, "
        "score bookkeeping). The `ale` backend steps the 8 ale-py emulators one after another in this "
        "thread, resizing with OpenCV.",
        f"**Learning step**: one Adam step on a batch of 32 `uint8 [4, 84, 84]` stacks, 4 batches "
        f"cycled (device arrays), each call waited for; {LEARN_SECONDS:g} s each after compiling (compile "
        f"s apart), timed in {LEARN_ROUNDS} turns of agentax and the reference alternating, pinned to one "
        "CPU (`pinned_to_one_cpu`, as agentax's other benches). agentax: "
        "`jax.jit(dqn.make_learn(presets.preset('dqn', 'nature').config))` (Huber, no Double, 1-step, the "
        "target synced every 1,000 steps inside the step, no gradient clipping, metrics out); the reference: "
        "a flax Nature CNN (default init), the TD target from a target network's parameters passed in "
        "(its sync, a copy every 1,000 steps, left out), Huber, `optax.adam(1e-4)`.",
        f"**Frame replay**: `FrameReplayBuffer(100_000, 8, n_step=1)`, {REPLAY_FILL:,} transitions "
        "added in 8-env batches (random frames, episodes of ~200 steps), then batches of 32 sampled "
        f"for {SAMPLE_SECONDS:g} s each (stacks rebuilt from the frame rings); bytes / transition is "
        "`nbytes / capacity`, every array included (a buffer of stacked `obs` + `next_obs` would "
        "need 56,448).",
    ]
    dqn_part = (
        f"**DQN vs SB3**: {DQN_STEPS:,} agent steps each, 1 env, learning from step "
        f"{DQN_LEARNING_STARTS:,}, a learning step of batch 32 every 4 agent steps, replay 100k, Adam "
        "1e-4, target every 1,000 learning steps, ε 1 → 0.01 over 1M agent steps (so actions stay "
        "nearly random in so short a run; SB3 skips the network for a random action, and agentax's "
        "jitted act when every env explores). Agent steps/s are measured from step "
        f"{DQN_WARMUP:,} to the end "
        "(agentax: its metrics rows, one every 2,048 steps; SB3: a callback's clock), so start-up, the "
        "random steps and compiling fall outside; 'compile / warm-up s' is the seconds to step "
        f"{DQN_WARMUP:,} (agentax: from the start of training, compiling included; SB3: from process "
        "start). agentax: `agentax train dqn --env ALE/Breakout-v5 --preset nature --sticky-actions 0 "
        "--learning-starts 1000 --buffer-size 100000 --num-envs 1 --train-frequency 4 "
        f"--gradient-steps 1 --total-steps {DQN_STEPS} --runner host` and `--runner parallel "
        "--actors 1`, plus `--no-checkpoint-replay` (saving the replay at the end is no part of the "
        "rate), an empty compilation cache for the first run that the second reuses, env backend "
        f"{host_backend}."
    )
    if sb3 is not None:
        host_ratio = dqn_runs["host"]["steps_per_second"] / sb3["steps_per_second"]
        par_ratio = dqn_runs["parallel"]["steps_per_second"] / sb3["steps_per_second"]
        met = "met" if max(host_ratio, par_ratio) >= SB3_TARGET else "missed"
        dqn_part += (
            f" SB3 {_sb3_version()} (torch {sb3['torch']} on the CPU, {sb3['threads']} threads) in "
            "`.bench-venv`: `DQN('CnnPolicy', VecFrameStack(make_atari_env('ALE/Breakout-v5', "
            "env_kwargs=dict(frameskip=1, repeat_action_probability=0.0)), 4), ...)` (AtariWrapper: up "
            "to 30 no-ops, frame skip 4, a lost life ends an episode, FIRE reset, clipped rewards), "
            "`optimize_memory_usage=True`, its default `max_grad_norm` 10. The issue asks for ≥ "
            f"{SB3_TARGET} × SB3: host {host_ratio:.2f} ×, parallel {par_ratio:.2f} × ({met})."
        )
    parts.append(dqn_part)
    parts.append(_on_policy_notes(on_policy_runs))
    parts.append(f"Machine load at the start of this section: {load_before}; at its end: {_load()}.")
    parts += extra
    if QUICK:
        parts.append(
            "*Quick run (`AGENTAX_BENCH_QUICK=1`): shorter runs than `make bench` uses, one each, on a "
            "machine shared with other work at the time; treat these figures as a smoke test.*"
        )
    return "\n\n".join(parts)


def _on_policy_notes(runs: dict[str, dict[str, dict]]) -> str:
    masked = runs["ppo atari"].get("compiled", {}).get("masked_fraction", float("nan"))
    return (
        "**PPO and PQN**: PPO's `atari` preset (8 envs × 128 steps, 4 epochs × 4 minibatches, Nature "
        "CNN) and PQN's `breakout-hour` and `breakout-15min` presets (64 envs × 32 steps, 2 epochs × 16 "
        f"minibatches of 128; 1 epoch × 32 of 64; Nature CNN with LayerNorm), {UPDATES + 1} updates "
        "each through `host.train`, `parallel.train` (1 actor, policy lag 1), `compiled_atari.train` "
        "(policy lag 0: one jitted call per update, the "
        "rollout with EnvPool's XLA step inside a `lax.scan`, then the learning step; policy lag 1: "
        "the rollout and the learning step as two programs, rollout k+1 in a thread beside the "
        "learning on rollout k) and `ray.train` (a local Ray, "
        "1 actor process, policy lag 1; its start-up counts in the first update) from this process, "
        "one after the other, EnvPool, a metrics row per update; agent steps/s from the first row "
        "(its update compiles; 'compile / warm-up s' is the seconds to it) to the last; `÷ reference` "
        "is over the host runner's PPO. The compiled runner counts EnvPool's reset steps (the step "
        "after each lost life or game, masked out of learning) as agent steps: "
        f"{masked:.1%} of PPO's steps here. What overlaps: in the parallel and Ray runners the actor (a "
        "thread; a process) steps the envs and acts with the policy of one update before while the "
        "learner learns (policy lag 1), so collection runs beside learning on the other core, as in "
        "the compiled runner at policy lag 1; the host runner and the compiled one at lag 0 collect, "
        "then learn. Convolutions: "
        f"`AGENTAX_CONV` {kernels_backend()}."
    )


def kernels_backend() -> str:
    from agentax import kernel_choice

    return f"{kernel_choice.mode()} → {kernel_choice.backend()}"


def _sb3_version() -> str:
    python = BENCH_VENV / "bin" / "python"
    done = subprocess.run(
        [str(python), "-c", "import stable_baselines3; print(stable_baselines3.__version__)"],
        capture_output=True,
        text=True,
    )
    return done.stdout.strip() or "?"


if __name__ == "__main__":
    if sys.argv[1:] not in (["on-policy"], ["on-policy", "--json"]):
        sys.exit(
            "usage: python benchmarks/bench_atari.py on-policy [--json]  (all of it: benchmarks/run.py atari)"
        )
    table, figures = on_policy_rows()
    if sys.argv[2:] == ["--json"]:
        print(json.dumps([table, figures]))
        sys.exit(0)
    for what, runner, rate, _, ratio, first, _ in table:
        print(f"{what:<36} {runner:<52} {rate:8.1f} agent steps/s  x{ratio:.2f}  first update {first} s")
    print(_on_policy_notes(figures))
    print(_load())
