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

This module is the store only: it reads and writes the folder. Drawing curve.png is
:mod:`agentax.curves`; rebuilding a run's policy is :func:`agentax.api.restore_policy`.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import datetime
import errno
import io
import json
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

import jax
import numpy as np

from agentax import formats
from agentax.errors import StorageFull, UsageError
from agentax.evaluate import EvalStats
from agentax.report import aggregate

RUN_FILE = "run.toml"
"""The run file (:mod:`agentax.runfile`) every run folder holds beside config.json."""
CHECKPOINT_PREFIX = "ckpt-"
REPLAY_PREFIX = "replay-"

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


@contextlib.contextmanager
def atomic_file(path: Path, needed: int = 0) -> Iterator[BinaryIO]:
    """A file to write ``path`` through: a temporary name in the same folder, fsynced and renamed
    over ``path`` when the block ends; on any error the temporary file goes (a full disk is
    :class:`~agentax.errors.StorageFull`, naming the ``needed`` bytes)."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as error:
        tmp.unlink(missing_ok=True)
        if isinstance(error, OSError) and error.errno in NO_SPACE:
            raise StorageFull(path, needed) from None
        raise


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through :func:`atomic_file`: all of it, or nothing."""
    with atomic_file(path, len(data)) as f:
        f.write(data)


NO_SPACE = (errno.ENOSPC, errno.EDQUOT)
"""The errors of a full disk or quota."""


def write_json(path: Path, obj: Any) -> None:
    """``obj`` as indented JSON, written atomically (numbers from numpy included)."""
    write_atomic(Path(path), (json.dumps(obj, indent=2, default=_json_default) + "\n").encode())


def read_json(path: str | Path) -> Any:
    """A JSON file agentax wrote (a clear error where it is not JSON)."""
    try:
        return json.loads(Path(path).read_text())
    except json.JSONDecodeError as error:
        raise UsageError(f"{path} is not valid JSON ({error}); was it written by agentax?") from None


def run_config(
    algo: str,
    env_id: str,
    preset: str,
    runner_kind: str,
    runner: Any,
    config: dict,
    encoders: dict[str, str] | None = None,
) -> dict:
    """What a trainer's ``config.json`` holds: the algorithm, env, preset, runner and its settings,
    and ``"encoders"`` where the run chose some (key → choice; a run without holds no such key, as
    every folder written before encoders could be chosen)."""
    runner = dataclasses.asdict(runner) if dataclasses.is_dataclass(runner) else dict(runner)
    return {
        "algo": algo,
        "env": env_id,
        "preset": preset,
        "runner_kind": runner_kind,
        "runner": runner,
        "config": config,
        **({"encoders": dict(encoders)} if encoders else {}),
    }


def read_config(run_dir: str | Path) -> dict[str, Any]:
    """The run's ``config.json`` in today's format (:func:`agentax.formats.config_of`: an older one
    migrated, a newer one refused); a clear error for a folder that holds no run."""
    path = Path(run_dir) / "config.json"
    if not path.is_file():
        raise UsageError(f"{run_dir} holds no run (no config.json); give a folder written by agentax train")
    try:
        config = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise UsageError(f"{path} is not valid JSON ({error})") from None
    if not isinstance(config, dict) or "algo" not in config or "env" not in config:
        raise UsageError(f"{path} lacks the 'algo' and 'env' keys of a run's config")
    return formats.config_of(config, run_dir)


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


def load_tree(path: str | Path, target: Any, algo: str = "") -> tuple[Any, dict[str, Any]]:
    """Read a tree saved by :func:`save_tree` into the structure of ``target``; returns ``(tree, meta)``.

    ``target`` may hold arrays or ``jax.ShapeDtypeStruct`` leaves (from ``jax.eval_shape``). A
    checkpoint of an older format is migrated first (:func:`agentax.formats.state_of`; ``algo``
    names the algorithm whose state it holds), one of a newer format is refused. A truncated,
    corrupt or mismatched file raises a :class:`UsageError` naming the file.
    """
    from flax import serialization

    path = Path(path)
    try:
        payload = serialization.msgpack_restore(path.read_bytes())
        meta = json.loads(payload["meta"])
    except Exception as error:  # OSError, msgpack's own (ExtraData, FormatError, ...), a bad meta
        raise UsageError(f"checkpoint {path} is corrupt ({type(error).__name__}: {error})") from None
    formats.check_readable(formats.version_of(meta), path)
    try:
        key_leaves = jax.tree.map(_is_key_like, target)
        plain_target = jax.tree.map(_plain_struct, target)
        state = formats.state_of(payload["state"], meta, algo, path)
        restored = serialization.from_state_dict(plain_target, state)
        expected, actual = jax.tree.leaves(plain_target), jax.tree.leaves(restored)
        if len(expected) != len(actual):
            raise ValueError(f"{len(actual)} arrays where {len(expected)} were expected")
        for want, got in zip(expected, actual, strict=True):
            if tuple(want.shape) != tuple(np.shape(got)) or np.dtype(want.dtype) != np.asarray(got).dtype:
                raise ValueError(
                    f"an array {np.asarray(got).dtype}{list(np.shape(got))} where {want.dtype}"
                    f"{list(want.shape)} was expected"
                )
    except (ValueError, KeyError, TypeError, AttributeError, IndexError) as error:
        raise UsageError(
            f"checkpoint {path} is corrupt or belongs to another configuration ({error})"
        ) from None
    tree = jax.tree.map(
        lambda is_key, x: jax.random.wrap_key_data(np.asarray(x)) if is_key else np.asarray(x),
        key_leaves,
        restored,
    )
    return tree, {k: v for k, v in meta.items() if k != "format"}


