"""A run's folder: config, metrics (CSV + TensorBoard), checkpoints, the learning curve, the evaluation.

Every trainer writes the same layout, so ``agentax evaluate/play --policy DIR``, ``agentax plot``
and ``agentax train --resume DIR`` work on any of them::

    runs/<algo>-<env>-<YYYYmmdd-HHMMSS>/
      config.json      the whole configuration; "algo" and "env" keys name the algorithm and env
      metrics.csv      a row per logging interval: env_steps, mean_return (pooled over seeds),
                       return_seed<k> per seed, and whatever else the trainer logs
      tensorboard/     the same scalars as TensorBoard event files (tensorboardX), in groups:
                       train/, eval/, loss/, perf/ (see tensorboard_tag)
      checkpoints/     ckpt-<updates>.msgpack (flax msgpack, never pickle), written to a temporary
                       name in the same folder and renamed, so a crash never leaves half a file
      curve.png        return against env steps: the training episodes' and the greedy evaluation's
                       (the measure that stops a run), means over seeds with 95 % bootstrap
                       intervals across seeds, and the env's solved threshold
      eval.json        the trained greedy policy on fresh evaluation seeds: mean_return,
                       std_return, min_return, max_return, episodes, pooled over seeds at the top
                       level and per seed under "per_seed"; with several seeds also iqm, median
                       and 95 % intervals across the seeds (iqm_ci, mean_ci, median_ci)

``load_policy(run_dir)`` rebuilds the trained policy of any run (any algorithm, any runner).
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import importlib
import io
import json
import math
import os
import threading
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from agentax import _xla
from agentax.errors import UsageError
from agentax.evaluate import EvalStats
from agentax.policies import Policy
from agentax.report import aggregate

SEARCH_MODULES: dict[str, str] = {
    "ga": "agentax.search.genetic",
    "cem": "agentax.search.cem",
    "grid": "agentax.search.grid",
    "random": "agentax.search.random_search",
}
CHECKPOINT_PREFIX = "ckpt-"
BOOTSTRAP_RESAMPLES = 2_000

# TensorBoard groups, as CleanRL's charts/ and losses/: metrics.csv keeps the plain names.
TENSORBOARD_GROUPS: dict[str, str] = {
    "mean_return": "train",
    "episodes": "train",
    "epsilon": "train",
    "updates": "train",
    "learning_steps": "train",
    "loss": "loss",
    "q_mean": "loss",
    "td_error": "loss",
    "entropy": "loss",
    "approx_kl": "loss",
    "policy_lag": "perf",
    "wall_seconds": "perf",
}
# Families of names, by prefix or suffix, after the exact names above.
TENSORBOARD_PREFIXES = (("return_seed", "train"), ("eval_", "eval"), ("replay_", "perf"))
TENSORBOARD_SUFFIXES = (("_loss", "loss"), ("_per_second", "perf"), ("_wait_fraction", "perf"))


def tensorboard_tag(name: str) -> str:
    """The grouped TensorBoard tag of a metrics.csv column: ``train/mean_return``, ``eval/eval_return``,
    ``loss/value_loss``, ``perf/steps_per_second``; a name in no group is logged under ``other/``."""
    group = TENSORBOARD_GROUPS.get(name)
    group = group or next((g for prefix, g in TENSORBOARD_PREFIXES if name.startswith(prefix)), None)
    group = group or next((g for suffix, g in TENSORBOARD_SUFFIXES if name.endswith(suffix)), None)
    return f"{group or 'other'}/{name}"


def default_run_dir(algo: str, env_id: str, root: str | Path = "runs") -> Path:
    """``runs/<algo>-<env>-<YYYYmmdd-HHMMSS>`` (with a ``-2``, ``-3`` suffix if taken)."""
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = Path(root) / f"{algo}-{env_id.replace('/', '_')}-{stamp}"
    candidate, n = path, 1
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.name}-{n}")
    return candidate


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary name in the same folder, then rename it over ``path``."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def write_json(path: Path, obj: Any) -> None:
    """``obj`` as indented JSON, written atomically (numbers from numpy included)."""
    write_atomic(Path(path), (json.dumps(obj, indent=2, default=_json_default) + "\n").encode())


def run_config(algo: str, env_id: str, preset: str, runner_kind: str, runner: Any, config: dict) -> dict:
    """What a trainer's ``config.json`` holds: the algorithm, env, preset, runner and its settings."""
    runner = dataclasses.asdict(runner) if dataclasses.is_dataclass(runner) else dict(runner)
    return {
        "algo": algo,
        "env": env_id,
        "preset": preset,
        "runner_kind": runner_kind,
        "runner": runner,
        "config": config,
    }


