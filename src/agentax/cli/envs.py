"""``agentax envs``: the environments, with their observation and action spaces."""

from __future__ import annotations

import json
from dataclasses import dataclass

import tyro
from rich.console import Console
from rich.table import Table

from agentax.envs import JAX_ENVS, make
from agentax.envs.gym import GYMNASIUM_SELECTION, NAMESPACE, GymnasiumEnv


@dataclass(frozen=True)
class EnvsArgs:
    """List agentax's JAX environments and a selection of Gymnasium's (any Gymnasium id works)."""

    json: bool = False
    """print one JSON list instead of a table"""


def env_rows() -> list[dict[str, str]]:
    """One row per env: id, kind (JAX or Gymnasium, stepped on the host), observation and action spaces."""
    rows = []
    for env_id in JAX_ENVS:
        env = make(env_id)
        rows.append(
            {
                "id": env_id,
                "kind": "JAX",
                "observation_space": str(getattr(env, "original_space", None) or env.observation_space()),
                "action_space": str(env.action_space()),
            }
        )
    for env_id in GYMNASIUM_SELECTION:
        env = GymnasiumEnv(env_id)
        rows.append(
            {
                "id": env_id,
                "kind": "Gymnasium",
                "observation_space": str(getattr(env, "original_space", None) or env.observation_space()),
                "action_space": str(env.action_space()),
            }
        )
        env.close()
    return rows


def main(argv: list[str]) -> int:
    args = tyro.cli(EnvsArgs, args=argv, prog="agentax envs")
    rows = env_rows()
    if args.json:
        print(json.dumps(rows))
        return 0
    table = Table(
        title="environments",
        caption=f"JAX envs also run in Gymnasium as {NAMESPACE}/ID; any other Gymnasium id works too",
    )
    for column in ("id", "kind", "observation space", "action space"):
        table.add_column(column)
    for row in rows:
        table.add_row(row["id"], row["kind"], row["observation_space"], row["action_space"])
    Console().print(table)
    return 0
