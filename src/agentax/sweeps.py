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
sweep starts from seed ``k``'s keys) and ``best.toml``, the same training as a run file
(``agentax train --config best.toml``).
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

STATISTICS = ("iqm", "mean", "median")  # report.aggregate's, each with its interval
RESULTS_COLUMNS = tuple(f"{name}{end}" for name in STATISTICS for end in ("", "_low", "_high"))


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


def _settings(method: str, grid, ranges, random: int, seed: int, fields, base) -> list[dict[str, Any]]:
    """The settings of a grid or random sweep, each validated before anything runs (none for Optuna:
    its settings are asked batch by batch)."""
    if method == "grid":
        axes = {n: parse_values(fields[n], text, n) for n, text in grid.items()}
        settings = [dict(zip(axes, combo, strict=True)) for combo in itertools.product(*axes.values())]
    elif method == "random":
        settings = random_settings(ranges, fields, random, seed)
    else:
        settings = []
    for setting in settings:
        _validated(base, setting)
    return settings


def sweep(
    algo: str,
    env: str,
    *,
    grid: dict[str, str] | None = None,
    ranges: dict[str, tuple[float, float, bool]] | None = None,
    random: int = 0,
    method: str = "auto",
    trials: int = 0,
    batch: int = 8,
    seeds: int = 8,
    seed: int = 0,
    preset: str = "auto",
    total_steps: int | None = None,
    out: str | Path | None = None,
    workers: int | None = None,
    ray_address: str | None = None,
    progress: bool = True,
    encoders: dict[str, str] | None = None,
) -> SweepResult:
    """Train every setting of ``grid`` (name → "v1,v2,...", their product), ``random`` draws from
    ``ranges``, or (``method="optuna"``) ``trials`` settings Optuna's TPE suggests in ``ranges``,
    ``batch`` at a time as one program; ``seeds`` seeds each; the observation's leaves encoded as
    ``encoders`` choose (key → choice, as ``agentax train --encoder``). Writes and returns the sweep
    (see the module docstring); ``out`` naming an unfinished sweep of the same request resumes it."""
    from agentax import _xla
    from agentax.agents import algorithm
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import JAX_ENVS, make_jax
    from agentax.runfile import choose_preset
    from agentax.runners.compiled import compiled_program
    from agentax.runners.cost import program_flops
    from agentax.runners.sweep import float_fields, traceable
    from agentax.runners.workers import default_count

    grid, ranges = grid or {}, ranges or {}
    method = method if method != "auto" else ("grid" if grid else "random")
    _check_request(method, grid, ranges, random, trials, batch)
    if workers is not None and workers < 1:
        raise UsageError(f"--workers must be at least 1, got {workers}")
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
    names = list(grid) + list(ranges)
    fields = _numeric_fields(algo, base, names)
    jax_env = make_jax(env)
    EnvSpec.of(jax_env).with_encoders(encoders, env)  # a bad key or choice: one line, before tracing

    def make_program(cfg):
        return compiled_program(module, jax_env, cfg, encoders=encoders)

    traced = [n for n in names if n in float_fields(base) and traceable(make_program, base, n)]
    static = [n for n in names if n not in traced]
    if method == "optuna" and static:
        raise UsageError(
            f"--method optuna suggests traced values only (one program a batch); {static[0]} sets a shape "
            "or a branch of the program: fix it with --preset or sweep it with --grid"
        )
    settings = _settings(method, grid, ranges, random, seed, fields, base)
    path = Path(out) if out is not None else _default_sweep_dir(algo, env)
    if workers is None:  # a resumed sweep's own; else every core once the sweep costs enough to gain
        members = len(settings) or trials
        workers = _asked(path).get("workers") or default_count(
            len(settings) or batch, lambda: members * seeds * program_flops(make_program(base))
        )
    request = {
        "algo": algo,
        "env": env,
        "preset": preset_name,
        "seeds": seeds,
        "seed": seed,
        "total_steps": base.total_steps,
        "method": method,
        "workers": workers,
        **({"settings": settings} if settings else {"ranges": ranges, "trials": trials, "batch": batch}),
        "traced": traced,
        "static": static,
        **({"encoders": dict(encoders)} if encoders else {}),  # (absent: as every older sweep.json)
    }
    _open_folder(path, request)

    programs = _Programs(path, request, base, chosen, static, traced, workers, ray_address, progress)
    if method == "optuna":
        settings, scores = _optuna(path, ranges, trials, batch, seed, programs.train, base, progress)
    else:
        scores = programs.train_all(settings)
    return _write_results(path, request, settings, scores)


