"""The compiled runner: a JAX env's whole training under ``jit`` + ``lax.scan``, vmapped over seeds.

One seed's :class:`~agentax.runners.rollout.Program` (:func:`program_of`) runs as chunks of
``updates_per_chunk`` updates, each ending with the greedy policy's evaluation when asked
(:mod:`agentax.runners.programs`). Between chunks (:class:`ChunkSchedule`) the runner logs a row,
checkpoints the whole carry and stops once every seed's evaluation reaches ``stop_at_return``; with
``workers > 1`` the seeds are split over processes (:mod:`agentax.runners.workers`).
"""

from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from agentax.agents.memory import check_seeds_fit
from agentax.agents.protocol import Agent, EnvSpec, Episodes, OffPolicy
from agentax.curves import preload_plotting
from agentax.envs import make_jax
from agentax.envs.core import Environment
from agentax.errors import UsageError
from agentax.policies import Policy
from agentax.runners import algorithm_of, cost, programs, workers
from agentax.runners.launch import agent_maker, parse_return, precision_of, run_agent_maker
from agentax.runners.programs import CHUNK_COMPILER_OPTIONS, init_from_seeds
from agentax.runners.replay_program import Freeze, off_policy_program
from agentax.runners.rollout import Program, VectorEnv, episodes_program, on_policy_program
from agentax.runners.session import SOLVED, TIMINGS, TrainResult, conclude, open_logger, row_of
from agentax.runs import Run, load_checkpoint


@dataclass(frozen=True)
class RunnerConfig:
    """How the runner schedules one training; saved in config.json under "runner"."""

    seed: int = 0
    """seed of the first agent; agent k uses seed + k"""
    num_seeds: int = 1
    """independent agents trained together in one vmapped program"""
    updates_per_chunk: int = 10
    """updates per compiled call; the runner logs once per chunk"""
    eval_every_chunks: int = 0
    """evaluate the greedy policy every this many chunks (and after the last); 0: every chunk when
    the run may stop once solved (``stop_at_return``), else about ``AUTO_EVALUATIONS`` times a run"""
    eval_episodes: int = 20
    """episodes per seed in each evaluation, during training and at the end"""
    stop_at_return: float | None = None
    """stop once an evaluation's mean return over seeds reaches this (None: train to the end)"""
    checkpoint_every_chunks: int = 0
    """also write a checkpoint every this many chunks (0: by time only)"""
    checkpoint_every_seconds: float = 30.0
    """write a checkpoint at most this often, and whenever the loop ends (finished, solved, stopped)"""
    freeze_at_return: float | None = None
    """off-policy agents: each seed stops learning once each of its greedy policy's last
    ``freeze_episodes`` episodes, played on side envs during training, returned at least this"""
    freeze_episodes: int = 8
    """greedy episodes (and side envs) behind ``freeze_at_return``"""
    num_settings: int = 1
    """a sweep's settings traced in this program: its ``num_settings × num_seeds`` agents run
    setting ``i // num_seeds`` with seed ``seed + i % num_seeds`` (:mod:`agentax.runners.sweep`)"""
    workers: int = 1
    """processes the seeds are split over, each a program of its own (:mod:`agentax.runners.workers`)"""
    ray_address: str | None = None
    """run the workers as one-CPU Ray tasks on this cluster (the run folder on a shared filesystem)"""

    def __post_init__(self):
        if self.num_settings < 1:
            raise UsageError(f"a sweep needs at least one setting, got {self.num_settings}")
        if self.num_seeds < 1:
            raise UsageError(f"--seeds must be at least 1, got {self.num_seeds}")
        if self.workers < 1:
            raise UsageError(f"--workers must be at least 1, got {self.workers}")
        if self.eval_every_chunks < 0:
            raise UsageError(f"eval_every_chunks must not be negative, got {self.eval_every_chunks}")
        for name in ("updates_per_chunk", "eval_episodes", "freeze_episodes"):
            if getattr(self, name) < 1:
                raise UsageError(f"{name} must be at least 1, got {getattr(self, name)}")


AUTO_EVALUATIONS = 10


