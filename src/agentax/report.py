"""Comparing runs honestly across seeds: IQM, mean and median with stratified-bootstrap intervals,
and the probability of improvement, after Agarwal et al. (2021), *Deep Reinforcement Learning at
the Edge of the Statistical Precipice* (NeurIPS), and their library ``rliable``.

A run's score is the final evaluation's mean return of each seed (``eval.json``'s ``per_seed``).
Scores come in *strata* (rliable's tasks): here one per env, holding the seeds of every run on that
env. All functions are pure NumPy; ``rliable`` itself is not used (it fails on import here, and its
``arch`` dependency is only needed for the bootstrap, which takes a dozen lines).

- **IQM** (interquartile mean, §4.1): the mean of the middle 50 % of the scores, pooled over
  strata, cutting ``floor(n / 4)`` scores at each end exactly as ``scipy.stats.trim_mean(x, 0.25)``
  (what rliable calls). Robust to a few outlying seeds, and far less noisy than the median.
- **Stratified bootstrap** (§A.3): resample the seeds *within* each stratum with replacement,
  recompute the statistic, repeat; the 95 % interval is the 2.5 and 97.5 percentiles of the
  replicates (rliable's default "percentile" method). Seeded, so a report is reproducible.
- **Probability of improvement** (§4.3): ``P(X > Y) = 1/K Σ_k 1/(M N) Σ_m Σ_n S(x_mk, y_nk)`` over
  the K strata both sides share, with ``S(x, y) = 1`` if ``x > y``, ``1/2`` if equal, else 0 (the
  Mann-Whitney U statistic over ``M N``); its interval resamples X's and Y's seeds independently
  in each stratum.

Rejected: a normal-approximation interval (``mean ± 1.96 σ/√n``, used for the learning curves):
with 3-10 seeds and skewed returns it is neither honest nor defined for the IQM and the median.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

Strata = Sequence[np.ndarray] | Sequence[float] | np.ndarray
"""Scores: one flat sequence of numbers (one stratum) or a sequence of strata, each 1-D."""

CONFIDENCE = 0.95
AGGREGATE_REPS = 50_000  # rliable's default for aggregate metrics
IMPROVEMENT_REPS = 2_000  # rliable's default for the probability of improvement


def iqm(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean along ``axis``: drop ``floor(n/4)`` scores at each end, average the rest."""
    scores = np.sort(np.asarray(scores, np.float64), axis=axis)
    n = scores.shape[axis]
    cut = int(0.25 * n)
    return np.take(scores, np.arange(cut, n - cut), axis=axis).mean(axis=axis)