def _numeric_fields(algo: str, base: Any, names: list[str]) -> dict[str, type]:
    """The type of each field of ``base`` (the algorithm's config); a ``UsageError`` where ``names``
    holds one it lacks or one that is not a number."""
    fields = {f.name: type(getattr(base, f.name)) for f in dataclasses.fields(base)}
    unknown = [n for n in names if n not in fields]
    if unknown:
        raise UsageError(
            f"unknown {algo} setting {unknown[0]!r}; the {type(base).__name__} fields are {', '.join(fields)}"
        )
    not_numbers = [n for n in names if fields[n] not in (int, float, bool)]
    if not_numbers:
        raise UsageError(f"{not_numbers[0]} is not a number and cannot be swept; set it with agentax train")
    return fields


@dataclass(frozen=True)
class _Programs:
    """How a sweep's settings train: those whose static values are equal as one program, their
    traced values a table inside it (split over ``workers`` processes)."""

    path: Path
    request: dict[str, Any]
    base: Any
    preset: Any
    static: list[str]
    traced: list[str]
    workers: int
    ray_address: str | None
    progress: bool

    def train(self, p: int, members: list[dict[str, Any]]) -> list[np.ndarray]:
        """Program ``p``: ``members`` (their static values equal) × the seeds; each member's scores."""
        from agentax.runners.compiled import RunnerConfig, schedule_of
        from agentax.runners.workers import map_processes

        seeds = self.request["seeds"]
        cfg = dataclasses.replace(self.base, **{n: members[0][n] for n in self.static})
        runner = RunnerConfig(
            seed=self.request["seed"], num_seeds=seeds, num_settings=len(members), **schedule_of(self.preset)
        )
        parts = np.array_split(np.arange(len(members)), min(self.workers, len(members)))
        jobs = []
        for w, part in enumerate(parts):
            table = {
                n: np.repeat([members[j][n] for j in part], seeds).astype(np.float32) for n in self.traced
            }
            folder = self.path.resolve() / (f"program-{p}" if len(parts) == 1 else f"program-{p}-{w}")
            jobs.append(
                (folder, self.request, cfg, dataclasses.replace(runner, num_settings=len(part)), table)
            )
        # several jobs: one process a worker, each with its own one-CPU XLA client (the first shows progress)
        shown = [(*job, self.progress and w == 0) for w, job in enumerate(jobs)]
        per_agent = np.concatenate(map_processes(_train_program, shown, self.ray_address))
        return [per_agent[j * seeds : (j + 1) * seeds] for j in range(len(members))]

    def train_all(self, settings: list[dict[str, Any]]) -> dict[int, np.ndarray]:
        """Every setting (a grid's or random draws'), a program per group of equal static values."""
        groups: dict[tuple, list[int]] = {}
        for i, setting in enumerate(settings):
            groups.setdefault(tuple(setting[n] for n in self.static), []).append(i)
        if self.progress:
            request = self.request
            print(
                f"sweep of {request['algo']} on {request['env']}: {len(settings)} settings × "
                f"{request['seeds']} seeds in {len(groups)} program(s) into {self.path}\n"
                f"  traced inside a program: {', '.join(self.traced) or 'none'}"
                f"\n  one program per value: {', '.join(self.static) or 'none'}",
                flush=True,
            )
        scores: dict[int, np.ndarray] = {}
        for p, members in enumerate(groups.values()):
            if self.progress:
                shown = ", ".join(f"{n}={settings[members[0]][n]}" for n in self.static)
                print(
                    f"program {p + 1}/{len(groups)}{': ' + shown if shown else ''} ({len(members)} settings)"
                )
            for i, member_scores in zip(members, self.train(p, [settings[i] for i in members]), strict=True):
                scores[i] = member_scores
        return scores