def _is_key_like(x: Any) -> bool:
    return jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _plain_struct(x: Any) -> jax.ShapeDtypeStruct:
    if _is_key_like(x):
        data = jax.eval_shape(jax.random.key_data, x)
        return jax.ShapeDtypeStruct(data.shape, data.dtype)
    return jax.ShapeDtypeStruct(np.shape(x), x.dtype)


def checkpoints(run_dir: str | Path, with_replay: bool = False) -> list[Path]:
    """The run's checkpoint files, oldest first; ``with_replay``: only those whose replay buffer
    (:func:`replay_beside`) was saved with them."""
    folder = Path(run_dir) / "checkpoints"
    found = folder.glob(f"{CHECKPOINT_PREFIX}*.msgpack") if folder.is_dir() else []
    found = sorted(found, key=lambda p: int(p.stem.removeprefix(CHECKPOINT_PREFIX)))
    return [p for p in found if replay_beside(p).is_file()] if with_replay else found


def replay_beside(checkpoint: Path) -> Path:
    """The replay buffer saved with ``checkpoints/ckpt-<updates>.msgpack``: ``replay-<updates>.npz``.

    It is written first and the checkpoint after it, so the checkpoint is the commit point: a
    checkpoint whose replay file exists has its complete replay (both are renamed into place), and a
    replay without its checkpoint (the run stopped between the two) is never used."""
    updates = checkpoint.stem.removeprefix(CHECKPOINT_PREFIX)
    return checkpoint.with_name(f"{REPLAY_PREFIX}{updates}.npz")


def latest_checkpoint(run_dir: str | Path) -> Path:
    """The newest checkpoint; a clear error if the run has none."""
    found = checkpoints(run_dir)
    if not found:
        raise UsageError(f"{run_dir} has no checkpoint in {Path(run_dir) / 'checkpoints'}; train it first")
    return found[-1]


def load_checkpoint(
    run_dir: str | Path, target: Any, with_replay: bool = False
) -> tuple[Any, dict[str, Any], Path]:
    """The newest checkpoint that loads into ``target``: ``(tree, meta, path)``; with
    ``with_replay``, the newest that has its replay buffer beside it, when one has (a note on
    stderr says which newer checkpoints it passes over, and when none has, that the replay refills).

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
    if with_replay:
        paired = checkpoints(run_dir, with_replay=True)
        if paired and paired[-1] != found[-1]:
            newer = len(found) - found.index(paired[-1]) - 1
            print(
                f"note: resuming from {paired[-1].name}, the newest checkpoint saved with its replay "
                f"buffer ({newer} newer without one passed over)",
                file=sys.stderr,
            )
        elif not paired:
            print("note: no checkpoint was saved with its replay buffer yet; it refills", file=sys.stderr)
        found = paired or found
    reason = ""
    algo = read_config(run_dir)["algo"] if (Path(run_dir) / "config.json").is_file() else ""
    for i, path in enumerate(reversed(found)):
        try:
            tree, meta = load_tree(path, target, algo)
        except formats.NewerFormat:
            raise
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
        try:
            (path / "checkpoints").mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError, PermissionError) as error:
            blocker = next((p for p in (path, *path.parents) if p.exists() and not p.is_dir()), None)
            why = f"{blocker} is a file, not a folder" if blocker else error.strerror.lower()
            raise UsageError(f"--out {path}: cannot make the run folder there ({why})") from None
        config = {"format": formats.FORMAT, **config}
        write_json(path / "config.json", config)
        return cls(path, config)

    @classmethod
    def open(cls, path: str | Path) -> Run:
        """The run in ``path``, to continue: a config.json of an older format is rewritten in
        today's (its new checkpoints are written in today's format too)."""
        config = read_config(path)
        if formats.version_of(read_json(Path(path) / "config.json")) < formats.FORMAT:
            write_json(Path(path) / "config.json", config)
        return cls(Path(path), config)

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
        meta = {**meta, "format": formats.FORMAT}
        (self.path / "checkpoints").mkdir(exist_ok=True)  # deleted by hand since, say
        try:
            path = save_tree(self.path / "checkpoints" / f"{CHECKPOINT_PREFIX}{updates}.msgpack", tree, meta)
        except StorageFull as full:
            raise StorageFull(full.path, full.needed, self.last_complete()) from None
        for old in checkpoints(self.path)[:-keep]:
            if not replay_beside(old).is_file():  # those with their replay go with it (ReplayCheckpoints)
                old.unlink(missing_ok=True)
        return path

    def last_complete(self) -> str:
        """What a failed write leaves to resume from, as a phrase for its error message."""
        kept = checkpoints(self.path)
        if not kept:
            return "the run has no checkpoint yet"
        return (
            f"the last complete checkpoint, {kept[-1]}, is kept: free space, then agentax train "
            f"--resume {self.path}"
        )

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
