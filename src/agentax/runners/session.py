"""One training's shell, written once for the runners that step their envs outside one program.

The host, parallel, Ray and compiled Atari runners differ in how they collect and learn; what is
around that is the same and lives here: the keys of a run (:func:`agent_keys`), a fresh agent or
the state of the newest usable checkpoint, the run logger (rows, TensorBoard, the progress bar),
the row schedule (a row every ``log_every_steps`` env steps, so the same seed gives the same rows),
the stop-at-return check, checkpoints by time (with the replay buffer committed by them) and the
final evaluation, with one seed rule, into one :class:`TrainResult`. The compiled runner keeps its
own loop around its one program, but logs through the same :class:`~agentax.runners.logger.RunLogger`
and returns the same result.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import jax
import numpy as np

from agentax.agents.protocol import Agent
from agentax.policies import Policy
from agentax.runners.logger import RunLogger
from agentax.runs import Run, load_checkpoint

EVAL_SEED_OFFSET = 123_457
"""The final evaluation of a run with seed ``s`` plays its episodes from seed ``s + 123,457``, far
from the seeds of its own envs (``s + 1000 i``), so no evaluation episode repeats a training one.
(The compiled runner evaluates inside its program on keys folded from each seed's key with
``compiled.EVAL_KEY_OFFSET``: the same separation in the key space.)"""


@dataclass
class TrainResult:
    """What a training did: the final state (with a leading seed axis on the compiled runner), its
    counts, the rows it logged, the final evaluation and, for the compiled runner, its timings."""

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
    init_key, learner_key, actors_key = jax.random.split(jax.random.key(seed), 3)
    return init_key, learner_key, actors_key


def checkpoint_target(agent: Agent) -> Any:
    """The shapes of a checkpoint of these runners: ``(agent state, learner key)``."""
    return jax.eval_shape(lambda key: (agent.init(key), key), jax.random.key(0))


def restore(agent: Agent, run: Run, with_replay: bool = False) -> tuple[Any, jax.Array, dict[str, Any]]:
    """``(agent state, learner key, meta)`` of the run's newest loadable checkpoint (``with_replay``:
    of the newest saved with its replay buffer); trims metrics.csv. ``meta["checkpoint"]`` is the
    file it came from."""
    (state, learner_key), meta, path = load_checkpoint(run.path, checkpoint_target(agent), with_replay)
    run.truncate_metrics(meta["env_steps"])
    return state, learner_key, {**meta, "checkpoint": path}


def evaluated_if_stopping(row: dict[str, float], runner: Any, evaluator: Any, state: Any) -> bool:
    """When the run may stop early, evaluate the greedy policy into ``row["eval_return"]``; whether
    it reached ``runner.stop_at_return``."""
    if runner.stop_at_return is None:
        return False
    row["eval_return"] = float(np.mean(evaluator(state)[0]))
    return row["eval_return"] >= runner.stop_at_return


def final_evaluation(evaluator: Any, state: Any, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The final evaluation's returns and lengths: fresh episodes, from ``seed + EVAL_SEED_OFFSET``."""
    return evaluator(state, seed=seed + EVAL_SEED_OFFSET)


def row_of(
    env_steps: int, updates: int, finished_returns: list[float], steps_per_second: float
) -> dict[str, float]:
    """A runner's bookkeeping for one metrics row (the agent's metrics join it in the logger)."""
    mean_return = float(np.mean(finished_returns)) if finished_returns else math.nan
    return {
        "env_steps": env_steps,
        "updates": updates,
        "mean_return": mean_return,
        "return_seed0": mean_return,
        "eval_return": math.nan,
        "steps_per_second": steps_per_second,
    }


class Session:
    """The shell of one training (see the module docstring). After construction ``state``,
    ``learner_key``, ``updates`` and ``env_steps`` are where the run starts (fresh or restored),
    ``meta`` is what its checkpoint said, and ``actors_key`` seeds its actors; :meth:`begin` opens
    the run logger once the runner can name what it runs."""

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
        if resume:
            self.state, self.learner_key, self.meta = restore(agent, run, with_replay)
        else:
            self.state = agent.init(init_key)
        self.updates, self.env_steps = int(self.meta["updates"]), int(self.meta["env_steps"])
        self.before_checkpoint = None  # what must be on disk before a checkpoint commits (the replay)
        self.next_log = self.env_steps + runner.log_every_steps
        self.logger: RunLogger | None = None
        self.solved: tuple[float, float, tuple[np.ndarray, np.ndarray]] | None = None
        """once the run stopped solved: its env steps, seconds and final evaluation"""

    def begin(self, description: str, progress: bool = False) -> RunLogger:
        """The run logger (a context manager: Ctrl-C becomes ``TrainingInterrupted``), its progress
        bar named ``description``; the first row's speed counts from here."""
        self.logger = RunLogger(
            self.run,
            self.agent.total_steps,
            done_steps=self.env_steps,
            progress=progress,
            description=description,
            checkpoint_every_seconds=self.runner.checkpoint_every_seconds,
            elapsed_before=float(self.meta["elapsed"]),
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
        """Write the row that :meth:`row_due` booked and checkpoint when due (``counts`` join the
        checkpoint's meta); whether the run reached ``stop_at_return``."""
        metrics = jax.device_get(metrics)  # waits for the last learning step: speeds count it
        now = time.perf_counter()
        speed = (env_steps - self.steps_at_log) / max(now - self.time_at_log, 1e-9)
        row = {**row_of(env_steps, updates, returns, speed), **(extra or {})}
        solved = evaluated_if_stopping(row, self.runner, self.evaluator, state) and self.confirmed(
            state, env_steps
        )
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
        """Whether the final evaluation reaches ``stop_at_return`` too, as the row's did: only then is
        the run solved (and stops), with that evaluation as its final one; else it trains on."""
        returns, lengths = final_evaluation(self.evaluator, state, self.runner.seed)
        if np.mean(returns) < self.runner.stop_at_return:
            return False
        self.solved = (env_steps, self.logger.wall_seconds(), (returns, lengths))
        return True

    def finish(self, state: Any, env_steps: int, updates: int) -> TrainResult:
        """The final evaluation on fresh episodes (eval.json, curve.png) and the result;
        ``train_seconds`` is the training loop's, to its last row and checkpoint."""
        train_seconds = time.perf_counter() - self.logger.start
        solved: dict[str, float] = {}
        if self.solved is None:
            returns, lengths = final_evaluation(self.evaluator, state, self.runner.seed)
        else:
            solved["solved_env_steps"], solved["solved_seconds"], (returns, lengths) = self.solved
        self.evaluator.close()
        evaluation = self.logger.finish(
            returns[None], lengths[None], env_steps=env_steps, updates=updates, **solved
        )
        return TrainResult(
            state,
            updates,
            env_steps,
            evaluation,
            self.logger.rows,
            train_seconds=train_seconds,
            policy=self.agent.greedy_policy(state),
            **solved,
        )
