"""``agentax evaluate``: returns of a policy over N episodes, as a table or one JSON object."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import tyro
from rich.console import Console
from rich.table import Table

from agentax.cli.policies import resolve_policy
from agentax.errors import UsageError
from agentax.evaluate import EvalStats, evaluate


@dataclass(frozen=True)
class EvaluateArgs:
    """Evaluate a policy over N episodes: mean, std, min and max of the episode returns."""

    env: str | None = None
    """environment id (agentax envs lists them); optional when --policy is a trained run's folder"""
    policy: str = "basic"
    """basic (the lecture's CartPole policy), random, or a trained run's folder"""
    episodes: int = 100
    """number of episodes"""
    seed: int = 0
    """random seed of the episodes and of the policy"""
    json: bool = False
    """print one JSON object instead of a table"""


def policy_label(policy: str) -> str:
    """How a policy argument is named in output: a run folder by its name."""
    return Path(policy).name if Path(policy).is_dir() else policy


def stats_table(env_id: str, policy: str, stats: EvalStats, seed: int, seconds: float) -> Table:
    table = Table(
        title=f"{policy} policy on {env_id}",
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


def main(argv: list[str]) -> int:
    args = tyro.cli(EvaluateArgs, args=argv, prog="agentax evaluate")
    if args.episodes <= 0:
        raise UsageError(f"--episodes must be at least 1, not {args.episodes}")
    env_id, env, policy = resolve_policy(args.policy, args.env, num_envs=min(args.episodes, 16))
    start = time.perf_counter()
    stats = evaluate(env, policy, args.episodes, args.seed)
    seconds = time.perf_counter() - start
    label = policy_label(args.policy)
    if args.json:
        print(json.dumps({"env": env_id, "policy": label, "seed": args.seed, **vars(stats)}))
    else:
        Console().print(stats_table(env_id, label, stats, args.seed, seconds))
    return 0