class Chunk(NamedTuple):
    """One call of the chunk program: ``num_active`` updates (0: only the evaluation), its 1-based
    ``number`` in the run, whether it ends with an evaluation, and that evaluation's index (its keys)."""

    num_active: int
    number: int
    do_eval: bool
    evaluation: int


def eval_every_chunks(runner: RunnerConfig, num_updates: int) -> int:
    """The runner's evaluation period in chunks (see ``RunnerConfig.eval_every_chunks``)."""
    if runner.eval_every_chunks:
        return runner.eval_every_chunks
    if runner.stop_at_return is not None:
        return 1
    chunks = -(-num_updates // runner.updates_per_chunk)
    return max(1, -(-chunks // AUTO_EVALUATIONS))


def check_fits(algorithm: Program, runner: RunnerConfig) -> None:
    """A ``UsageError`` when the agents' carry, twice (the program's buffers and a checkpoint's host
    copy), cannot fit in memory; one agent is the algorithm's to refuse (no extra trace)."""
    agents = runner.num_seeds * runner.num_settings
    if agents == 1:
        return
    one_seed = jax.eval_shape(init_from_seeds(algorithm), np.zeros(1, np.int32))
    per_seed = sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(one_seed) if hasattr(x, "dtype"))
    check_seeds_fit(runner.num_seeds, 2 * per_seed, "the agents' training state, twice", agents)


def seeds_of(runner: RunnerConfig) -> np.ndarray:
    """The seeds of the runner's agents ``[num_settings × num_seeds]``: ``seed + k % num_seeds``."""
    return np.tile(
        np.arange(runner.seed, runner.seed + runner.num_seeds, dtype=np.int32), runner.num_settings
    )


def _episode_means(before, after) -> np.ndarray:
    """Per seed: mean return of the episodes finished between two host EpisodeStats (else last returns)."""
    completed = after.completed - before.completed
    fallback = np.where(after.completed > 0, after.last_return.mean(axis=-1), np.nan)
    means = (after.return_sum - before.return_sum) / np.maximum(completed, 1)
    return np.where(completed > 0, means, fallback)


class ChunkSchedule(NamedTuple):
    """Which chunk comes after which: ``updates_per_chunk`` updates each, an evaluation every
    ``eval_every`` chunks and after the last, at most ``max_chunks`` of them in one call (None: all)."""

    num_updates: int
    updates_per_chunk: int
    eval_every: int
    max_chunks: int | None = None

    def after(self, updates: int, chunks: int, evaluations: int) -> Chunk | None:
        """The chunk after ``updates`` updates, ``chunks`` of them in this call (None: no more)."""
        if updates >= self.num_updates or (self.max_chunks is not None and chunks >= self.max_chunks):
            return None
        num_active = min(self.updates_per_chunk, self.num_updates - updates)
        number = updates // self.updates_per_chunk + 1
        last = updates + num_active >= self.num_updates
        return Chunk(num_active, number, last or number % self.eval_every == 0, evaluations)


@dataclass
class Counts:
    """Where a compiled training stands: what its checkpoints' meta holds (and ``elapsed``)."""

    updates: int
    evaluations: int
    env_steps: float
    solved_env_steps: float | None = None
    solved_seconds: float | None = None


def train_program(
    algorithm: Program,
    env: Environment,
    runner: RunnerConfig,
    run: Run | None = None,
    *,
    resume: bool = False,
    progress: bool = False,
    max_chunks: int | None = None,
    program_description: dict[str, Any] | None = None,
) -> TrainResult:
    """Train the runner's agents together; log, checkpoint and evaluate into ``run`` (if given).
    ``resume=True`` continues ``run`` from its newest checkpoint; ``max_chunks`` stops after that many
    chunks, leaving a resumable run; ``program_description`` (JSON-able), where it determines the
    program, names it for :func:`agentax.runners.programs.build` to keep."""
    start = time.perf_counter()
    seeds = seeds_of(runner)
    shapes, init_program, chunk_program = programs.build(algorithm, env, runner, seeds, program_description)
    state_tree = jax.tree.structure(shapes)
    meta: dict[str, Any] = {"updates": 0, "evaluations": 0, "elapsed": 0.0}
    if resume:
        if run is None:
            raise ValueError("resume needs the run to resume")
        state, meta, _ = load_checkpoint(run.path, shapes)
        run.truncate_metrics(meta["env_steps"])
    else:
        state = jax.tree.unflatten(state_tree, init_program(seeds))
    if run is not None:
        preload_plotting()  # for curve.png, while XLA (which lets go of the GIL) loads or compiles
    compile_start = time.perf_counter()
    compiled = chunk_program.lower(jax.tree.leaves(state), 0, True, seeds, 0).compile(CHUNK_COMPILER_OPTIONS)
    compile_seconds = time.perf_counter() - compile_start

    def call(state, chunk: Chunk):  # dispatched: nothing waits for it
        leaves, metrics, returns, lengths = compiled(
            jax.tree.leaves(state), chunk.num_active, chunk.do_eval, seeds, chunk.evaluation
        )
        return jax.tree.unflatten(state_tree, leaves), metrics, returns, lengths

    stats = jax.device_get(state.episodes)
    counts = Counts(int(meta["updates"]), int(meta["evaluations"]), float(np.mean(stats.env_steps)))
    counts.solved_env_steps, counts.solved_seconds = (meta.get(name) for name in SOLVED)
    every = eval_every_chunks(runner, algorithm.num_updates)
    schedule = ChunkSchedule(algorithm.num_updates, runner.updates_per_chunk, every, max_chunks)
    total_steps = algorithm.num_updates * algorithm.steps_per_update
    logger = open_logger(run, total_steps, counts.env_steps, runner, float(meta["elapsed"]), progress)
    with logger:
        state, final_eval = _chunks(call, state, stats, schedule, runner, logger, counts, start)
    train_seconds = time.perf_counter() - logger.start
    solved = (counts.solved_env_steps, counts.solved_seconds)
    result = TrainResult(
        state, counts.updates, counts.env_steps, {}, logger.rows, *solved, compile_seconds, train_seconds
    )
    if counts.updates < algorithm.num_updates and counts.solved_env_steps is None:
        return result  # stopped early by max_chunks: resumable, not finished
    if final_eval is None:
        state, _, *final_eval = call(state, Chunk(0, 0, True, counts.evaluations))
    returns, lengths = np.asarray(final_eval[0]), np.asarray(final_eval[1])
    result.state, result.final_returns = state, (returns, lengths)
    return conclude(run, result, returns, lengths, *SOLVED, *TIMINGS)


def _chunks(call, state, stats, schedule: ChunkSchedule, runner: RunnerConfig, logger, counts: Counts, start):
    """Call the schedule's chunks, a row and, when due, a checkpoint after each; ``(state, the final
    evaluation where the run stopped solved, else None)``. Chunk k + 1 runs while chunk k's row is
    written (its episode counters copied out first: the next chunk takes the donated buffers), unless
    chunk k's state is still needed (a checkpoint, a stop at this evaluation)."""
    final_eval, chunks, every = None, 0, runner.checkpoint_every_chunks
    chunk = schedule.after(counts.updates, 0, counts.evaluations) if counts.solved_env_steps is None else None
    in_flight = call(state, chunk) if chunk is not None else None
    row_time = time.perf_counter()
    while chunk is not None:
        state, metrics, eval_returns, _ = in_flight
        counts.updates += chunk.num_active
        counts.evaluations += int(chunk.do_eval)
        chunks += 1
        following = schedule.after(counts.updates, chunks, counts.evaluations)
        checkpoint = following is None or bool(every and chunk.number % every == 0)
        may_stop = chunk.do_eval and runner.stop_at_return is not None
        ahead = following is not None and not (checkpoint or logger.checkpoint_due() or may_stop)
        episodes = state.episodes
        if ahead:
            episodes = jax.device_put(episodes, may_alias=False)
            in_flight = call(state, following)
        new_stats, metrics, eval_returns = jax.device_get((episodes, metrics, eval_returns))
        now = time.perf_counter()
        seconds, row_time = now - row_time, now
        steps_before, counts.env_steps = counts.env_steps, float(np.mean(new_stats.env_steps))
        evals = [float(np.mean(r)) if chunk.do_eval else math.nan for r in eval_returns]
        speed = (counts.env_steps - steps_before) / max(seconds, 1e-9)
        row = row_of(counts.env_steps, counts.updates, _episode_means(stats, new_stats), speed, evals)
        stats, row = new_stats, logger.log(row, metrics)
        if may_stop and min(map(np.mean, eval_returns)) >= runner.stop_at_return:
            state, final_eval, following = _confirmed(call, state, schedule, counts, chunks, runner, start)
        if not ahead:
            meta = {**asdict(counts), "elapsed": row["wall_seconds"]}
            logger.checkpoint(
                counts.updates, state, meta, force=checkpoint or counts.solved_env_steps is not None
            )
            if following is not None:
                in_flight = call(state, following)
        chunk = following
    return state, final_eval


def _confirmed(
    call, state, schedule: ChunkSchedule, counts: Counts, chunks: int, runner: RunnerConfig, start
):
    """Every seed reached ``stop_at_return`` at this evaluation: the run is solved once the final
    evaluation (fresh keys) agrees, which then is the final one; else it trains on, and with a chunk
    to come its evaluations take the next keys. ``(state, final evaluation or None, next chunk)``."""
    state, _, *final_eval = call(state, Chunk(0, 0, True, counts.evaluations))
    if min(map(np.mean, np.asarray(final_eval[0]))) >= runner.stop_at_return:
        counts.solved_env_steps, counts.solved_seconds = counts.env_steps, time.perf_counter() - start
        return state, final_eval, None
    following = schedule.after(counts.updates, chunks, counts.evaluations + 1)
    if following is not None:
        counts.evaluations, final_eval = counts.evaluations + 1, None
    return state, final_eval, following


def restore_policy(
    run_dir, algorithm: Program, runner: RunnerConfig, seed_index: int | None = None
) -> Policy:
    """The greedy policy of one seed of a run's newest checkpoint (the best seed by eval.json if None)."""
    target = jax.eval_shape(init_from_seeds(algorithm), seeds_of(runner))
    state, _, _ = load_checkpoint(run_dir, target)
    one = jax.tree.map(lambda x: x[best_seed(run_dir) if seed_index is None else seed_index], state)
    return algorithm.greedy_policy(one)


def best_of(per_seed: list[dict[str, Any]]) -> int:
    """The index of the best seed by an evaluation's ``per_seed`` rows (0 if there are none)."""
    return int(np.argmax([s["mean_return"] for s in per_seed])) if per_seed else 0


def best_seed(run_dir: str | Path) -> int:
    """The index of a run's best seed by its final evaluation (eval.json), else 0."""
    path = Path(run_dir) / "eval.json"
    return best_of(json.loads(path.read_text()).get("per_seed", []) if path.is_file() else [])


def program_of(agent: Agent, env: Environment, runner: RunnerConfig | None = None) -> Program:
    """The program of ``agent`` on the JAX env ``env`` for its experience, with ``runner``'s freeze if any."""
    experience = agent.experience
    envs = VectorEnv(env, env.default_params(), experience.num_envs)
    freeze_at = None if runner is None else runner.freeze_at_return
    if isinstance(experience, OffPolicy):
        freeze = None if freeze_at is None else Freeze(freeze_at, runner.freeze_episodes)
        return off_policy_program(agent, envs, freeze)
    if freeze_at is not None:
        raise UsageError(
            "--freeze-at-return: freezing seeds needs an off-policy agent's learning gates, "
            f"not {agent.name}'s"
        )
    if isinstance(experience, Episodes):
        return episodes_program(agent, envs)
    return on_policy_program(agent, envs)


def compiled_program(
    module: Any, env: Environment, cfg: Any, runner: RunnerConfig | None = None, encoders: dict | None = None
) -> Program:
    """The program of ``module``'s agent (an algorithm module, ``cfg`` its config) on the JAX env
    ``env``, its leaves encoded as ``encoders`` choose, with the per-seed early stop of ``runner``."""
    spec = EnvSpec.of(env).with_encoders(encoders, env.id)
    return program_of(agent_maker(module, spec, cfg)(), env, runner)


Config = RunnerConfig  # the first of a runner module's four names (agentax.runners.launch)


def configure(run_args: Any, agent: Agent, preset: Any) -> tuple[RunnerConfig, str]:
    """The compiled run ``run_args`` describe (:mod:`agentax.runners.launch`), refused before
    anything is written where the program cannot run it (or more seeds than memory holds)."""
    stop, env = run_args.stop_at_return, make_jax(run_args.env)
    seed_flops = functools.partial(cost.program_flops, program_of(agent, env))  # by default, the split's
    freeze = parse_return("--freeze-at-return", run_args.freeze_at_return, preset.freeze_at_return)
    runner = RunnerConfig(
        seed=run_args.seed,
        num_seeds=run_args.seeds,
        **schedule_of(preset),
        stop_at_return=stop,
        freeze_at_return=freeze,
        freeze_episodes=run_args.freeze_episodes,
        workers=run_args.workers or workers.default_for(run_args.seeds, seed_flops, stop),
        ray_address=run_args.ray_address,
    )
    check_fits(program_of(agent, env, runner), runner)
    if runner.ray_address is not None and runner.workers == 1:
        raise UsageError(
            "--ray-address sends the compiled runner's --workers to a Ray cluster: give --workers N "
            "(or --runner ray for the Ray runner's actors)"
        )
    return runner, workers.announced(runner, chosen=run_args.workers is None)


def schedule_of(preset: Any) -> dict[str, int]:
    """What a :class:`RunnerConfig` takes of a preset: its chunks and evaluations."""
    names = ("updates_per_chunk", "eval_every_chunks", "eval_episodes")
    return {name: getattr(preset, name) for name in names}


def train(
    agent: Agent,
    env_id: str,
    runner: RunnerConfig,
    run: Run | None = None,
    *,
    resume: bool = False,
    progress: bool = False,
) -> TrainResult:
    """Train the runner's seeds of ``agent`` on the JAX env ``env_id`` into ``run``, in this process
    (``result.policy``: the best seed's greedy policy) or over ``runner.workers`` processes."""
    if runner.workers > 1:
        return workers.train(run, runner, train_worker, resume=resume, progress=progress)
    env = make_jax(env_id)
    algorithm = program_of(agent, env, runner)
    description = None
    if run is not None:  # algo, env, config, encoders, precision and the freeze determine the program
        description = {k: run.config[k] for k in ("algo", "env", "config", "encoders") if k in run.config}
        description["precision"] = precision_of(run.config)  # bf16 products: another program
        description["freeze"] = [runner.freeze_at_return, runner.freeze_episodes]
    result = train_program(
        algorithm, env, runner, run, resume=resume, progress=progress, program_description=description
    )
    best = best_of(result.eval.get("per_seed", []))
    result.policy = algorithm.greedy_policy(jax.tree.map(lambda x: x[best], result.state))
    return result


def train_worker(
    config: dict[str, Any], run: Run, runner: RunnerConfig, *, resume: bool, progress: bool
) -> TrainResult:
    """One worker's seeds (``runner``) of the run ``config`` describes, in this process, into ``run``."""
    agent = run_agent_maker(config, *algorithm_of(config))()  # as launch.prepare made it
    return train(agent, config["env"], runner, run, resume=resume, progress=progress)


def restore(run_dir: Path, config: dict[str, Any], agent: Agent) -> Policy:
    """The greedy policy of the run's best seed (by eval.json), from its (worker's) newest checkpoint."""
    env, runner = make_jax(config["env"]), RunnerConfig(**config["runner"])
    if runner.workers == 1:
        return restore_policy(run_dir, program_of(agent, env, runner), runner)
    w, local = workers.worker_of(runner, best_seed(run_dir))
    part = workers.split(runner)[w]
    return restore_policy(workers.worker_dir(run_dir, w), program_of(agent, env, part), part, local)