def read_config(run_dir: str | Path) -> dict[str, Any]:
    """The run's ``config.json``; a clear error for a folder that holds no run."""
    path = Path(run_dir) / "config.json"
    if not path.is_file():
        raise UsageError(f"{run_dir} holds no run (no config.json); give a folder written by agentax train")
    try:
        config = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise UsageError(f"{path} is not valid JSON ({error})") from None
    if not isinstance(config, dict) or "algo" not in config or "env" not in config:
        raise UsageError(f"{path} lacks the 'algo' and 'env' keys of a run's config")
    return config


def read_metrics(run_dir: str | Path) -> list[dict[str, float]]:
    """The rows of ``metrics.csv`` as floats (blank cells become NaN)."""
    path = Path(run_dir) / "metrics.csv"
    if not path.is_file():
        raise UsageError(f"{run_dir} has no metrics.csv; give a run folder written by agentax")
    with open(path, newline="") as f:
        return [
            {k: float(v) if v not in ("", None) else math.nan for k, v in row.items()}
            for row in csv.DictReader(f)
        ]


# Checkpoints: any pytree, typed PRNG keys included, as flax msgpack.


def _is_key(x: Any) -> bool:
    return isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def save_tree(path: str | Path, tree: Any, meta: dict[str, Any] | None = None) -> Path:
    """Write ``tree`` (and a small JSON-able ``meta`` dict) to ``path`` atomically, as msgpack."""
    from flax import serialization

    host = jax.tree.map(lambda x: np.asarray(jax.random.key_data(x) if _is_key(x) else x), tree)
    payload = {"state": serialization.to_state_dict(host), "meta": json.dumps(meta or {})}
    path = Path(path)
    write_atomic(path, serialization.msgpack_serialize(payload))
    return path


def load_tree(path: str | Path, target: Any) -> tuple[Any, dict[str, Any]]:
    """Read a tree saved by :func:`save_tree` into the structure of ``target``; returns ``(tree, meta)``.

    ``target`` may hold arrays or ``jax.ShapeDtypeStruct`` leaves (from ``jax.eval_shape``). A
    truncated, corrupt or mismatched file raises a :class:`UsageError` naming the file.
    """
    from flax import serialization

    path = Path(path)
    try:
        payload = serialization.msgpack_restore(path.read_bytes())
        meta = json.loads(payload["meta"])
        key_leaves = jax.tree.map(_is_key_like, target)
        plain_target = jax.tree.map(_plain_struct, target)
        restored = serialization.from_state_dict(plain_target, payload["state"])
        expected, actual = jax.tree.leaves(plain_target), jax.tree.leaves(restored)
        if len(expected) != len(actual):
            raise ValueError(f"{len(actual)} arrays where {len(expected)} were expected")
        for want, got in zip(expected, actual, strict=True):
            if tuple(want.shape) != tuple(np.shape(got)) or np.dtype(want.dtype) != np.asarray(got).dtype:
                raise ValueError(
                    f"an array {np.asarray(got).dtype}{list(np.shape(got))} where {want.dtype}"
                    f"{list(want.shape)} was expected"
                )
    except (OSError, ValueError, KeyError, TypeError, AttributeError, IndexError) as error:
        raise UsageError(
            f"checkpoint {path} is corrupt or belongs to another configuration ({error})"
        ) from None
    except Exception as error:  # msgpack's own errors (ExtraData, FormatError, StackError, ...)
        raise UsageError(f"checkpoint {path} is corrupt ({type(error).__name__}: {error})") from None
    tree = jax.tree.map(
        lambda is_key, x: jax.random.wrap_key_data(np.asarray(x)) if is_key else np.asarray(x),
        key_leaves,
        restored,
    )
    return tree, meta


def _is_key_like(x: Any) -> bool:
    return jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _plain_struct(x: Any) -> jax.ShapeDtypeStruct:
    if _is_key_like(x):
        data = jax.eval_shape(jax.random.key_data, x)
        return jax.ShapeDtypeStruct(data.shape, data.dtype)
    return jax.ShapeDtypeStruct(np.shape(x), x.dtype)


