"""The host loop: PPO on Gymnasium-only envs (MountainCar, Acrobot, Pendulum, ...).

Gymnasium steps the envs on the host (a ``SAME_STEP``-autoreset vector env through
:class:`agentax.envs.gym.GymnasiumEnv`, so ``obs`` / ``final_obs`` split as in the JAX envs); the
agent is the same pure PPO as on the compiled runner — ``ppo.act`` jitted once per step for the
whole batch of envs, ``ppo.learn`` jitted once per iteration. One seed per process.

Checkpoints hold the agent (parameters, optimizer state, counters) and the key; a resumed run
restarts its envs (seeded by the iteration number), since a Gymnasium env's state cannot be saved.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import jax
import numpy as np

from agentax.agents import ppo
from agentax.errors import UsageError
from agentax.policies import Policy
from agentax.runs import Run, latest_checkpoint, load_tree, run_config


@dataclass(frozen=True)
class HostRunnerConfig:
    """How the host loop schedules one training; saved in config.json under "runner"."""

    seed: int = 0
    """seed of the agent and of the envs"""
    log_every_updates: int = 5
    """log a row (and checkpoint) every this many iterations"""
    eval_episodes: int = 10
    """episodes of the final evaluation (and of the stop-at-return checks)"""
    stop_at_return: float | None = None
    """stop once an evaluation (run at each log) reaches this mean return (None: train to the end)"""


@dataclass
class HostResult:
    agent: ppo.PPOAgent
    updates: int
    env_steps: int
    eval: dict[str, Any]
    rows: list[dict[str, float]]


def _make_env(env_id: str, num_envs: int):
    from agentax.envs.gym import GymnasiumEnv

    return GymnasiumEnv(env_id, num_envs)


def _agent_target(spec: ppo.Spec, cfg: ppo.PPOConfig):
    return jax.eval_shape(lambda key: (ppo.init(key, spec, cfg), key), jax.random.key(0))


def train_ppo(
    env_id: str,
    cfg: ppo.PPOConfig,
    runner: HostRunnerConfig,
    run: Run | None = None,
    *,
    resume: bool = False,
    progress: bool = False,
) -> HostResult:
    """Train PPO on the Gymnasium env ``env_id``; log, checkpoint and evaluate into ``run`` if given."""
    from agentax.evaluate import EvalStats, host_episode_returns

    cfg.validate()
    env = _make_env(env_id, cfg.num_envs)
    spec = ppo.Spec(tuple(env.observation_space().shape), env.action_space())
    act = jax.jit(partial(ppo.act, spec=spec, cfg=cfg))
    learn = jax.jit(partial(ppo.learn, spec=spec, cfg=cfg))
    updates, env_steps = 0, 0
    if resume:
        (agent, key), meta = load_tree(latest_checkpoint(run.path), _agent_target(spec, cfg))
        updates, env_steps = int(meta["updates"]), int(meta["env_steps"])
        run.truncate_metrics(env_steps)
    else:
        key = jax.random.key(runner.seed)
        key, init_key = jax.random.split(key)
        agent = ppo.init(init_key, spec, cfg)
    obs = env.reset(seed=runner.seed + 1000 * updates)
    episode_return = np.zeros(cfg.num_envs)
    finished: list[float] = []
    rows: list[dict[str, float]] = []
    start = time.perf_counter()
    steps_at_log, time_at_log = env_steps, start
    try:
        while updates < cfg.num_updates:
            columns = {
                name: [] for name in ("obs", "action", "log_prob", "value", "reward", "terminated", "done")
            }
            final_obs = []
            for _ in range(cfg.num_steps):
                key, act_key = jax.random.split(key)
                action, action_log_prob, value = jax.device_get(act(agent.params, obs, act_key))
                ts = env.step(np.asarray(ppo.env_action(action, spec)))
                for name, value_t in (
                    ("obs", obs),
                    ("action", action),
                    ("log_prob", action_log_prob),
                    ("value", value),
                    ("reward", ts.reward),
                    ("terminated", ts.terminated),
                    ("done", ts.done),
                ):
                    columns[name].append(np.asarray(value_t))
                final_obs.append(np.asarray(ts.final_obs))
                episode_return += ts.reward
                for i in np.flatnonzero(ts.done):
                    finished.append(float(episode_return[i]))
                    episode_return[i] = 0.0
                obs = ts.obs
            rollout = ppo.Rollout(
                **{k: np.stack(v) for k, v in columns.items()}, final_obs=np.stack(final_obs)
            )
            key, learn_key = jax.random.split(key)
            agent, metrics = learn(agent, rollout, learn_key)
            updates += 1
            env_steps += cfg.steps_per_update
            if updates % runner.log_every_updates and updates < cfg.num_updates:
                continue
            mean_return = float(np.mean(finished)) if finished else math.nan
            finished.clear()
            eval_mean = math.nan
            if runner.stop_at_return is not None:
                returns, _ = host_episode_returns(
                    env_for_eval(env_id),
                    ppo.greedy_policy(agent.params, spec, cfg),
                    runner.eval_episodes,
                    seed=10_000 + updates,
                )
                eval_mean = float(np.mean(returns))
            now = time.perf_counter()
            row = {
                "env_steps": env_steps,
                "updates": updates,
                "mean_return": mean_return,
                "return_seed0": mean_return,
                "eval_return": eval_mean,
                "steps_per_second": (env_steps - steps_at_log) / max(now - time_at_log, 1e-9),
                "wall_seconds": now - start,
                **{name: float(value) for name, value in jax.device_get(metrics).items()},
            }
            steps_at_log, time_at_log = env_steps, now
            rows.append(row)
            if progress:
                print(
                    f"{env_steps:>9,} env steps  {row['steps_per_second']:>7,.0f} steps/s  "
                    f"return {mean_return:.1f}",
                    file=sys.stderr,
                )
            if run is not None:
                run.log(row)
                run.save_checkpoint(updates, (agent, key), {"updates": updates, "env_steps": env_steps})
            if runner.stop_at_return is not None and eval_mean >= runner.stop_at_return:
                break
    finally:
        env.close()
    returns, lengths = host_episode_returns(
        env_for_eval(env_id),
        ppo.greedy_policy(agent.params, spec, cfg),
        runner.eval_episodes,
        seed=runner.seed + 123_457,
    )
    if run is not None:
        evaluation = run.write_eval(np.asarray(returns)[None], np.asarray(lengths)[None], env_steps=env_steps)
        run.plot()
        run.close()
    else:
        evaluation = vars(EvalStats.from_returns(returns, lengths))
    return HostResult(agent, updates, env_steps, evaluation, rows)


def env_for_eval(env_id: str):
    """A fresh one-env copy for evaluation (the training envs keep their episodes)."""
    return _make_env(env_id, 1)


def restore_host_policy(run_dir: Path, config: dict[str, Any], cfg: ppo.PPOConfig) -> Policy:
    """The greedy policy of a host-loop PPO run's newest checkpoint."""
    env = _make_env(config["env"], 1)
    spec = ppo.Spec(tuple(env.observation_space().shape), env.action_space())
    env.close()
    (agent, _), _ = load_tree(latest_checkpoint(run_dir), _agent_target(spec, cfg))
    return ppo.greedy_policy(agent.params, spec, cfg)