def mean(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.mean(np.asarray(scores, np.float64), axis=axis)


def median(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.median(np.asarray(scores, np.float64), axis=axis)


AGGREGATES: dict[str, Callable[..., np.ndarray]] = {"iqm": iqm, "mean": mean, "median": median}
"""The aggregate statistics a report gives, each ``f(scores, axis=-1)``, in their report order."""


def _strata(strata: Strata) -> list[np.ndarray]:
    """Scores as a list of non-empty 1-D float arrays: a flat sequence of numbers is one stratum,
    anything else a sequence of strata (a 2-D array: one row per stratum)."""
    if all(np.ndim(s) == 0 for s in strata):
        strata = [strata]
    out = [np.asarray(s, np.float64).ravel() for s in strata]
    if not out or any(s.size == 0 for s in out):
        raise ValueError("every stratum needs at least one score")
    return out


def _resample(stratum: np.ndarray, reps: int, rng: np.random.Generator) -> np.ndarray:
    """``reps`` bootstrap samples of ``stratum``: ``[reps, n]``."""
    return stratum[rng.integers(0, stratum.size, size=(reps, stratum.size))]


def _percentile_interval(replicates: np.ndarray, confidence: float) -> tuple[float, float]:
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(replicates, [tail, 100 - tail])
    return float(low), float(high)


def bootstrap_ci(
    strata: Strata,
    statistic: Callable[..., np.ndarray] = iqm,
    *,
    reps: int = AGGREGATE_REPS,
    confidence: float = CONFIDENCE,
    seed: int = 0,
) -> tuple[float, float]:
    """Stratified-bootstrap percentile interval of ``statistic`` over the pooled scores of ``strata``.

    Each replicate resamples every stratum's scores with replacement (keeping its size) and pools
    them; ``statistic(samples [reps, N], axis=-1)`` is evaluated for all replicates at once.
    """
    rng = np.random.default_rng(seed)
    samples = np.concatenate([_resample(s, reps, rng) for s in _strata(strata)], axis=1)  # (reps, N)
    return _percentile_interval(statistic(samples, axis=-1), confidence)


def aggregate(
    strata: Strata,
    *,
    reps: int = AGGREGATE_REPS,
    confidence: float = CONFIDENCE,
    seed: int = 0,
) -> dict[str, float | list[float]]:
    """``{"iqm", "iqm_ci", "mean", "mean_ci", "median", "median_ci"}`` of the pooled scores of ``strata``."""
    strata = _strata(strata)
    pooled = np.concatenate(strata)
    result: dict[str, float | list[float]] = {}
    for name, statistic in AGGREGATES.items():
        result[name] = float(statistic(pooled))
        interval = bootstrap_ci(strata, statistic, reps=reps, confidence=confidence, seed=seed)
        result[f"{name}_ci"] = list(interval)
    return result


def _improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``P(X > Y)`` of one stratum over the last two axes: x ``[..., M]``, y ``[..., N]`` -> ``[...]``."""
    x, y = x[..., :, None], y[..., None, :]
    return np.mean((x > y) + 0.5 * (x == y), axis=(-2, -1))


def probability_of_improvement(x_strata: Strata, y_strata: Strata) -> float:
    """``P(X > Y)``: the chance that a seed of X beats a seed of Y on the same stratum, averaged over the
    strata (``x_strata[k]`` and ``y_strata[k]`` are the two sides' scores on stratum k)."""
    xs, ys = _strata(x_strata), _strata(y_strata)
    if len(xs) != len(ys):
        raise ValueError(f"{len(xs)} strata of X against {len(ys)} of Y; pair them by stratum")
    return float(np.mean([_improvement(x, y) for x, y in zip(xs, ys, strict=True)]))


def probability_of_improvement_ci(
    x_strata: Strata,
    y_strata: Strata,
    *,
    reps: int = IMPROVEMENT_REPS,
    confidence: float = CONFIDENCE,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile interval of :func:`probability_of_improvement`, X's and Y's seeds resampled
    independently within each stratum (rliable's ``StratifiedIndependentBootstrap``)."""
    xs, ys = _strata(x_strata), _strata(y_strata)
    if len(xs) != len(ys):
        raise ValueError(f"{len(xs)} strata of X against {len(ys)} of Y; pair them by stratum")
    rng = np.random.default_rng(seed)
    per_stratum = [
        _improvement(_resample(x, reps, rng), _resample(y, reps, rng)) for x, y in zip(xs, ys, strict=True)
    ]  # K arrays of [reps]
    return _percentile_interval(np.mean(per_stratum, axis=0), confidence)


# Comparing groups of runs (``agentax report``).


def compare(
    groups: dict[str, dict[str, Sequence[float]]],
    *,
    reps: int = AGGREGATE_REPS,
    confidence: float = CONFIDENCE,
    seed: int = 0,
) -> dict:
    """The report of ``groups`` (label -> env id -> final score of each seed; an env is a stratum).

    ``{"runs": [{"label", "seeds", "envs", "iqm", "iqm_ci", "mean", "mean_ci", "median",
    "median_ci"}], "probability_of_improvement": {"x", "y", "envs", "probability", "ci"} or None}``.
    The probability of improvement, ``P(x > y)`` of the first group over the second, is given for
    exactly two groups that share at least one env (it compares seeds on the same env only).
    """
    runs = [
        {
            "label": label,
            "seeds": sum(len(scores) for scores in by_env.values()),
            "envs": list(by_env),
            **aggregate(list(by_env.values()), reps=reps, confidence=confidence, seed=seed),
        }
        for label, by_env in groups.items()
    ]
    improvement = None
    if len(groups) == 2:
        (x_label, x_envs), (y_label, y_envs) = groups.items()
        shared = [env for env in x_envs if env in y_envs]
        if shared:
            xs, ys = [x_envs[env] for env in shared], [y_envs[env] for env in shared]
            interval = probability_of_improvement_ci(
                xs, ys, reps=min(reps, IMPROVEMENT_REPS), confidence=confidence, seed=seed
            )
            improvement = {
                "x": x_label,
                "y": y_label,
                "envs": shared,
                "probability": probability_of_improvement(xs, ys),
                "ci": list(interval),
            }
    return {"runs": runs, "probability_of_improvement": improvement}


def plot_intervals(report: dict, path: str | Path) -> Path:
    """Write the point estimates and intervals of a :func:`compare` report as a PNG (one panel per
    aggregate, one row per group, as rliable's ``plot_interval_estimates``); returns the path."""
    from matplotlib.figure import Figure

    runs = report["runs"]
    fig = Figure(figsize=(3.2 * len(AGGREGATES), 0.9 + 0.45 * len(runs)), dpi=110)
    axes = fig.subplots(1, len(AGGREGATES), sharey=True, squeeze=False)[0]
    rows = np.arange(len(runs))[::-1]  # the first group on top
    for ax, name in zip(axes, AGGREGATES, strict=True):
        for row, run, color in zip(rows, runs, _colors(len(runs)), strict=True):
            low, high = run[f"{name}_ci"]
            ax.barh(row, high - low, left=low, height=0.6, color=color, alpha=0.6)
            ax.plot([run[name]] * 2, [row - 0.3, row + 0.3], color="black", linewidth=1.5)
        ax.set_title({"iqm": "IQM"}.get(name, name))
        ax.set_xlabel("final return")
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(rows, [run["label"] for run in runs])
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    return path


def _colors(n: int) -> list:
    from matplotlib import colormaps

    return [colormaps["tab10"](i % 10) for i in range(n)]