def checkpoints(run_dir: str | Path) -> list[Path]:
    """The run's checkpoint files, oldest first."""
    folder = Path(run_dir) / "checkpoints"
    found = folder.glob(f"{CHECKPOINT_PREFIX}*.msgpack") if folder.is_dir() else []
    return sorted(found, key=lambda p: int(p.stem.removeprefix(CHECKPOINT_PREFIX)))


def latest_checkpoint(run_dir: str | Path) -> Path:
    """The newest checkpoint; a clear error if the run has none."""
    found = checkpoints(run_dir)
    if not found:
        raise UsageError(f"{run_dir} has no checkpoint in {Path(run_dir) / 'checkpoints'}; train it first")
    return found[-1]


def load_checkpoint(run_dir: str | Path, target: Any) -> tuple[Any, dict[str, Any], Path]:
    """The newest checkpoint that loads into ``target``: ``(tree, meta, path)``.

    A damaged file (cut short by a full disk, overwritten, from another configuration) is skipped
    with one warning line on stderr and the next older one is tried; :meth:`Run.save_checkpoint`
    keeps three, so a single bad file costs one checkpoint interval rather than the run. If none
    loads, a :class:`UsageError` names the run folder and the last reason; with no checkpoint at
    all, the error of :func:`latest_checkpoint`.
    """
    import sys

    found = checkpoints(run_dir)
    if not found:
        latest_checkpoint(run_dir)  # raises the "has no checkpoint" UsageError
    reason = ""
    for i, path in enumerate(reversed(found)):
        try:
            tree, meta = load_tree(path, target)
        except UsageError as error:  # load_tree turns every read/decode/shape failure into this
            cause = error.__context__  # the original error (raised ``from None``, so kept as context)
            if cause is None:
                reason = str(error)
            else:
                reason = f"{type(cause).__name__}: {cause}" if str(cause) else type(cause).__name__
            if i + 1 < len(found):
                older = found[-(i + 2)]
                print(
                    f"warning: skipping damaged checkpoint {path} ({reason}); using {older}", file=sys.stderr
                )
            continue
        return tree, meta, path
    raise UsageError(
        f"{run_dir}: none of its {len(found)} checkpoint(s) loads; the oldest, {found[0]}, is damaged "
        f"or belongs to another configuration ({reason})"
    )