def train_cli(algo: str, module: Any, run_args: Any, cfg: ppo.PPOConfig, preset: Any, out: Path) -> int:
    """``agentax train ppo --env <Gymnasium id>``: create the run folder and train on the host."""
    from agentax.cli.train import parse_stop, report

    if run_args.seeds != 1:
        raise UsageError(f"{run_args.env} steps on the host: train one seed per process (--seeds 1)")
    env = _make_env(run_args.env, 1)
    solved = env.vector_env.spec.reward_threshold if env.vector_env.spec is not None else None
    env.close()
    stop = parse_stop(run_args.stop_at_return, preset, _Threshold(solved))
    runner = HostRunnerConfig(seed=run_args.seed, eval_episodes=preset.eval_episodes, stop_at_return=stop)
    config = run_config(algo, run_args.env, run_args.preset, "host", runner, module.config_to_dict(cfg))
    run = Run.create(out, config)
    print(f"training {algo} on {run_args.env} (host loop) into {out}", file=sys.stderr)
    start = time.perf_counter()
    result = train_ppo(run_args.env, cfg, runner, run, progress=run_args.progress)
    report(result.eval, out, time.perf_counter() - start)
    return 0


def resume_cli(module: Any, run: Run, cfg: ppo.PPOConfig, progress: bool) -> int:
    from agentax.cli.train import report

    runner = HostRunnerConfig(**run.config["runner"])
    start = time.perf_counter()
    result = train_ppo(run.config["env"], cfg, runner, run, resume=True, progress=progress)
    report(result.eval, run.path, time.perf_counter() - start)
    return 0


@dataclass(frozen=True)
class _Threshold:
    reward_threshold: float | None
