"""The compiled runner's launcher (see :mod:`agentax.runners.launch`): a run of agentax's JAX envs
configured from its description, trained in one process or split over ``--workers``
(:mod:`agentax.runners.workers`), resumed and restored."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from agentax.errors import UsageError
from agentax.policies import Policy
from agentax.runners import compiled, workers
from agentax.runners.compiled import RunnerConfig, compiled_program
from agentax.runners.launch import Launch, parse_stop


def prepare(algo: str, module: Any, run_args: Any, cfg: Any, preset: Any, kind: str) -> Launch:
    """The compiled run ``run_args`` describe, refused before anything is written where the
    program cannot run it (or more seeds than memory holds)."""
    from agentax.envs import make_jax

    env = make_jax(run_args.env)
    stop = parse_stop(run_args.stop_at_return, preset, env)
    runner = RunnerConfig(
        seed=run_args.seed,
        num_seeds=run_args.seeds,
        updates_per_chunk=preset.updates_per_chunk,
        eval_every_chunks=preset.eval_every_chunks,
        eval_episodes=preset.eval_episodes,
        stop_at_return=stop,
        freeze_at_return=run_args.freeze(preset, kind),
        freeze_episodes=run_args.freeze_episodes,
        workers=run_args.workers or _default_workers(run_args.seeds, cfg.total_steps, stop),
        ray_address=run_args.ray_address,
    )
    compiled.check_fits(compiled_program(module, env, cfg, runner), runner)
    if runner.ray_address is not None and runner.workers == 1:
        raise UsageError(
            "--ray-address sends the compiled runner's --workers to a Ray cluster: give --workers N "
            "(or --runner ray for the Ray runner's actors)"
        )
    return _launch(module, env, cfg, runner, _where(runner, chosen=run_args.workers is None))


def _default_workers(seeds: int, total_steps: int, stop_at_return: float | None) -> int:
    """Without ``--workers``: every core for a run of all its steps long enough to gain; one process
    for a run that stops at a return (how long it runs is not known, and a split would stop each
    worker on its own seeds' return)."""
    return 1 if stop_at_return is not None else workers.default_count(seeds, seeds * total_steps)


def _where(runner: RunnerConfig, chosen: bool) -> str:
    """The line's words on the seeds and the processes; ``chosen``: by default, not by --workers."""
    seeds = f"{runner.num_seeds} seed{'s' if runner.num_seeds > 1 else ''}"
    if runner.workers == 1:
        return seeds
    count = len(workers.split(runner))
    by_default = ", one per core; --workers 1 keeps one process" if chosen else ""
    return f"{seeds} over {count} worker processes{by_default}"


def reopen(config: dict[str, Any], module: Any, cfg: Any, runner: RunnerConfig) -> Launch:
    """The compiled run of ``config`` (a config.json), to resume."""
    from agentax.envs import make_jax

    return _launch(module, make_jax(config["env"]), cfg, runner, "")


def _launch(module: Any, env: Any, cfg: Any, runner: RunnerConfig, where: str) -> Launch:
    def train(run: Any, resume: bool, progress: bool) -> tuple[Any, Policy | None]:
        if runner.workers > 1:
            return workers.train(run, runner, resume=resume, progress=progress), None
        return compiled.train_module(module, env, cfg, runner, run, resume=resume, progress=progress)

    return Launch(runner, where, train)


def restore(run_dir: Path, config: dict[str, Any], module: Any, cfg: Any) -> Policy:
    """The greedy policy of the run's best seed (by eval.json), from its (worker's) newest checkpoint."""
    from agentax.envs import make_jax

    env, runner = make_jax(config["env"]), RunnerConfig(**config["runner"])
    if runner.workers == 1:
        return compiled.restore_policy(run_dir, compiled_program(module, env, cfg, runner), runner)
    w, local = workers.worker_of(runner, compiled.best_seed(run_dir))
    part = workers.split(runner)[w]
    return compiled.restore_policy(
        workers.worker_dir(run_dir, w), compiled_program(module, env, cfg, part), part, local
    )