class Run:
    """The open folder of one run: a thin shell that writes, the rest of this module reads.

    ``Run.create`` starts a new run (refusing a folder that already holds one), ``Run.open``
    continues one (``--resume``).
    """

    def __init__(self, path: Path, config: dict[str, Any]):
        self.path = Path(path)
        self.config = config
        self._writer = None
        self._columns: list[str] | None = None
        metrics = self.path / "metrics.csv"
        if metrics.is_file():
            with open(metrics, newline="") as f:
                self._columns = next(csv.reader(f), None)

    @classmethod
    def create(cls, path: str | Path, config: dict[str, Any]) -> Run:
        """Make the folder and write ``config.json`` (which must name ``algo`` and ``env``)."""
        path = Path(path)
        if (path / "config.json").exists():
            raise UsageError(
                f"{path} already holds a run; continue it with 'agentax train --resume {path}' "
                "or choose another --out"
            )
        if not {"algo", "env"} <= config.keys():
            raise ValueError("a run's config needs 'algo' and 'env' keys")
        (path / "checkpoints").mkdir(parents=True, exist_ok=True)
        write_json(path / "config.json", config)
        return cls(path, config)

    @classmethod
    def open(cls, path: str | Path) -> Run:
        return cls(Path(path), read_config(path))

    def log(self, row: dict[str, float]) -> None:
        """Append a row to metrics.csv and to TensorBoard. A metric first seen in a later row (a loss
        once learning starts) becomes a new column, blank in the earlier rows."""
        metrics = self.path / "metrics.csv"
        if self._columns is None:
            self._columns = list(row)
            with open(metrics, "w", newline="") as f:
                csv.writer(f).writerow(self._columns)
        extra = [name for name in row if name not in self._columns]
        if extra:
            with open(metrics, newline="") as f:
                rows = list(csv.reader(f))
            self._columns += extra
            rows = [self._columns] + [r + [""] * len(extra) for r in rows[1:]]
            write_atomic(metrics, _csv_bytes(rows))
        with open(metrics, "a", newline="") as f:
            csv.writer(f).writerow([_cell(row.get(c)) for c in self._columns])
        if self._writer is None:
            from tensorboardX import SummaryWriter

            self._writer = SummaryWriter(str(self.path / "tensorboard"), flush_secs=10)
        step = int(row.get("env_steps", 0))
        for name, value in row.items():
            if name != "env_steps" and value is not None and math.isfinite(float(value)):
                self._writer.add_scalar(tensorboard_tag(name), float(value), step)

    def truncate_metrics(self, max_env_steps: float) -> None:
        """Drop the rows logged after ``max_env_steps`` (a resumed run logs them again)."""
        metrics = self.path / "metrics.csv"
        if not metrics.is_file():
            return
        with open(metrics, newline="") as f:
            rows = list(csv.reader(f))
        index = rows[0].index("env_steps")
        kept = [rows[0]] + [r for r in rows[1:] if float(r[index]) <= max_env_steps]
        with open(metrics, "w", newline="") as f:
            csv.writer(f).writerows(kept)

    def save_checkpoint(self, updates: int, tree: Any, meta: dict[str, Any], keep: int = 3) -> Path:
        """Write ``checkpoints/ckpt-<updates>.msgpack`` atomically; keep the ``keep`` newest.

        More than one is kept so that :func:`load_checkpoint` has an older one to fall back on.
        """
        path = save_tree(self.path / "checkpoints" / f"{CHECKPOINT_PREFIX}{updates}.msgpack", tree, meta)
        for old in checkpoints(self.path)[:-keep]:
            old.unlink(missing_ok=True)
        return path

    def write_eval(self, per_seed_returns: np.ndarray, per_seed_lengths: np.ndarray, **extra: Any) -> dict:
        """Write eval.json from returns ``[num_seeds, episodes]``: pooled stats on top, per seed below.

        With several seeds it also holds the aggregates of :mod:`agentax.report` over the seeds'
        mean returns: ``iqm``, ``median`` and the 95 % stratified-bootstrap intervals ``iqm_ci``,
        ``mean_ci`` (of ``mean_return``, which equals the mean of the seeds' means) and ``median_ci``.
        """
        per_seed_returns, per_seed_lengths = np.atleast_2d(per_seed_returns), np.atleast_2d(per_seed_lengths)
        pooled = EvalStats.from_returns(per_seed_returns.ravel(), per_seed_lengths.ravel())
        per_seed = [
            vars(EvalStats.from_returns(returns, lengths))
            for returns, lengths in zip(per_seed_returns, per_seed_lengths, strict=True)
        ]
        across_seeds = {}
        if len(per_seed) > 1:
            across_seeds = aggregate([s["mean_return"] for s in per_seed])
            del across_seeds["mean"]  # mean_return already
        result = {**vars(pooled), "per_seed": per_seed, **across_seeds, **extra}
        write_json(self.path / "eval.json", result)
        return result

    def plot(self) -> Path:
        """Write curve.png from metrics.csv."""
        return plot_curves([self.path], self.path / "curve.png")

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None


def _csv_bytes(rows: list[list[str]]) -> bytes:
    buffer = io.StringIO()
    csv.writer(buffer).writerows(rows)
    return buffer.getvalue().encode()


def _cell(value: Any) -> str:
    if value is None:
        return ""
    value = float(value)
    return "" if math.isnan(value) else repr(round(value, 6)) if not value.is_integer() else str(int(value))


def _json_default(value: Any) -> Any:
    if isinstance(value, tuple | list):
        return list(value)
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def seed_columns(row: dict[str, float], prefix: str = "return_seed") -> list[str]:
    """The per-seed columns (``return_seed0``, ``return_seed1``, ...) of a metrics row, in seed order."""
    return sorted((c for c in row if c.startswith(prefix)), key=lambda c: int(c.removeprefix(prefix)))


