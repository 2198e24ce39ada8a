"""One training's shell, written once for every runner: keys, a fresh or restored state, the run
logger, rows, the stop-at-return check, checkpoints (with the replay beside them) and the final
evaluation (:func:`conclude`). :class:`Session` holds them for the runners that step their envs
outside one program; the compiled runner and the workers call the pieces.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import numpy as np

from agentax.agents.protocol import Agent
from agentax.curves import plot_curves
from agentax.errors import StorageFull
from agentax.evaluate import EvalStats
from agentax.policies import Policy
from agentax.replay.files import restore_replay, save_replay
from agentax.runners.logger import RunLogger
from agentax.runs import CHECKPOINT_PREFIX, REPLAY_PREFIX, Run, checkpoints, load_checkpoint, replay_beside

EVAL_SEED_OFFSET = 123_457
EVAL_KEY_OFFSET = 1_000_003
"""Evaluation never repeats training episodes: the final evaluation of a host run of seed ``s`` plays
from seed ``s + EVAL_SEED_OFFSET``; the compiled program's evaluation ``i`` of a seed from
``fold_in(key(seed), EVAL_KEY_OFFSET + i)``."""
SOLVED = ("solved_env_steps", "solved_seconds")  # a run stopped at stop_at_return (eval.json)
TIMINGS = ("compile_seconds", "train_seconds")  # the compiled runner's timings (eval.json)


@dataclass
class TrainResult:
    """What a training did: the final state (a leading seed axis on the compiled runner), its
    counts, rows, final evaluation and timings."""

    state: Any
    updates: int
    env_steps: float
    eval: dict[str, Any]
    rows: list[dict[str, float]] = field(default_factory=list)
    solved_env_steps: float | None = None
    solved_seconds: float | None = None
    compile_seconds: float = 0.0
    train_seconds: float = 0.0
    final_returns: tuple[Any, Any] | None = None
    """the compiled runner's final evaluation: returns and lengths ``[seeds, episodes]``"""
    policy: Policy | None = None
    """the greedy policy of the best seed (None where the agents stayed in other processes)"""


