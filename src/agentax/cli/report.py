"""``agentax report RUN [RUN ...] [--labels ...] [--json] [--plot PATH]``: compare runs across seeds.

Each run folder's final evaluation (``eval.json``: the mean return of each seed) is one group, or,
with ``--labels``, the runs sharing a label pool their seeds into one group (five host runs of one
seed each, say). A group's seeds on one env form one stratum. For each group: the interquartile
mean, the mean and the median of the seeds' returns, each with a 95 % stratified-bootstrap interval;
for two groups, the probability that the first improves on the second (:mod:`agentax.report`,
after Agarwal et al. 2021).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from agentax.errors import UsageError
from agentax.report import AGGREGATE_REPS


@dataclass(frozen=True)
class ReportArgs:
    """IQM, mean and median of runs' final returns across seeds, with 95 % bootstrap intervals."""

    runs: Annotated[tuple[str, ...], tyro.conf.Positional]
    """run folders written by agentax train (each holds eval.json)"""
    labels: tuple[str, ...] = ()
    """one label per run; runs with the same label are pooled into one group (default: the folder name)"""
    json: bool = False
    """print one JSON object instead of a table"""
    plot: str | None = None
    """also draw the intervals into this PNG"""
    reps: int = AGGREGATE_REPS
    """bootstrap resamples (the probability of improvement takes at most 2,000, as rliable)"""
    seed: int = 0
    """seed of the bootstrap (the same seed gives the same intervals)"""


def final_scores(run_dir: str | Path) -> tuple[str, list[float]]:
    """``(env id, mean return of each seed)`` of a run's final evaluation."""
    from agentax.runs import read_config

    env_id = read_config(run_dir)["env"]
    path = Path(run_dir) / "eval.json"
    if not path.is_file():
        raise UsageError(f"{run_dir} has no eval.json (has its training finished?)")
    try:
        evaluation = json.loads(path.read_text())
        per_seed = evaluation.get("per_seed") or [evaluation]
        return env_id, [float(seed["mean_return"]) for seed in per_seed]
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as error:
        raise UsageError(f"{path} holds no final evaluation ({type(error).__name__}: {error})") from None


def default_labels(runs: tuple[str, ...]) -> list[str]:
    """Each run's folder name, or the path as given where two folders share a name."""
    names = [Path(run).name for run in runs]
    return [name if names.count(name) == 1 else run for name, run in zip(names, runs, strict=True)]


def _interval(run: dict, name: str) -> str:
    low, high = run[f"{name}_ci"]
    return f"{run[name]:.1f} [{low:.1f}, {high:.1f}]"


def main(argv: list[str]) -> int:
    args = tyro.cli(ReportArgs, args=argv, prog="agentax report")
    if not args.runs:
        raise UsageError("give at least one run folder: agentax report RUN [RUN ...]")
    if args.labels and len(args.labels) != len(args.runs):
        raise UsageError(f"--labels needs one label per run ({len(args.runs)}), got {len(args.labels)}")
    if args.reps < 1:
        raise UsageError(f"--reps must be at least 1, got {args.reps}")
    for run in args.runs:
        if not Path(run).is_dir():
            raise UsageError(f"{run} is not a folder; give run folders written by agentax train")
    from agentax.report import compare, plot_intervals

    groups: dict[str, dict[str, list[float]]] = {}
    for label, run in zip(args.labels or default_labels(args.runs), args.runs, strict=True):
        env_id, scores = final_scores(run)
        groups.setdefault(label, {}).setdefault(env_id, []).extend(scores)
    report = compare(groups, reps=args.reps, seed=args.seed)
    if args.plot:
        plot_intervals(report, args.plot)
    if args.json:
        print(json.dumps(report))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="final evaluation across seeds", caption="95 % stratified-bootstrap intervals")
    for column in ("run", "env", "seeds", "IQM", "mean", "median"):
        table.add_column(column, justify="left" if column in ("run", "env") else "right")
    for run in report["runs"]:
        intervals = [_interval(run, name) for name in ("iqm", "mean", "median")]
        table.add_row(run["label"], ", ".join(run["envs"]), str(run["seeds"]), *intervals)
    console = Console()
    console.print(table)
    improvement = report["probability_of_improvement"]
    if improvement is not None:
        low, high = improvement["ci"]
        console.print(
            f"P({improvement['x']} > {improvement['y']}) = {improvement['probability']:.2f} "
            f"[{low:.2f}, {high:.2f}] on {', '.join(improvement['envs'])}",
            highlight=False,
        )
    elif len(groups) == 2:
        console.print("no probability of improvement: the two groups share no env", highlight=False)
    if args.plot:
        print(f"wrote {args.plot}")
    return 0
