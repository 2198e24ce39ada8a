"""The run logger every runner writes through: rows, progress bar, checkpoints.

It checks the agent's metrics and the checkpointed parameters are finite (else
:class:`~agentax.errors.TrainingDiverged`), writes rows to metrics.csv and TensorBoard, and as a
context manager turns Ctrl-C into :class:`~agentax.errors.TrainingInterrupted`. With ``run=None``
it only keeps the rows and checks.
"""

from __future__ import annotations

import datetime
import math
import sys
import time
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from agentax.errors import TrainingDiverged, TrainingInterrupted
from agentax.runs import Run

DIVERGED_HINT = "lower the learning rate or clip the gradients (--max-grad-norm)"


def check_finite_tree(tree: Any, env_steps: float, last_checkpoint: str | None) -> None:
    """Raise ``TrainingDiverged`` if any floating-point leaf of ``tree`` (parameters) is not finite."""
    for leaf in jax.tree.leaves(tree):
        if jax.dtypes.issubdtype(getattr(leaf, "dtype", None), np.floating) and not np.all(
            np.isfinite(np.asarray(leaf))
        ):
            raise TrainingDiverged(_diverged("non-finite parameters", env_steps, last_checkpoint))


def _diverged(what: str, env_steps: float, last_checkpoint: str | None) -> str:
    kept = f"; the run keeps its last finite checkpoint {last_checkpoint}" if last_checkpoint else ""
    return f"{what} at env step {env_steps:,.0f}: {DIVERGED_HINT}{kept}"


def time_left(
    total_steps: float, done_steps: float, steps_per_second: float, now: float | None = None
) -> str:
    """``"left 19:30:05, ends 17:42"`` (the end's date where it is not today) at ``steps_per_second``;
    ``""`` before a speed is known."""
    remaining = max(total_steps - done_steps, 0.0)
    if not steps_per_second > 0 or not math.isfinite(steps_per_second):
        return ""
    seconds = round(remaining / steps_per_second)
    hours, rest = divmod(seconds, 3600)
    left = f"{hours}:{rest // 60:02d}:{rest % 60:02d}"
    start = time.time() if now is None else now
    end = datetime.datetime.fromtimestamp(start + seconds)
    same_day = end.date() == datetime.datetime.fromtimestamp(start).date()
    when = end.strftime("%H:%M") if same_day else end.strftime("%b %d %H:%M")
    return f"left {left}, ends {when}"


class Progress:
    """A rich progress bar over env steps, with the latest return and runner figures (a no-op if off)."""

    def __init__(self, enabled: bool, total_steps: float, done_steps: float, description: str = "training"):
        self.bar = None
        if not enabled:
            return
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        self.bar = Progress(
            TextColumn(f"[bold]{description}"),
            BarColumn(),
            TextColumn("{task.completed:,.0f}/{task.total:,.0f} env steps"),
            TextColumn("{task.fields[speed]} steps/s"),
            TextColumn("return {task.fields[ret]}"),
            TextColumn("{task.fields[extra]}"),
            TimeElapsedColumn(),
            TextColumn("{task.fields[left]}"),
            console=Console(file=sys.stderr),
        )
        self.task = self.bar.add_task(
            "train", total=total_steps, completed=done_steps, speed="-", ret="-", extra="", left=""
        )
        self.total_steps = total_steps
        self.bar.start()

    def update(self, env_steps: float, speed: float, mean_return: float, extra: str = "") -> None:
        if self.bar is not None:
            ret = "-" if math.isnan(mean_return) else f"{mean_return:.1f}"
            left = time_left(self.total_steps, env_steps, speed)
            self.bar.update(
                self.task, completed=env_steps, speed=f"{speed:,.0f}", ret=ret, extra=extra, left=left
            )

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()


BAR_COLUMNS = ("actor_wait_fraction", "learner_wait_fraction", "policy_lag")  # on the bar too


class RunLogger:
    """Writes one training's rows and checkpoints into ``run`` (if given); ``elapsed_before`` is the
    wall time of the earlier part of a resumed run."""

    def __init__(
        self,
        run: Run | None,
        total_steps: float,
        *,
        done_steps: float = 0,
        progress: bool = False,
        description: str = "training",
        checkpoint_every_seconds: float = 30.0,
        elapsed_before: float = 0.0,
    ):
        self.run = run
        self.rows: list[dict[str, float]] = []
        self.checkpoint_every_seconds = checkpoint_every_seconds
        self.elapsed_before = elapsed_before
        self.start = time.perf_counter()
        self.last_checkpoint_time = self.start
        self.last_checkpoint: str | None = None
        self.bar = Progress(progress, total_steps, done_steps, description)

    def __enter__(self) -> RunLogger:
        return self

    def __exit__(self, kind, error, traceback) -> None:
        self.bar.close()
        if kind is not None and issubclass(kind, KeyboardInterrupt) and kind is not TrainingInterrupted:
            if self.run is not None:
                self.run.close()
                raise TrainingInterrupted(str(self.run.path)) from None

    def wall_seconds(self) -> float:
        """Seconds of training so far, the earlier part of a resumed run included."""
        return self.elapsed_before + time.perf_counter() - self.start

    def log(self, row: dict[str, float], metrics: dict[str, Any]) -> dict[str, float]:
        """Check ``metrics`` are finite (``TrainingDiverged`` names the first that is not), then write
        ``row`` + metrics (+ ``wall_seconds``); returns it."""
        env_steps = float(row["env_steps"])
        for name, value in metrics.items():
            if not np.all(np.isfinite(np.asarray(value, np.float64))):
                raise TrainingDiverged(_diverged(f"non-finite {name}", env_steps, self.last_checkpoint))
        row = {
            **row,
            "wall_seconds": self.wall_seconds(),
            **{k: float(np.mean(v)) for k, v in metrics.items()},
        }
        self.rows.append(row)
        if self.run is not None:
            self.run.log(row)
        extra = "  ".join(f"{name.replace('_', ' ')} {row[name]:,.2f}" for name in BAR_COLUMNS if name in row)
        self.bar.update(
            env_steps, row.get("steps_per_second", math.nan), row.get("mean_return", math.nan), extra
        )
        return row

    def checkpoint_due(self) -> bool:
        """Whether :meth:`checkpoint` would save now unforced."""
        return self.run is not None and (
            self.last_checkpoint is None
            or time.perf_counter() - self.last_checkpoint_time >= self.checkpoint_every_seconds
        )

    def checkpoint(
        self,
        step: int,
        tree: Any,
        meta: dict[str, Any],
        *,
        force: bool = False,
        before: Callable[[int, bool], Any] | None = None,
    ) -> bool:
        """Save ``tree`` (finite only) at the first row, then every ``checkpoint_every_seconds`` or when
        ``force``d, ``before(step, force)`` first (what must be on disk first); whether it saved."""
        if self.run is None or not (force or self.checkpoint_due()):
            return False
        now = time.perf_counter()
        check_finite_tree(tree, meta.get("env_steps", 0), self.last_checkpoint)
        if before is not None:
            before(step, force)
        path = self.run.save_checkpoint(step, tree, meta)
        self.last_checkpoint, self.last_checkpoint_time = path.name, now
        return True
