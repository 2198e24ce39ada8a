"""``agentax sweep``: settings × seeds trained in as few compiled programs as their shapes allow.

A sweep is a list of settings (a grid, or ``random`` draws from ranges) of an algorithm's
hyperparameters on one of agentax's JAX envs. The names whose values can be traced
(:func:`agentax.runners.sweep.traceable`: learning rates, discounts, λ, coefficients) become an
axis of one program beside the seeds; the others (env counts, rollout lengths, widths, flags) split
the sweep into one program per combination of their values, run one after the other. Each program
is an ordinary compiled run folder (``program-<p>/``: metrics.csv with a column per agent,
TensorBoard, checkpoints, eval.json), so an interrupted sweep resumes program by program.

The sweep folder holds ``sweep.json`` (what was asked, and which names were traced),
``results.csv`` (one row per setting: the IQM, mean and median of the final evaluation over seeds,
each with its 95 % stratified-bootstrap interval, :mod:`agentax.report`), ``scores.png`` (the IQM
against each hyperparameter) and ``best.json`` (the best setting by IQM and the ``agentax train``
command that trains it alone with the same seeds: the same numbers, since agent ``(s, k)`` of a
sweep starts from seed ``k``'s keys).
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
import math
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agentax.errors import UsageError

RESULTS_COLUMNS = (
    "iqm",
    "iqm_low",
    "iqm_high",
    "mean",
    "mean_low",
    "mean_high",
    "median",
    "median_low",
    "median_high",
)


@dataclass(frozen=True)
class SweepResult:
    """A finished sweep: its folder, one dict per setting (its values and scores), the best one."""

    path: Path
    names: list[str]
    settings: list[dict[str, Any]]
    best: dict[str, Any]


def parse_values(field_type: type, text: str, name: str) -> list[Any]:
    """``"1e-4,3e-4"`` as values of a field of ``field_type`` (one line naming a bad value)."""
    values = []
    for item in text.split(","):
        try:
            values.append(_as_type(field_type, item.strip()))
        except ValueError:
            kind = {int: "an integer", float: "a number", bool: "true or false"}[field_type]
            raise UsageError(f"--grid {name}: {item.strip()!r} is not {kind}") from None
    if not values:
        raise UsageError(f"--grid {name}: no values")
    return values


def _as_type(field_type: type, text: str) -> Any:
    if field_type is bool:
        if text.lower() not in ("true", "false", "1", "0"):
            raise ValueError(text)
        return text.lower() in ("true", "1")
    if field_type is int:
        return int(float(text)) if float(text).is_integer() else int(text)
    return field_type(text)


def random_settings(
    ranges: dict[str, tuple[float, float, bool]], types: dict[str, type], count: int, seed: int
):
    """``count`` settings drawn from ``ranges`` (name → (low, high, log)), uniformly or log-uniformly."""
    rng = np.random.default_rng(seed)
    drawn = {}
    for name, (low, high, log) in ranges.items():
        if log and low <= 0:
            raise UsageError(f"--range {name}: a log range needs low > 0, got {low}")
        u = rng.uniform(math.log(low) if log else low, math.log(high) if log else high, count)
        values = np.exp(u) if log else u
        drawn[name] = [int(round(v)) if types[name] is int else float(v) for v in values]
    return [{name: drawn[name][i] for name in ranges} for i in range(count)]


def parse_range(text: str) -> tuple[str, tuple[float, float, bool]]:
    """``"learning_rate=1e-5:1e-2:log"`` → ``("learning_rate", (1e-5, 1e-2, True))``."""
    name, _, spec = text.partition("=")
    parts = spec.split(":")
    try:
        if not name or len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] not in ("log", "linear")):
            raise ValueError
        low, high = float(parts[0]), float(parts[1])
    except ValueError:
        raise UsageError(f"--range {text!r}: write NAME=LOW:HIGH or NAME=LOW:HIGH:log") from None
    if not low < high:
        raise UsageError(f"--range {name}: low must be below high, got {low} and {high}")
    return name, (low, high, len(parts) == 3 and parts[2] == "log")


def sweep(
    algo: str,
    env: str,
    *,
    grid: dict[str, str] | None = None,
    ranges: dict[str, tuple[float, float, bool]] | None = None,
    random: int = 0,
    seeds: int = 8,
    seed: int = 0,
    preset: str = "auto",
    total_steps: int | None = None,
    out: str | Path | None = None,
    progress: bool = True,
) -> SweepResult:
    """Train every setting of ``grid`` (name → "v1,v2,...", their product) or ``random`` draws from
    ``ranges`` with ``seeds`` seeds each; write and return the sweep (see the module docstring).
    ``out`` naming an unfinished sweep of the same request resumes it."""
    from agentax import _xla
    from agentax.api import algorithm, choose_preset, compiled_program, config_to_dict
    from agentax.envs import JAX_ENVS, make_jax
    from agentax.runners.compiled import RunnerConfig
    from agentax.runners.sweep import float_fields, traceable

    grid, ranges = grid or {}, ranges or {}
    if bool(grid) == bool(random):
        raise UsageError(
            "give the settings as --grid NAME=V1,V2,... or as --random N with --range NAME=LOW:HIGH"
        )
    if random and not ranges:
        raise UsageError("--random N draws from ranges: give at least one --range NAME=LOW:HIGH[:log]")
    if env not in JAX_ENVS:
        raise UsageError(
            f"a sweep runs in the compiled runner, on a JAX env ({', '.join(JAX_ENVS)}), not {env!r}"
        )
    _xla.enable_compilation_cache()
    module = algorithm(algo)
    preset_name, chosen = choose_preset(algo, env, preset)
    base = (
        chosen.config if total_steps is None else dataclasses.replace(chosen.config, total_steps=total_steps)
    )
    fields = {f.name: type(getattr(base, f.name)) for f in dataclasses.fields(base)}
    names = list(grid) + list(ranges)
    unknown = [n for n in names if n not in fields]
    if unknown:
        raise UsageError(
            f"unknown {algo} setting {unknown[0]!r}; the {type(base).__name__} fields are {', '.join(fields)}"
        )
    not_numbers = [n for n in names if fields[n] not in (int, float, bool)]
    if not_numbers:
        raise UsageError(f"{not_numbers[0]} is not a number and cannot be swept; set it with agentax train")
    if grid:
        axes = {n: parse_values(fields[n], text, n) for n, text in grid.items()}
        settings = [dict(zip(axes, combo, strict=True)) for combo in itertools.product(*axes.values())]
    else:
        settings = random_settings(ranges, fields, random, seed)
    jax_env = make_jax(env)

    def make_program(cfg):
        return compiled_program(module, jax_env, cfg)

    traced = [n for n in names if n in float_fields(base) and traceable(make_program, base, n)]
    static = [n for n in names if n not in traced]
    for setting in settings:  # every setting validated before anything runs
        candidate = dataclasses.replace(base, **setting)
        if hasattr(candidate, "validate"):
            candidate.validate()
    groups: dict[tuple, list[int]] = {}
    for i, setting in enumerate(settings):
        groups.setdefault(tuple(setting[n] for n in static), []).append(i)

    path = Path(out) if out is not None else _default_sweep_dir(algo, env)
    request = {
        "algo": algo,
        "env": env,
        "preset": preset_name,
        "seeds": seeds,
        "seed": seed,
        "total_steps": base.total_steps,
        "settings": settings,
        "traced": traced,
        "static": static,
    }
    _open_folder(path, request)
    if progress:
        print(
            f"sweep of {algo} on {env}: {len(settings)} settings × {seeds} seeds in {len(groups)} program(s) "
            f"into {path}\n  traced inside a program: {', '.join(traced) or 'none'}"
            f"\n  one program per value: {', '.join(static) or 'none'}",
            flush=True,
        )
    scores: dict[int, np.ndarray] = {}
    for p, (static_values, members) in enumerate(groups.items()):
        cfg = dataclasses.replace(base, **dict(zip(static, static_values, strict=True)))
        runner = RunnerConfig(
            seed=seed,
            num_seeds=seeds,
            num_settings=len(members),
            updates_per_chunk=chosen.updates_per_chunk,
            eval_every_chunks=chosen.eval_every_chunks,
            eval_episodes=chosen.eval_episodes,
        )
        table = {n: np.repeat([settings[i][n] for i in members], seeds).astype(np.float32) for n in traced}
        if progress:
            shown = ", ".join(f"{n}={v}" for n, v in zip(static, static_values, strict=True))
            print(
                f"program {p + 1}/{len(groups)}{': ' + shown if shown else ''} ({len(members)} settings)",
                flush=True,
            )
        per_agent = _train_program(
            path / f"program-{p}",
            algo,
            env,
            preset_name,
            cfg,
            runner,
            table,
            make_program,
            config_to_dict,
            progress,
        )
        for j, i in enumerate(members):
            scores[i] = per_agent[j * seeds : (j + 1) * seeds]
    return _write_results(path, request, settings, scores, static)


def _default_sweep_dir(algo: str, env: str) -> Path:
    from agentax.runs import default_run_dir

    run = default_run_dir(algo, env)
    return run.with_name("sweep-" + run.name)


def _open_folder(path: Path, request: dict[str, Any]) -> None:
    """Make the sweep folder, or check that the one there is this sweep's (then it resumes)."""
    from agentax.runs import write_json

    asked = path / "sweep.json"
    if asked.exists():
        if json.loads(asked.read_text()) != json.loads(json.dumps(request)):
            raise UsageError(f"{path} holds another sweep (its sweep.json differs); choose another --out")
        return
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise UsageError(f"--out {path}: not an empty folder nor a sweep's")
    path.mkdir(parents=True, exist_ok=True)
    write_json(asked, request)


