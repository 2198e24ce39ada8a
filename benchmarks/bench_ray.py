"""Ray actors against thread actors, and what Ray costs per batch and per parameter publish.

Rows, all measured in this run, with one local Ray (as many CPUs as the machine has) started once:

- **runs**: the parallel runner's DQN workload and PPO ``cartpole-fast`` (``bench_parallel``'s
  settings, 2 actors, policy lag 1) with thread actors (``--runner parallel``) and Ray actors
  (``--runner ray``), one after the other, after a warm-up run of each (compiled programs cached):
  training seconds (to the last metrics row), actor env steps/s and learner updates/s (the rows'
  means, the first row left out);
- **per collected batch**: the round trip of a Ray actor call returning a NumPy batch, against a
  thread handing the same batch over a queue; batch sizes of a CartPole rollout (one actor's
  ``[32, 4]`` transitions) and of an Atari one (``[128, 4]`` transitions of ``uint8 [4, 84, 84]``
  observations, ``obs`` and ``next_obs``: 27.6 MiB);
- **per parameter publish**: ``ray.put`` of the acting view (``acting_view``: parameters, no
  optimizer state) of PPO's CartPole MLP and of PPO's Nature CNN, and an actor's fetch of it
  (``ray.get`` + ``jax.device_put``), with the bytes published;
- **an Atari actor**: one Ray actor process collecting PPO ``atari`` rollouts on Breakout.

The notes project these to 8, 64 and 512 actors on several machines.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
import queue
import statistics
import threading
import time

import bench_parallel as bp
import numpy as np

QUICK = bp.QUICK
REPEATS = 20 if QUICK else 50  # round trips per batch size and publishes per state


def _rows_mean(rows: list[dict], name: str) -> float:
    return bp._mean_of(rows[1:] or rows, name)


def runs(ray) -> tuple[list[list], dict]:
    """Thread actors and Ray actors on the same two workloads."""
    from agentax.agents import dqn, ppo, presets
    from agentax.runners import parallel
    from agentax.runners import ray as ray_runner

    spec = _cartpole_spec()
    workloads = {
        "DQN (bench_parallel workload)": (
            dqn,
            dataclasses.replace(
                presets.preset("dqn", "default").config, total_steps=bp.DQN_STEPS, **bp.DQN_WORKLOAD
            ),
        ),
        "PPO cartpole-fast": (
            ppo,
            dataclasses.replace(presets.preset("ppo", "cartpole-fast").config, total_steps=bp.PPO_STEPS),
        ),
    }
    table, figures = [], {}
    for label, (module, cfg) in workloads.items():
        agent = module.make_agent(spec, cfg)
        small = dataclasses.replace(agent, total_steps=2_048)
        remake = functools.partial(module.make_agent, spec, cfg)  # pickled by reference
        threads_cfg = parallel.ParallelRunnerConfig(actors=2, policy_lag=1)
        ray_cfg = ray_runner.RayRunnerConfig(actors=2, policy_lag=1)
        parallel.train(small, bp.ENV_ID, threads_cfg)  # warm-ups: compile, start
        ray_runner.train(small, bp.ENV_ID, ray_cfg, make_agent=remake)
        in_threads = parallel.train(agent, bp.ENV_ID, threads_cfg)
        on_ray = ray_runner.train(agent, bp.ENV_ID, ray_cfg, make_agent=remake)
        for runner, result in (("threads", in_threads), ("ray", on_ray)):
            seconds = bp.run_seconds(result)
            row = [
                label,
                runner,
                round(seconds, 2),
                round(_rows_mean(result.rows, "actor_steps_per_second")),
                round(_rows_mean(result.rows, "learner_updates_per_second"), 1),
            ]
            table.append(row)
            figures[f"{label} {runner}"] = seconds
        figures[f"{label} ray/threads"] = figures[f"{label} ray"] / figures[f"{label} threads"]
        table[-1].append(round(figures[f"{label} ray/threads"], 2))
        table[-2].append(1.0)
    return table, figures


def _cartpole_spec():
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_host_env

    env = make_host_env(bp.ENV_ID, 1)
    spec = EnvSpec.of(env)
    env.close()
    return spec


class Echo:
    """A Ray actor that hands back a batch it already holds (the cost of the hand-over alone)."""

    def __init__(self):
        self.batches = {}

    def make(self, name: str, shape: tuple, dtype: str) -> int:
        self.batches[name] = np.ones(shape, dtype)
        return self.batches[name].nbytes

    def batch(self, name: str):
        return self.batches[name]

    def fetch(self, published: list) -> float:
        import jax
        import ray

        start = time.perf_counter()
        jax.block_until_ready(jax.device_put(ray.get(published[0])))
        return time.perf_counter() - start


BATCHES = {
    # a CartPole rollout of one actor: [32, 4] transitions of float32 [4] obs and next_obs, action, ...
    "CartPole rollout [32, 4]": ((32, 4, 2 * 4 + 4), "float32"),
    # an Atari rollout of one actor: [128, 4] transitions of uint8 [4, 84, 84] obs and next_obs
    "Atari rollout [128, 4]": ((128, 4, 2, 4, 84, 84), "uint8"),
    # the same with each frame sent once (train.ray.PackedFrames: the new frames, 8 whole stacks)
    "Atari rollout [128, 4], frames once": ((128 * 4 + 16, 84, 84), "uint8"),
}


def batch_rows(ray) -> tuple[list[list], dict]:
    echo = ray.remote(Echo).remote()
    table, figures = [], {}
    for name, (shape, dtype) in BATCHES.items():
        size = ray.get(echo.make.remote(name, shape, dtype))
        for _ in range(3):
            ray.get(echo.batch.remote(name))
        remote = []
        for _ in range(REPEATS):
            start = time.perf_counter()
            ray.get(echo.batch.remote(name))
            remote.append(time.perf_counter() - start)
        local = _queue_hand_over(np.ones(shape, dtype))
        table.append([f"batch: {name}", f"{size / 2**20:.2f} MB", _ms(remote), _ms(local)])
        figures[name] = {"bytes": size, "ray_ms": _ms(remote), "thread_ms": _ms(local)}
    ray.kill(echo)
    return table, figures


def _queue_hand_over(batch: np.ndarray) -> list[float]:
    """A thread puts ``batch`` into a queue of size one, the caller takes it (as the thread actors)."""
    handed, seconds = queue.Queue(maxsize=1), []
    for _ in range(REPEATS):
        start = time.perf_counter()
        threading.Thread(target=handed.put, args=(batch,)).start()
        handed.get()
        seconds.append(time.perf_counter() - start)
    return seconds


def _ms(seconds: list[float]) -> float:
    return round(1000 * statistics.median(seconds), 3)


def publish_rows(ray) -> tuple[list[list], dict]:
    import jax

    from agentax.agents import ppo, presets
    from agentax.agents.protocol import EnvSpec, acting_view
    from agentax.envs.core import Discrete

    specs = {
        "PPO CartPole MLP 64-64": (_cartpole_spec(), presets.preset("ppo", "cartpole-fast").config),
        "PPO Nature CNN (Atari)": (
            EnvSpec((4, 84, 84), Discrete(4), np.dtype("uint8")),
            presets.preset("ppo", "atari").config,
        ),
    }
    echo = ray.remote(Echo).remote()
    table, figures = [], {}
    for name, (spec, cfg) in specs.items():
        state = ppo.make_agent(spec, cfg).init(jax.random.key(0))
        view = jax.device_get(acting_view(state))
        size = sum(x.nbytes for x in jax.tree.leaves(view))
        full = sum(np.asarray(x).nbytes for x in jax.tree.leaves(state))
        puts, fetches = [], []
        for _ in range(REPEATS):
            start = time.perf_counter()
            ref = ray.put(jax.device_get(acting_view(state)))
            puts.append(time.perf_counter() - start)
            fetches.append(ray.get(echo.fetch.remote([ref])))
        table.append(
            [f"publish: {name}", f"{size / 2**20:.2f} MB (state {full / 2**20:.2f})", _ms(puts), _ms(fetches)]
        )
        figures[name] = {"bytes": size, "state_bytes": full, "put_ms": _ms(puts), "fetch_ms": _ms(fetches)}
    ray.kill(echo)
    return table, figures


def atari_actor_row(ray) -> tuple[list, dict]:
    """One Ray actor process collecting PPO ``atari`` rollouts on Breakout (4 envs, 128 steps): its
    agent steps/s (the second rollout; the first compiles) and the bytes of its batch."""
    import jax

    from agentax.agents import ppo, presets
    from agentax.agents.protocol import EnvSpec, acting_view
    from agentax.envs.core import Discrete
    from agentax.runners.ray import Collector, RayRunnerConfig

    spec = EnvSpec((4, 84, 84), Discrete(4), np.dtype("uint8"))
    cfg = dataclasses.replace(presets.preset("ppo", "atari").config, num_envs=4)
    make_agent = functools.partial(ppo.make_agent, spec, cfg)
    key = np.asarray(jax.random.key_data(jax.random.key(0)))
    actor = ray.remote(Collector).remote(make_agent, "ALE/Breakout-v5", RayRunnerConfig(), 4, 0, key)
    published = [(0, ray.put(jax.device_get(acting_view(make_agent().init(jax.random.key(0))))))]
    ray.get(actor.rollout.remote(published, cfg.num_steps))
    start = time.perf_counter()
    packed, _, steps = ray.get(actor.rollout.remote(published, cfg.num_steps))
    seconds = time.perf_counter() - start
    ray.kill(actor)
    size = sum(x.nbytes for x in (packed.new_frames, packed.fresh_stacks, packed.end_stacks))
    size += sum(np.asarray(x).nbytes for x in jax.tree.leaves(packed.rest))
    rate = steps / seconds
    row = ["Atari actor: PPO atari on Breakout, 4 envs × 128 steps", f"{size / 2**20:.1f} MB a batch sent"]
    return [*row, "", round(rate), "", "", "", ""], {"steps_per_second": rate, "batch_bytes": size}


def run() -> dict:
    import ray

    ray.init(
        num_cpus=os.cpu_count(), include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False
    )
    try:
        run_table, run_figures = runs(ray)
        batch_table, batch_figures = batch_rows(ray)
        publish_table, publish_figures = publish_rows(ray)
        atari_row, atari_figures = atari_actor_row(ray)
    finally:
        ray.shutdown()
    rows = [[r[0], r[1], r[2], r[3], r[4], "", "", r[5]] for r in run_table]
    rows += [[r[0], r[1], "", "", "", r[2], r[3], ""] for r in batch_table + publish_table]
    rows.append(atari_row)
    return {
        "name": "ray",
        "title": "Ray actors against thread actors; Ray's cost per batch and per publish",
        "headers": [
            "what",
            "runner or size",
            "training s",
            "actor steps/s",
            "learner updates/s",
            "Ray ms (round trip or put)",
            "thread queue ms or actor fetch ms",
            "ray / threads",
        ],
        "rows": rows,
        "notes": _notes(run_figures, batch_figures, publish_figures, atari_figures),
        "figures": {
            "runs": run_figures,
            "batches": batch_figures,
            "publishes": publish_figures,
            "atari_actor": atari_figures,
        },
    }


def _notes(runs: dict, batches: dict, publishes: dict, atari: dict) -> str:
    batch = batches["Atari rollout [128, 4]"]
    cnn = publishes["PPO Nature CNN (Atari)"]
    return (
        f"{'Quick runs (AGENTAX_BENCH_QUICK=1). ' if QUICK else ''}"
        "Runs: 2 actors, one local Ray with as many CPUs as the machine has, thread and Ray runs one "
        "after the other after a warm-up of each; training seconds to the last metrics row; actor "
        "steps/s and learner updates/s are the rows' means without the first. Batch rows: the median "
        f"of {REPEATS} round trips of a Ray actor call returning a batch it holds, against a thread "
        "handing the same batch over a queue of size one. Publish rows: the median of "
        f"{REPEATS} `ray.put` calls of the acting view and of an actor's `ray.get` + `jax.device_put`. "
        f"An Atari rollout batch ({batch['bytes'] / 2**20:.1f} MB) costs {batch['ray_ms']:.1f} ms a "
        f"round trip; a Nature-CNN publish ({cnn['bytes'] / 2**20:.1f} MB) costs {cnn['put_ms']:.1f} ms "
        f"to put and {cnn['fetch_ms']:.1f} ms to fetch per actor process. One Ray actor process "
        f"collecting PPO Breakout rollouts (4 envs, the CNN policy on the CPU) makes "
        f"{atari['steps_per_second']:.0f} agent steps/s and sends a {atari['batch_bytes'] / 2**20:.1f} MB "
        "batch every 512 steps (each frame once). MB here are MiB."
    )