def agent_keys(seed: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(init_key, learner_key, actors_key)`` of a run (actor ``i`` folds its key from the last)."""
    return tuple(jax.random.split(jax.random.key(seed), 3))


@jax.jit
def split_key(key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``jax.random.split(key)`` as a pair, in one compiled call (op by op: three, ~0.1 ms a step)."""
    new, sub = jax.random.split(key)
    return new, sub


def checkpoint_target(agent: Agent) -> Any:
    """The shapes of a checkpoint of these runners: ``(agent state, learner key)``."""
    return jax.eval_shape(lambda key: (agent.init(key), key), jax.random.key(0))


def final_evaluation(evaluator: Any, state: Any, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The final evaluation's returns and lengths: fresh episodes, from ``seed + EVAL_SEED_OFFSET``."""
    return evaluator(state, seed=seed + EVAL_SEED_OFFSET)


def row_of(
    env_steps: float, updates: int, per_seed_returns: Any, steps_per_second: float, per_seed_evals: Any = None
) -> dict[str, float]:
    """A runner's columns of one row: the mean return per seed of the episodes finished since the last
    row (NaN: none) and, where the row evaluated, each seed's evaluation mean."""
    per_seed = np.asarray(per_seed_returns, dtype=np.float64)
    row = {
        "env_steps": env_steps,
        "updates": updates,
        "mean_return": float(np.nanmean(per_seed)) if np.isfinite(per_seed).any() else math.nan,
        **{f"return_seed{k}": float(r) for k, r in enumerate(per_seed)},
        "eval_return": math.nan,
    }
    if per_seed_evals is not None:
        row["eval_return"] = float(np.mean(per_seed_evals))
        row.update({f"eval_seed{k}": float(e) for k, e in enumerate(per_seed_evals)})
    return {**row, "steps_per_second": steps_per_second}


def open_logger(
    run: Run | None,
    total_steps: float,
    done_steps: float,
    runner: Any,
    elapsed_before: float,
    progress: bool,
    description: str = "training",
) -> RunLogger:
    """The run logger of a training (a context manager: Ctrl-C becomes ``TrainingInterrupted``)."""
    return RunLogger(
        run,
        total_steps,
        done_steps=done_steps,
        progress=progress,
        description=description,
        checkpoint_every_seconds=runner.checkpoint_every_seconds,
        elapsed_before=elapsed_before,
    )


def conclude(run: Run | None, result: TrainResult, returns: Any, lengths: Any, *written: str, **extra: Any):
    """``result`` with its final evaluation (``returns``, ``lengths``: ``[seeds, episodes]``) in
    ``result.eval``; with a ``run``, eval.json (the counts, ``written`` fields, ``extra``), curve.png."""
    returns, lengths = np.atleast_2d(returns), np.atleast_2d(lengths)
    fields = {name: getattr(result, name) for name in written}
    extra = {"env_steps": result.env_steps, "updates": result.updates, **fields, **extra}
    if run is None:
        stats = vars(EvalStats.from_returns(returns.ravel(), lengths.ravel()))
        result.eval = {**stats, "per_seed_mean": returns.mean(axis=1).tolist(), **extra}
        return result
    result.eval = run.write_eval(returns, lengths, **extra)
    plot_curves([run.path], run.path / "curve.png")
    run.close()
    return result


class ReplayCheckpoints:
    """The replay buffer saved as ``checkpoints/replay-<updates>.npz`` before its checkpoint, which
    commits the pair: with the first checkpoint, then at most every ``every_seconds``, and at the
    end; the two newest pairs are kept."""

    KEEP = 2

    def __init__(self, run: Run | None, replay: Any, enabled: bool, every_seconds: float):
        self.run, self.replay = run, replay
        self.enabled = enabled and run is not None
        self.every_seconds, self.saved_at = every_seconds, None

    def before_checkpoint(self, updates: int, force: bool) -> None:
        """Save the replay of checkpoint ``updates`` when due (``force``: now); its checkpoint follows."""
        first = self.saved_at is None  # the first checkpoint has its replay too (small then)
        due = force or first or time.perf_counter() - self.saved_at >= self.every_seconds
        if not (self.enabled and due):
            return
        checkpoint = self.run.path / "checkpoints" / f"{CHECKPOINT_PREFIX}{updates}.msgpack"
        try:
            save_replay(self.replay, replay_beside(checkpoint))
        except StorageFull as full:
            raise StorageFull(full.path, full.needed, self.run.last_complete()) from None
        self.saved_at = time.perf_counter()
        paired = {replay_beside(p) for p in checkpoints(self.run.path, with_replay=True)[-self.KEEP :]}
        for old in (self.run.path / "checkpoints").glob(f"{REPLAY_PREFIX}*.npz"):
            if old not in paired and old != replay_beside(checkpoint):
                old.unlink(missing_ok=True)  # older pairs, and a replay whose checkpoint never came

    def restore(self, checkpoint: Path) -> None:
        """Load the replay saved with ``checkpoint`` (the one :func:`restore` resumed from), if any."""
        if self.enabled and replay_beside(checkpoint).is_file():
            restore_replay(self.replay, replay_beside(checkpoint))


class Session:
    """The shell of one training: ``state``, ``learner_key``, ``updates`` and ``env_steps`` are where
    the run starts (fresh or restored), ``meta`` what its checkpoint said, ``actors_key`` its actors'."""

    def __init__(
        self,
        agent: Agent,
        run: Run | None,
        runner: Any,
        evaluator: Any,
        *,
        resume: bool = False,
        with_replay: bool = False,
    ):
        self.agent, self.run, self.runner, self.evaluator = agent, run, runner, evaluator
        init_key, self.learner_key, self.actors_key = agent_keys(runner.seed)
        self.meta: dict[str, Any] = {"env_steps": 0, "updates": 0, "elapsed": 0.0}
        if resume:  # the newest loadable checkpoint (with_replay: saved with its replay); rows trimmed
            target = checkpoint_target(agent)
            (self.state, self.learner_key), meta, path = load_checkpoint(run.path, target, with_replay)
            run.truncate_metrics(meta["env_steps"])
            self.meta = {**meta, "checkpoint": path}  # the file it came from (its replay is beside it)
        else:
            self.state = agent.init(init_key)
        self.updates, self.env_steps = int(self.meta["updates"]), int(self.meta["env_steps"])
        self.before_checkpoint = None  # what must be on disk before a checkpoint commits (the replay)
        self.next_log = self.env_steps + runner.log_every_steps
        self.logger: RunLogger | None = None
        self.solved: tuple[float, float, tuple[np.ndarray, np.ndarray]] | None = None
        """once the run stopped solved: its env steps, seconds and final evaluation"""

    def keep_replay(self, replay: Any) -> None:
        """Keep ``replay`` beside the checkpoints (:class:`ReplayCheckpoints`), restored on resume."""
        every = self.runner.replay_checkpoint_every_seconds
        self.keep(ReplayCheckpoints(self.run, replay, self.runner.checkpoint_replay, every))

    def keep(self, kept: Any) -> None:
        """Save ``kept`` before each checkpoint (``kept.before_checkpoint(updates, force)``), restored
        from the checkpoint this run resumed from (``kept.restore(path)``)."""
        self.before_checkpoint = kept.before_checkpoint
        if "checkpoint" in self.meta:  # a resumed run
            kept.restore(self.meta["checkpoint"])

    def begin(self, description: str, progress: bool = False) -> RunLogger:
        """The run logger (a context manager), its progress bar named ``description``."""
        elapsed = float(self.meta["elapsed"])
        self.logger = open_logger(
            self.run, self.agent.total_steps, self.env_steps, self.runner, elapsed, progress, description
        )
        self.steps_at_log, self.time_at_log = self.env_steps, time.perf_counter()
        return self.logger

    def row_due(self, env_steps: int, final: bool) -> bool:
        """Whether a row is due at ``env_steps`` (always at the end); books the next one if so."""
        if env_steps < self.next_log and not final:
            return False
        self.next_log += self.runner.log_every_steps
        return True

    def log_row(
        self,
        state: Any,
        learner_key: jax.Array,
        env_steps: int,
        updates: int,
        returns: list[float],
        metrics: dict[str, Any],
        *,
        final: bool,
        extra: dict[str, float] | None = None,
        counts: dict[str, int] | None = None,
    ) -> bool:
        """Write the row :meth:`row_due` booked, checkpoint when due (``counts`` join the checkpoint's
        meta); whether the run reached ``stop_at_return``."""
        metrics = jax.device_get(metrics)  # waits for the last learning step: speeds count it
        now = time.perf_counter()
        speed = (env_steps - self.steps_at_log) / max(now - self.time_at_log, 1e-9)
        finished = [float(np.mean(returns)) if returns else math.nan]
        row = {**row_of(env_steps, updates, finished, speed), **(extra or {})}
        solved = False
        if self.runner.stop_at_return is not None:  # the run may stop: evaluate, and confirm a solve
            row["eval_return"] = float(np.mean(self.evaluator(state)[0]))
            solved = row["eval_return"] >= self.runner.stop_at_return and self.confirmed(state, env_steps)
        self.logger.log(row, metrics)
        self.steps_at_log, self.time_at_log = env_steps, time.perf_counter()
        meta = {
            "env_steps": env_steps,
            "updates": updates,
            **(counts or {}),
            "elapsed": self.logger.wall_seconds(),
        }
        self.logger.checkpoint(
            updates, (state, learner_key), meta, force=final or solved, before=self.before_checkpoint
        )
        return solved

    def confirmed(self, state: Any, env_steps: int) -> bool:
        """Whether the final evaluation reaches ``stop_at_return`` too: then the run is solved, with
        that evaluation as its final one."""
        returns, lengths = final_evaluation(self.evaluator, state, self.runner.seed)
        if np.mean(returns) < self.runner.stop_at_return:
            return False
        self.solved = (env_steps, self.logger.wall_seconds(), (returns, lengths))
        return True

    def finish(self, state: Any, env_steps: int, updates: int) -> TrainResult:
        """The final evaluation on fresh episodes (eval.json, curve.png) and the result."""
        train_seconds = time.perf_counter() - self.logger.start
        solved: dict[str, float] = {}
        if self.solved is None:
            returns, lengths = final_evaluation(self.evaluator, state, self.runner.seed)
        else:
            solved["solved_env_steps"], solved["solved_seconds"], (returns, lengths) = self.solved
        self.evaluator.close()
        result = TrainResult(
            state, updates, env_steps, {}, self.logger.rows, train_seconds=train_seconds, **solved
        )
        result.policy = self.agent.greedy_policy(state)
        return conclude(self.run, result, returns[None], lengths[None], *solved)