def _check_request(method: str, grid: dict, ranges: dict, random: int, trials: int, batch: int) -> None:
    """One line for a request that names no settings, or two kinds of them."""
    if method not in ("grid", "random", "optuna"):
        raise UsageError(f"unknown --method {method!r}; choose from grid, random, optuna")
    if method == "optuna":
        if grid or random:
            raise UsageError(
                "--method optuna suggests its own settings: give --range flags, not --grid or --random"
            )
        if trials < 1 or batch < 1 or not ranges:
            raise UsageError("--method optuna needs --trials N (and --batch K) and at least one --range")
        return
    if bool(grid) == bool(random):
        raise UsageError(
            "give the settings as --grid NAME=V1,V2,... or as --random N with --range NAME=LOW:HIGH"
        )
    if random and not ranges:
        raise UsageError("--random N draws from ranges: give at least one --range NAME=LOW:HIGH[:log]")


def _validated(base: Any, setting: dict[str, Any]) -> None:
    candidate = dataclasses.replace(base, **setting)
    if hasattr(candidate, "validate"):
        candidate.validate()


def _optuna(path: Path, ranges, trials: int, batch: int, seed: int, train_settings, base, progress: bool):
    """Optuna's ask-and-tell, a batch of trials at a time, each batch one program; a trial's value
    is the IQM of its seeds. A batch's settings are kept (``asked-<b>.json``) before it trains, so a
    resumed sweep asks the same ones again (enqueued) and the TPE sampler, told the same results,
    carries on as it would have."""
    import optuna

    from agentax.report import iqm
    from agentax.runs import write_json

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="maximize", sampler=optuna.samplers.TPESampler(seed=seed))
    distributions = {
        n: optuna.distributions.FloatDistribution(low, high, log=log)
        for n, (low, high, log) in ranges.items()
    }
    settings: list[dict[str, Any]] = []
    scores: dict[int, np.ndarray] = {}
    batches = -(-trials // batch)
    for b in range(batches):
        asked_path = path / f"asked-{b}.json"
        if asked_path.exists():
            for params in json.loads(asked_path.read_text()):
                study.enqueue_trial(params)
        asked = [study.ask(distributions) for _ in range(min(batch, trials - b * batch))]
        members = [dict(t.params) for t in asked]
        for member in members:
            _validated(base, member)
        write_json(asked_path, members)
        if progress:
            print(f"optuna batch {b + 1}/{batches}: {len(members)} trials in one program", flush=True)
        for trial, member, member_scores in zip(asked, members, train_settings(b, members), strict=True):
            study.tell(trial, float(iqm(np.asarray(member_scores))))
            scores[len(settings)] = member_scores
            settings.append(member)
    return settings, scores


def _default_sweep_dir(algo: str, env: str) -> Path:
    from agentax.runs import default_run_dir

    run = default_run_dir(algo, env)
    return run.with_name("sweep-" + run.name)


def _asked(path: Path) -> dict[str, Any]:
    """The request in the sweep folder ``path`` (its sweep.json), or {} where there is none yet."""
    asked = path / "sweep.json"
    return json.loads(asked.read_text()) if asked.exists() else {}


def _open_folder(path: Path, request: dict[str, Any]) -> None:
    """Make the sweep folder, or check that the one there is this sweep's (then it resumes)."""
    from agentax import formats
    from agentax.runs import write_json

    if asked := _asked(path):
        formats.check_readable(formats.version_of(asked), path / "sweep.json")
        if {k: v for k, v in asked.items() if k != "format"} != json.loads(json.dumps(request)):
            raise UsageError(f"{path} holds another sweep (its sweep.json differs); choose another --out")
        return
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise UsageError(f"--out {path}: not an empty folder nor a sweep's")
    path.mkdir(parents=True, exist_ok=True)
    write_json(path / "sweep.json", {"format": formats.FORMAT, **request})


def _train_program(folder: Path, request, cfg, runner, table, progress: bool = False) -> np.ndarray:
    """One program of the sweep in its run folder (resumed from its checkpoint, or read back when
    it finished): the final evaluation's mean return of each agent ``[settings × seeds]``. Its
    arguments are data, so a worker process can run it."""
    from agentax.agents import algorithm, config_to_dict
    from agentax.envs import make_jax
    from agentax.runners.compiled import compiled_program, train_program
    from agentax.runners.sweep import sweep_program
    from agentax.runners.workers import resume_or_restart
    from agentax.runs import run_config

    done = folder / "eval.json"
    if done.exists():
        return np.asarray([s["mean_return"] for s in json.loads(done.read_text())["per_seed"]])
    module, env = algorithm(request["algo"]), make_jax(request["env"])
    encoders = request.get("encoders")
    program = sweep_program(
        lambda config: compiled_program(module, env, config, encoders=encoders), cfg, table
    )
    settings = config_to_dict(cfg)
    config = run_config(
        request["algo"], request["env"], request["preset"], "sweep", runner, settings, encoders
    )
    run, resume = resume_or_restart(folder, {**config, "table": {n: c.tolist() for n, c in table.items()}})
    result = train_program(program, env, runner, run, resume=resume, progress=progress)
    return np.asarray([s["mean_return"] for s in result.eval["per_seed"]])


def _write_results(path: Path, request, settings, scores) -> SweepResult:
    from agentax.report import aggregate
    from agentax.runs import write_json

    rows = []
    for i, setting in enumerate(settings):
        stats = aggregate(scores[i], reps=5_000, seed=i)
        intervals = {
            f"{n}{end}": stats[f"{n}_ci"][k] for n in STATISTICS for k, end in enumerate(("_low", "_high"))
        }
        rows.append({**setting, **{n: stats[n] for n in STATISTICS}, **intervals})
        rows[-1]["scores"] = [float(s) for s in scores[i]]
    with open(path / "results.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, [*settings[0], *RESULTS_COLUMNS])
        writer.writeheader()
        writer.writerows([{k: v for k, v in row.items() if k != "scores"} for row in rows])
    best = max(rows, key=lambda row: (row["iqm"], row["mean"]))  # ties (a solved env) by the mean
    setting = {n: best[n] for n in settings[0]}
    flags = " ".join(f"--{n.replace('_', '-')} {shlex.quote(str(v))}" for n, v in setting.items())
    flags += "".join(f" --encoder {shlex.quote(f'{k}={v}')}" for k, v in request.get("encoders", {}).items())
    command = (
        f"agentax train {request['algo']} --env {request['env']} --preset {request['preset']} "
        f"--seeds {request['seeds']} --seed {request['seed']} --total-steps {request['total_steps']} "
        f"--stop-at-return none {flags}"
    )
    write_json(
        path / "best.json",
        {"setting": setting, "iqm": best["iqm"], "scores": best["scores"], "command": command},
    )
    _write_best_run_file(path / "best.toml", request, setting, command)
    _plot(path / "scores.png", rows, list(settings[0]), request)
    return SweepResult(path, list(settings[0]), rows, {**best, "command": command})


def _write_best_run_file(path: Path, request: dict[str, Any], setting: dict[str, Any], command: str) -> None:
    """best.toml: the best setting as a run file (:mod:`agentax.runfile`), the same training as
    best.json's ``command``: ``agentax train --config best.toml``."""
    from agentax import runfile

    _, chosen = runfile.choose_preset(request["algo"], request["env"], request["preset"])
    cfg = dataclasses.replace(chosen.config, total_steps=request["total_steps"], **setting)
    run_args = runfile.RunArgs(
        env=request["env"],
        preset=request["preset"],
        seed=request["seed"],
        seeds=request["seeds"],
        stop_at_return="none",
        encoders=request.get("encoders", {}),
    )
    header = f"the best setting of the sweep in {path.parent}: {command}\nor: agentax train --config {path}"
    runfile.write(path, request["algo"], run_args, cfg, header)


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