def preload_plotting() -> None:
    """Import matplotlib in a thread now, so that writing curve.png later costs no import.

    matplotlib's import takes ~0.5 s, a fifth of a warm ``agentax train``. Started while XLA
    compiles or runs (which releases the GIL), the import overlaps with it; the thread runs no XLA
    code, so it may leave the CPU the process is pinned to (:mod:`agentax._xla`) for the others.
    """

    def load() -> None:
        if _xla.UNPINNED_CPUS:
            os.sched_setaffinity(0, _xla.UNPINNED_CPUS)  # this thread only
        import matplotlib.backends.backend_agg  # noqa: F401
        import matplotlib.figure  # noqa: F401

    threading.Thread(target=load, name="agentax-preload-plotting").start()


def bootstrap_band(
    per_seed: np.ndarray, confidence: float = 0.95, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Row by row, the percentile-bootstrap interval of the mean across seeds: ``(low, high)``.

    ``per_seed`` is ``[rows, seeds]``, NaN where a seed has no value (yet). Every replicate draws
    the seeds with replacement (one fixed set of draws, ``seed``, for all rows) and averages the
    finite values drawn; rows with fewer than two finite seeds get NaN. Both ends are means of
    observed values, so the band stays within the data's range: unlike ``mean ± 1.96 σ/√n``, it
    never promises a CartPole return above 500.
    """
    per_seed = np.asarray(per_seed, np.float64)
    rows, num_seeds = per_seed.shape
    low, high = np.full(rows, np.nan), np.full(rows, np.nan)
    enough = np.isfinite(per_seed).sum(1) >= 2
    if num_seeds < 2 or not enough.any():
        return low, high
    draws = np.random.default_rng(seed).integers(0, num_seeds, size=(resamples, num_seeds))
    tail = 100 * (1 - confidence) / 2
    chunk = max(1, 2**22 // (resamples * num_seeds))  # rows at a time: ~32 MB of replicates
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # replicates that drew only NaN seeds
        for start in range(0, rows, chunk):
            means = np.nanmean(per_seed[start : start + chunk][:, draws], axis=-1)  # (chunk, resamples)
            low[start : start + chunk], high[start : start + chunk] = np.nanpercentile(
                means, [tail, 100 - tail], axis=-1
            )
    return np.where(enough, low, np.nan), np.where(enough, high, np.nan)


@dataclasses.dataclass(frozen=True)
class Curve:
    """One measure of a run against env steps (only the rows where it was measured)."""

    steps: np.ndarray  # (points,)
    mean: np.ndarray  # (points,) the mean over seeds
    low: np.ndarray | None  # (points,) the 95 % bootstrap interval across seeds; None for one seed
    high: np.ndarray | None
    num_seeds: int


@dataclasses.dataclass(frozen=True)
class RunCurves:
    """What ``curve.png`` draws for one run."""

    label: str
    training: Curve | None  # the return of the training episodes (exploring policy)
    evaluation: Curve | None  # the greedy policy's evaluation return, the measure that stops a run
    solved: float | None  # the env's reward threshold


def _curve(rows: list[dict[str, float]], prefix: str, mean_column: str) -> Curve | None:
    steps = np.array([r.get("env_steps", i) for i, r in enumerate(rows)], np.float64)
    columns = seed_columns(rows[0], prefix)
    if columns:
        per_seed = np.array([[r[c] for c in columns] for r in rows], np.float64)  # (rows, seeds)
    elif mean_column in rows[0]:
        per_seed = np.array([[r[mean_column]] for r in rows], np.float64)
    else:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # rows where no seed has a value
        mean = np.nanmean(per_seed, axis=1)
    measured = np.isfinite(mean)
    if not measured.any():
        return None
    if per_seed.shape[1] < 2:
        return Curve(steps[measured], mean[measured], None, None, 1)
    low, high = bootstrap_band(per_seed[measured])
    return Curve(steps[measured], mean[measured], low, high, per_seed.shape[1])


def solved_threshold(env_id: str) -> float | None:
    """The return at which ``env_id`` counts as solved: a JAX env's ``reward_threshold``,
    Gymnasium's ``spec.reward_threshold``; None for Atari and envs without one."""
    from agentax.envs import JAX_ENVS
    from agentax.envs.atari import is_atari_id

    if env_id in JAX_ENVS:
        threshold = getattr(JAX_ENVS[env_id](), "reward_threshold", None)
    elif is_atari_id(env_id):
        return None
    else:
        import gymnasium

        try:
            threshold = gymnasium.spec(env_id).reward_threshold
        except gymnasium.error.Error:
            return None
    return None if threshold is None else float(threshold)


def run_curves(run_dir: str | Path, label: str | None = None) -> RunCurves:
    """The series of ``curve.png`` for one run folder, from metrics.csv and config.json."""
    rows = read_metrics(run_dir)
    if not rows:
        raise UsageError(f"{run_dir}/metrics.csv has no rows yet")
    config = read_config(run_dir)
    return RunCurves(
        label=label or f"{config['algo']} {config['env']} ({Path(run_dir).name})",
        training=_curve(rows, "return_seed", "mean_return"),
        evaluation=_curve(rows, "eval_seed", "eval_return"),
        solved=solved_threshold(str(config["env"])),
    )


def curve_figure(run_dirs: Sequence[str | Path], labels: Sequence[str] | None = None) -> Any:
    """The matplotlib ``Figure`` of :func:`plot_curves` (returned, not saved, so tests can read it).

    For each run: the training episodes' return (solid) and the greedy evaluation's (markers; the
    measure ``--stop-at-return`` compares with the threshold), each the mean over seeds with its
    95 % percentile-bootstrap interval across seeds as a band; the env's solved threshold dashed.
    One run gets two colours (training, evaluation); several runs a colour each.
    """
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    fig = Figure(figsize=(7.5, 4.5), dpi=110)  # no pyplot: no GUI backend, no global figure list
    ax = fig.subplots()
    runs = [run_curves(d, labels[i] if labels else None) for i, d in enumerate(run_dirs)]
    single = len(runs) == 1
    band_seeds: set[int] = set()
    for i, run in enumerate(runs):
        prefix = "" if single else f"{run.label}: "
        for curve, what, style in [
            (run.training, "training episodes", {"linewidth": 1.3}),
            (run.evaluation, "greedy evaluation", {"marker": "o", "markersize": 3.5, "linewidth": 1.6}),
        ]:
            if curve is None:
                continue
            color = f"C{2 * i if what.startswith('training') else 2 * i + 1}" if single else f"C{i}"
            if not single and what.startswith("training"):
                style = {**style, "alpha": 0.55}
            ax.plot(curve.steps, curve.mean, color=color, label=prefix + what, **style)
            if curve.low is not None:
                ax.fill_between(curve.steps, curve.low, curve.high, color=color, alpha=0.2, linewidth=0)
                band_seeds.add(curve.num_seeds)
    for threshold in sorted({r.solved for r in runs if r.solved is not None}):
        ax.axhline(threshold, color="0.35", linestyle="--", linewidth=1.0, label=f"solved ({threshold:g})")
    handles, texts = ax.get_legend_handles_labels()
    for num_seeds in sorted(band_seeds):  # one grey legend entry for the bands of every colour
        handles.append(Patch(color="0.5", alpha=0.3, linewidth=0))
        texts.append(f"band: 95 % bootstrap CI over {num_seeds} seeds")
    if single:
        ax.set_title(runs[0].label, fontsize=10)
    ax.set_xlabel("env steps")
    ax.set_ylabel("episode return")
    ax.grid(alpha=0.3)
    ax.legend(handles, texts, fontsize=8)
    fig.tight_layout()
    return fig


def plot_curves(run_dirs: Sequence[str | Path], out: str | Path, labels: Sequence[str] | None = None) -> Path:
    """Write the learning curves of one or more runs to ``out`` (a PNG); see :func:`curve_figure`."""
    out = Path(out)
    curve_figure(run_dirs, labels).savefig(out)
    return out


def load_policy(run_dir: str | Path) -> tuple[str, Policy]:
    """``(env_id, policy)`` of a trained run: a learning algorithm's (``agentax.train.load_policy``)
    or a policy search's (its module's ``load_policy``)."""
    from agentax.agents import ALGORITHMS

    config = read_config(run_dir)
    algo = config["algo"]
    if algo in ALGORITHMS:
        from agentax.train import load_policy as load_trained

        return config["env"], load_trained(Path(run_dir), config)
    if algo not in SEARCH_MODULES:
        known = ", ".join([*ALGORITHMS, *SEARCH_MODULES])
        raise UsageError(f"{run_dir}: unknown algorithm {algo!r} in config.json; known: {known}")
    module = importlib.import_module(SEARCH_MODULES[algo])
    return config["env"], module.load_policy(Path(run_dir), config)
