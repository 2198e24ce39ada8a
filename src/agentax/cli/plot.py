"""``agentax plot DIR [DIR ...] --out curves.png``: overlay the learning curves of run folders.

Each run draws its training episodes' return and its greedy evaluation's (the measure that stops a
run), means over seeds with 95 % bootstrap intervals across seeds as bands, and the env's solved
threshold as a dashed line (see :func:`agentax.curves.curve_figure`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from agentax.errors import UsageError


@dataclass(frozen=True)
class PlotArgs:
    runs: Annotated[tuple[str, ...], tyro.conf.Positional]
    """run folders written by agentax train (each holds metrics.csv and config.json)"""
    out: str = "curves.png"
    """the PNG to write"""
    labels: tuple[str, ...] = ()
    """one legend label per run (default: algorithm, env and folder name)"""


def main(argv: list[str]) -> int:
    args = tyro.cli(PlotArgs, args=argv, prog="agentax plot")
    if not args.runs:
        raise UsageError("give at least one run folder: agentax plot DIR [DIR ...] --out curves.png")
    if args.labels and len(args.labels) != len(args.runs):
        raise UsageError(f"--labels needs one label per run ({len(args.runs)}), got {len(args.labels)}")
    from agentax.curves import plot_curves

    for run in args.runs:
        if not Path(run).is_dir():
            raise UsageError(f"{run} is not a folder; give run folders written by agentax train")
    out = plot_curves(args.runs, args.out, args.labels or None)
    print(f"wrote {out}")
    return 0
