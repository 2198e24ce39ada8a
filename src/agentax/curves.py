"""Learning curves: curve.png of a run, or of several runs side by side (``agentax plot``).

Each measure (the training episodes' return, the greedy evaluation's) is the mean over seeds with its
95 % percentile-bootstrap interval across seeds, read from the run folder's metrics.csv
(:mod:`agentax.runs`); the env's solved threshold is drawn dashed.
"""

from __future__ import annotations

import dataclasses
import threading
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from agentax.errors import UsageError
from agentax.runs import read_config, read_metrics, seed_columns

BOOTSTRAP_RESAMPLES = 2_000


def preload_plotting() -> None:
    """Import matplotlib in a thread now, so that writing curve.png later costs no import.

    matplotlib's import takes ~0.5 s, a fifth of a warm ``agentax train``. Started while XLA
    compiles or runs (which releases the GIL), the import overlaps with it.
    """

    def load() -> None:
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