def _train_program(
    folder: Path, algo, env, preset_name, cfg, runner, table, make_program, config_to_dict, progress
) -> np.ndarray:
    """One program of the sweep in its run folder (resumed from its checkpoint, or read back when
    it finished): the final evaluation's mean return of each agent ``[settings × seeds]``."""
    from agentax.envs import make_jax
    from agentax.runners import compiled
    from agentax.runners.sweep import sweep_program
    from agentax.runs import Run, checkpoints, run_config

    done = folder / "eval.json"
    if done.exists():
        return np.asarray([s["mean_return"] for s in json.loads(done.read_text())["per_seed"]])
    program = sweep_program(make_program, cfg, table)
    resume = folder.exists() and bool(checkpoints(folder))
    if resume:
        run = Run.open(folder)
    else:
        if folder.exists():  # made but never checkpointed: start it again
            import shutil

            shutil.rmtree(folder)
        config = run_config(algo, env, preset_name, "sweep", runner, config_to_dict(cfg))
        run = Run.create(folder, {**config, "table": {n: c.tolist() for n, c in table.items()}})
    result = compiled.train(program, make_jax(env), runner, run, resume=resume, progress=progress)
    return np.asarray([s["mean_return"] for s in result.eval["per_seed"]])


def _write_results(path: Path, request, settings, scores, static) -> SweepResult:
    from agentax.report import aggregate
    from agentax.runs import write_json

    rows = []
    for i, setting in enumerate(settings):
        stats = aggregate(scores[i], reps=5_000, seed=i)
        rows.append(
            {
                **setting,
                "iqm": stats["iqm"],
                "iqm_low": stats["iqm_ci"][0],
                "iqm_high": stats["iqm_ci"][1],
                "mean": stats["mean"],
                "mean_low": stats["mean_ci"][0],
                "mean_high": stats["mean_ci"][1],
                "median": stats["median"],
                "median_low": stats["median_ci"][0],
                "median_high": stats["median_ci"][1],
                "scores": [float(s) for s in scores[i]],
            }
        )
    with open(path / "results.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, [*settings[0], *RESULTS_COLUMNS])
        writer.writeheader()
        writer.writerows([{k: v for k, v in row.items() if k != "scores"} for row in rows])
    best = max(rows, key=lambda row: row["iqm"])
    setting = {n: best[n] for n in settings[0]}
    flags = " ".join(f"--{n.replace('_', '-')} {shlex.quote(str(v))}" for n, v in setting.items())
    command = (
        f"agentax train {request['algo']} --env {request['env']} --preset {request['preset']} "
        f"--seeds {request['seeds']} --seed {request['seed']} --total-steps {request['total_steps']} "
        f"--stop-at-return none {flags}"
    )
    write_json(
        path / "best.json",
        {"setting": setting, "iqm": best["iqm"], "scores": best["scores"], "command": command},
    )
    _plot(path / "scores.png", rows, list(settings[0]), request)
    return SweepResult(path, list(settings[0]), rows, {**best, "command": command})


def _plot(out: Path, rows: list[dict], names: list[str], request: dict) -> None:
    """The IQM (and its interval) of each setting against each hyperparameter."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(names), figsize=(4.5 * len(names), 3.5), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        x = np.asarray([row[name] for row in rows], float)
        y = np.asarray([row["iqm"] for row in rows])
        low, high = (
            np.asarray([row["iqm_low"] for row in rows]),
            np.asarray([row["iqm_high"] for row in rows]),
        )
        ax.errorbar(x, y, yerr=[y - low, high - y], fmt="o", capsize=3)
        if (x > 0).all() and x.max() / x.min() >= 20:
            ax.set_xscale("log")
        ax.set_xlabel(name)
        ax.set_ylabel("final evaluation, IQM over seeds")
    figure.suptitle(
        f"{request['algo']} on {request['env']}: {request['seeds']} seeds per setting (95 % intervals)"
    )
    figure.tight_layout()
    figure.savefig(out, dpi=100)
    plt.close(figure)


__all__ = ["SweepResult", "parse_range", "parse_values", "random_settings", "sweep"]
