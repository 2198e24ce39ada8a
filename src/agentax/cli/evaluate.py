"""``agentax evaluate``: returns of a policy over N episodes, as a table or one JSON object.

Atari games are played whole (every life, raw rewards: the true score) in EnvPool's or ale-py's
envs, up to 16 side by side, with the trained run's env settings (backend, sticky actions) unless
the options override them.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tyro
from rich.console import Console
from rich.table import Table

from agentax.cli.policies import _make as make_env
from agentax.cli.policies import env_description, resolve_policy
from agentax.envs import AtariEnv
from agentax.errors import UsageError
from agentax.evaluate import EvalStats, check_policy_fits, evaluate, host_episode_returns
from agentax.export import is_exported
from agentax.policies import Policy


@dataclass(frozen=True)
class EvaluateArgs:
    """Evaluate a policy over N episodes: mean, std, min and max of the episode returns."""

    env: str | None = None
    """environment id (agentax envs lists them); optional when --policy is a trained run's folder"""
    policy: str = "basic"
    """basic (the lecture's CartPole policy), random, a trained run's folder, or a file written by
    agentax export (.onnx through onnxruntime, .stablehlo through jax.export; --env defaults to its card's)"""
    episodes: int = 100
    """number of episodes (Atari: whole games, their true scores)"""
    seed: int = 0
    """random seed of the episodes and of the policy"""
    json: bool = False
    """print one JSON object instead of a table"""
    env_backend: str | None = None
    """Atari: envpool, ale or auto (default: the run's, else auto)"""
    sticky_actions: float | None = None
    """Atari: probability that the emulator repeats the last action (default: the run's, else 0.25)"""


def policy_label(policy: str) -> str:
    """How a policy argument is named in output: a run folder by its name."""
    return Path(policy).name if Path(policy).is_dir() else policy


def stats_table(
    env_id: str, policy: str, stats: EvalStats, seed: int, seconds: float, settings: str = ""
) -> Table:
    table = Table(
        title=f"{policy} policy on {env_id}" + (f" ({settings})" if settings else ""),
        caption=f"{stats.episodes} episodes, seed {seed}, {seconds:.2f} s",
    )
    for column in ("mean return", "std", "min", "max", "mean length"):
        table.add_column(column, justify="right")
    table.add_row(
        f"{stats.mean_return:.2f}",
        f"{stats.std_return:.2f}",
        f"{stats.min_return:g}",
        f"{stats.max_return:g}",
        f"{stats.mean_length:.1f}",
    )
    return table


def exported_policy(
    path: str,
    env_id: str | None,
    num_envs: int = 1,
    *,
    env_backend: str | None = None,
    sticky_actions: float | None = None,
) -> tuple[str, Any, Policy]:
    """``(env_id, env, policy)`` for a file of ``agentax export``, as :func:`resolve_policy` gives them
    for a run's folder: the env from ``env_id``, else the model card's (with its Atari settings)."""
    from agentax.export import as_policy, load

    exported = load(path)
    env_id = env_id or exported.card["env"]
    env = make_env(env_id, num_envs, env_backend, sticky_actions, exported.card.get("env_settings", {}))
    policy = as_policy(exported)
    check_policy_fits(env, policy, env_id)
    return env_id, env, policy


def main(argv: list[str]) -> int:
    args = tyro.cli(EvaluateArgs, args=argv, prog="agentax evaluate")
    if args.episodes <= 0:
        raise UsageError(f"--episodes must be at least 1, not {args.episodes}")
    resolve = exported_policy if is_exported(args.policy) else resolve_policy
    env_id, env, policy = resolve(
        args.policy,
        args.env,
        num_envs=min(args.episodes, 16),
        env_backend=args.env_backend,
        sticky_actions=args.sticky_actions,
    )
    start = time.perf_counter()
    if isinstance(env, AtariEnv):  # whole games side by side in the evaluation view
        try:
            stats = EvalStats.from_returns(*host_episode_returns(env, policy, args.episodes, args.seed))
        finally:
            env.close()
    else:
        stats = evaluate(env, policy, args.episodes, args.seed)
    seconds = time.perf_counter() - start
    label = policy_label(args.policy)
    if args.json:
        atari = (
            {"env_backend": env.backend_name, "sticky_actions": env.sticky_actions}
            if isinstance(env, AtariEnv)
            else {}
        )
        print(json.dumps({"env": env_id, "policy": label, "seed": args.seed, **atari, **vars(stats)}))
    else:
        Console().print(stats_table(env_id, label, stats, args.seed, seconds, env_description(env)))
    return 0
