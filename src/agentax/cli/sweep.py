"""``agentax sweep ALGO --env ID --grid NAME=V1,V2 [--grid ...] | --random N --range NAME=LOW:HIGH[:log]
| --method optuna --trials N --batch K --range ...``.

Trains every setting with ``--seeds`` seeds on the compiled runner, the settings whose names can be
traced side by side in one program (:mod:`agentax.sweeps`), and prints one row per setting: the IQM,
mean and median of the final evaluation over seeds with 95 % bootstrap intervals, best first.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Annotated

import tyro


@dataclass(frozen=True)
class SweepArgs:
    """Hyperparameter settings × seeds, trained in as few compiled programs as their shapes allow."""

    algo: Annotated[str, tyro.conf.Positional]
    """the algorithm: reinforce, ppo, dqn or pqn"""
    env: str = "CartPole-v1"
    """one of agentax's JAX envs"""
    grid: Annotated[tuple[str, ...], tyro.conf.UseAppendAction] = ()
    """NAME=V1,V2,... (repeat the flag: every combination is a setting)"""
    random: int = 0
    """draw this many settings from the --range flags instead of a grid"""
    range: Annotated[tuple[str, ...], tyro.conf.UseAppendAction] = ()
    """NAME=LOW:HIGH or NAME=LOW:HIGH:log (with --random or --method optuna)"""
    method: str = "auto"
    """grid, random, or optuna (TPE: --trials N settings asked --batch K at a time, each batch one
    program); auto: grid with --grid, else random"""
    trials: int = 0
    """--method optuna: settings to try in all"""
    batch: int = 8
    """--method optuna: settings asked at once and trained side by side in one program"""
    seeds: int = 8
    """seeds per setting (the same seeds for every setting)"""
    seed: int = 0
    """the first seed; also seeds the random draws"""
    preset: str = "auto"
    """the preset every setting starts from"""
    total_steps: int | None = None
    """env steps per agent (default: the preset's)"""
    workers: int | None = None
    """processes to split each program's settings over (one a CPU core; XLA's CPU client runs the
    compiled runner on one core); default: every core once the sweep's agent steps reach the measured
    break-even, else 1; an interrupted sweep resumes with the same number"""
    ray_address: str | None = None
    """run the workers as Ray tasks on this cluster ('auto' or HOST:PORT of `ray start --head`); the
    sweep folder must be on a filesystem every node shares"""
    out: str | None = None
    """the sweep folder (default runs/sweep-ALGO-ENV-TIME); an unfinished sweep there resumes"""
    json: bool = False
    """print the results as one JSON object"""
    progress: bool = True
    """show the progress of each program"""
    encoder: Annotated[tuple[str, ...], tyro.conf.UseAppendAction] = ()
    """KEY=CHOICE: the encoder of the observation's leaf KEY, as agentax train's (repeat the flag)"""


def main(argv: list[str]) -> int:
    from agentax.errors import UsageError
    from agentax.sweeps import parse_range, sweep

    args = tyro.cli(SweepArgs, args=argv, prog="agentax sweep")
    grid = {}
    for item in args.grid:
        name, sep, values = item.partition("=")
        if not sep or not name:
            raise UsageError(f"--grid {item!r}: write NAME=V1,V2,...")
        grid[name] = values
    ranges = dict(parse_range(item) for item in args.range)
    encoders = {key: choice for key, _, choice in (item.partition("=") for item in args.encoder)}
    result = sweep(
        args.algo,
        args.env,
        grid=grid,
        ranges=ranges,
        random=args.random,
        method=args.method,
        trials=args.trials,
        batch=args.batch,
        seeds=args.seeds,
        seed=args.seed,
        preset=args.preset,
        total_steps=args.total_steps,
        out=args.out,
        workers=args.workers,
        ray_address=args.ray_address,
        progress=args.progress,
        encoders=encoders,
    )
    if args.json:
        print(json.dumps({"sweep": str(result.path), "settings": result.settings, "best": result.best}))
        return 0
    names = [
        n for n in result.settings[0] if n not in ("scores",) and not n.startswith(("iqm", "mean", "median"))
    ]
    print(f"{'  '.join(names)}  IQM [95 % interval]  mean  median")
    for row in sorted(result.settings, key=lambda r: -r["iqm"]):
        values = "  ".join(f"{row[n]:g}" if isinstance(row[n], float) else str(row[n]) for n in names)
        interval = f"[{row['iqm_low']:.1f}, {row['iqm_high']:.1f}]"
        print(f"{values}  {row['iqm']:.1f} {interval}  {row['mean']:.1f}  {row['median']:.1f}")
    print(f"best: {result.best['command']}")
    print(f"sweep folder: {result.path} (results.csv, scores.png, best.json, best.toml)")
    return 0
