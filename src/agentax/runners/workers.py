"""The compiled runner on every core: a run's seeds split over worker processes, one per core.

Worker ``w`` trains a contiguous slice of the seeds (:func:`split`) as an ordinary compiled run in
``<run>/worker-<w>/``, in a process with its own one-CPU XLA client (:mod:`agentax._xla`); the run
gets their rows merged (:func:`merge_rows`), eval.json over every seed and curve.png. Each worker
stops at ``stop_at_return`` on its own seeds (design.md, "The host runners, module by module").
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import os
import shutil
import signal
import socket
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from queue import Empty
from typing import Any

import numpy as np

from agentax.errors import TrainingInterrupted, UsageError
from agentax.runners.ray_cluster import ray_session
from agentax.runners.session import SOLVED, TIMINGS, TrainResult, conclude
from agentax.runs import Run, checkpoints, read_config, read_json, read_metrics, write_json

FINAL_RETURNS = "final-returns.json"
"""A finished worker's final returns and lengths ``[seeds, episodes]`` (and timings)."""

BREAK_EVEN_AGENT_STEPS = 4_000_000
"""PPO CartPole agent steps from which a run split over the cores finished sooner than one process
(``benchmarks/bench_break_even.py``; design.md)."""
PPO_CARTPOLE_FLOPS_PER_STEP = 2.49e5
"""XLA's floating-point operations per agent step of that program (PPO ``default``, CartPole-v1)."""
BREAK_EVEN_FLOPS = BREAK_EVEN_AGENT_STEPS * PPO_CARTPOLE_FLOPS_PER_STEP
"""XLA's operations (summed over seeds and a sweep's settings) from which workers pay (~1e12)."""


def usable_cores() -> int:
    """The CPUs this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def default_count(jobs: int, flops: float | Callable[[], float]) -> int:
    """The default ``--workers``: one per usable core (at most ``jobs``) once ``flops`` (summed over
    the jobs; a callable is asked only where there are several cores and jobs) reach
    :data:`BREAK_EVEN_FLOPS`, else 1."""
    cores = max(1, min(usable_cores(), jobs))
    if cores == 1:
        return 1
    return cores if (flops() if callable(flops) else flops) >= BREAK_EVEN_FLOPS else 1


def default_for(seeds: int, seed_flops: Callable[[], float], stop_at_return: float | None) -> int:
    """The default ``--workers`` of a run (``seed_flops()``: one seed's whole training); 1 for a run
    that stops at a return (its length is not known, and each worker would stop on its own seeds)."""
    return 1 if stop_at_return is not None else default_count(seeds, lambda: seeds * seed_flops())


def announced(runner: Any, chosen: bool) -> str:
    """The line's words on the seeds and the processes; ``chosen``: by default, not by --workers."""
    seeds = f"{runner.num_seeds} seed{'s' if runner.num_seeds > 1 else ''}"
    if runner.workers == 1:
        return seeds
    count = len(split(runner))
    by_default = ", one per core; --workers 1 keeps one process" if chosen else ""
    return f"{seeds} over {count} worker processes{by_default}"


def split(runner: Any) -> list[Any]:
    """Each worker's runner config: ``runner.workers`` contiguous, even slices of the seeds (at most
    one worker a seed), each with ``workers=1``."""
    count = min(runner.workers, runner.num_seeds)
    sizes = [len(part) for part in np.array_split(np.arange(runner.num_seeds), count)]
    starts = np.cumsum([0, *sizes[:-1]])
    return [
        dataclasses.replace(runner, seed=runner.seed + int(start), num_seeds=size, workers=1)
        for start, size in zip(starts, sizes, strict=True)
    ]


def worker_dir(run_dir: str | Path, w: int) -> Path:
    return Path(run_dir) / f"worker-{w}"


def map_processes(fn: Callable[..., Any], jobs: Sequence[tuple], ray_address: str | None = None) -> list[Any]:
    """``[fn(*job) for job in jobs]``, each job in a spawned process of its own when there are several
    (``fn`` importable by name), or a Ray task on the cluster at ``ray_address`` (:func:`map_ray`).

    Ctrl-C (or SIGTERM) reaches this process only, which passes it on once to every worker and waits
    for them to stop at a checkpoint before it raises; a worker's error stops the others the same way
    and is raised here."""
    if ray_address is not None:
        return map_ray(fn, jobs, ray_address)
    if len(jobs) == 1:
        return [fn(*jobs[0])]
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    processes = [context.Process(target=_job, args=(fn, job, i, queue)) for i, job in enumerate(jobs)]
    for process in processes:
        process.start()
    results: dict[int, tuple[bool, Any]] = {}
    try:
        _collect(queue, processes, results, stop_on_error=True)
    except KeyboardInterrupt:
        _interrupt(processes)
        _collect(queue, processes, results, stop_on_error=False)
        raise
    finally:
        for process in processes:
            process.join()
    failures = [value for ok, value in results.values() if not ok]
    lost = [i for i, p in enumerate(processes) if i not in results]
    if failures:
        raise failures[0]
    if lost:
        code = processes[lost[0]].exitcode
        raise RuntimeError(f"worker {lost[0]} died without a result (exit code {code})")
    return [results[i][1] for i in range(len(jobs))]


def _collect(queue: Any, processes: Sequence[Any], results: dict, *, stop_on_error: bool) -> None:
    """Wait for the workers' results (or their deaths); with ``stop_on_error`` the first error
    interrupts the others."""
    while len(results) < len(processes):
        try:
            i, ok, value = queue.get(timeout=0.5)
        except Empty:
            if not any(p.is_alive() for p in processes) and queue.empty():
                return
            continue
        results[i] = (ok, value)
        if not ok and stop_on_error:
            stop_on_error = False
            _interrupt(processes)


def _job(fn: Callable[..., Any], job: tuple, i: int, queue: Any) -> None:
    os.setpgrp()  # out of the terminal's group: interrupts come from the parent, once
    signal.signal(signal.SIGINT, signal.default_int_handler)  # even where the parent's was ignored (``&``)
    try:
        queue.put((i, True, fn(*job)))
    except BaseException as error:  # sent back to be raised in the parent
        queue.put((i, False, error))


def _interrupt(processes: Sequence[Any]) -> None:
    for process in processes:
        if process.is_alive():
            os.kill(process.pid, signal.SIGINT)


def map_ray(fn: Callable[..., Any], jobs: Sequence[tuple], address: str) -> list[Any]:
    """``[fn(*job) for job in jobs]`` as Ray tasks of one CPU each on the cluster at ``address``;
    each job's first element is the folder it writes in, which every node must see. Ctrl-C cancels
    the tasks (each stops at its safe point) and raises."""
    with ray_session(address) as ray:
        task = ray.remote(num_cpus=1, max_retries=0)(_ray_job)
        refs = [task.remote(fn, job) for job in jobs]
        try:
            return ray.get(refs)
        except KeyboardInterrupt:
            for ref in refs:
                ray.cancel(ref)  # a KeyboardInterrupt in the task: it checkpoints and ends
            ray.wait(refs, num_returns=len(refs), timeout=60)
            raise
        except ray.exceptions.RayTaskError as error:  # the task's own error, as raised there
            raise (error.cause if isinstance(error.cause, BaseException) else error) from None


def node() -> str:
    """Where this process runs: the host name, and the Ray node's id inside a Ray task."""
    ray = sys.modules.get("ray")
    if ray is not None and ray.is_initialized():
        return f"{socket.gethostname()} (Ray node {ray.get_runtime_context().get_node_id()[:12]})"
    return socket.gethostname()


def _ray_job(fn: Callable[..., Any], job: tuple) -> Any:
    """One job in a Ray task; its first element is the (absolute) folder it writes in."""
    folder = Path(job[0])
    if not folder.parent.is_dir():
        raise UsageError(
            f"a worker on {socket.gethostname()} cannot see {folder.parent}: a run or sweep on a Ray "
            "cluster writes its folder from every node, so --out must be on a filesystem they all share"
        )
    return fn(*job)


SEED_COLUMNS = ("return_seed", "eval_seed")  # the per-seed columns: return_seed<k>, eval_seed<k>


def merge_rows(tables: Sequence[Sequence[dict[str, float]]], seeds: Sequence[int]) -> list[dict[str, float]]:
    """One run's rows from its workers' (row ``i`` of each, as far as each got): per-seed columns
    renumbered, ``mean_return`` and ``eval_return`` over every seed, ``wall_seconds`` the latest, the
    other metrics the mean weighted by the workers' ``seeds``."""
    offsets = np.cumsum([0, *seeds[:-1]])
    merged = []
    for i in range(max(map(len, tables))):
        present = [(t[i], n, o) for t, n, o in zip(tables, seeds, offsets, strict=True) if i < len(t)]
        seeded = {
            f"{prefix}{offset + k}": source[f"{prefix}{k}"]
            for prefix in SEED_COLUMNS
            for source, count, offset in present
            for k in range(count)
            if f"{prefix}{k}" in source
        }
        row: dict[str, float] = {}
        for name in dict.fromkeys(name for source, _, _ in present for name in source):
            if name.startswith(SEED_COLUMNS):
                if name.endswith("_seed0"):  # every worker's seeds of this column, here
                    row.update({k: v for k, v in seeded.items() if k.startswith(name[:-1])})
            elif name == "wall_seconds":  # the workers run at once: the latest
                row[name] = max(source.get(name, math.nan) for source, _, _ in present)
            elif name in ("mean_return", "eval_return"):
                prefix = SEED_COLUMNS[name == "eval_return"]
                finite = [v for k, v in seeded.items() if k.startswith(prefix) and math.isfinite(v)]
                row[name] = float(np.mean(finite)) if finite else math.nan
            else:
                finite = [
                    (source[name], n) for source, n, _ in present if math.isfinite(source.get(name, math.nan))
                ]
                total = sum(n for _, n in finite)
                row[name] = sum(v * n for v, n in finite) / total if finite else math.nan
        merged.append({**row, **seeded})
    return merged


def worker_of(runner: Any, seed_index: int) -> tuple[int, int]:
    """``(w, k)``: seed ``seed_index`` of the run is seed ``k`` of worker ``w`` (:func:`split`)."""
    parts = split(runner)
    w = next(w for w, part in enumerate(parts) if seed_index < part.seed - runner.seed + part.num_seeds)
    return w, seed_index - (parts[w].seed - runner.seed)


def train(run: Any, runner: Any, train_one: Callable[..., Any], *, resume: bool, progress: bool) -> Any:
    """Train ``runner``'s seeds split over ``runner.workers`` processes (:func:`train_worker`), then
    write the run's merged metrics, eval.json and curve.png; a ``TrainResult`` with ``state=None``."""
    parts = split(runner)
    jobs = [
        (str(run.path.resolve()), w, part, resume, progress and w == 0, train_one)
        for w, part in enumerate(parts)
    ]
    try:
        timings = map_processes(train_worker, jobs, runner.ray_address)
    except KeyboardInterrupt:  # each worker stopped at its safe point: the run resumes as a whole
        raise TrainingInterrupted(str(run.path)) from None
    except Exception as error:
        if getattr(error, "run_dir", None):  # a worker's folder: resume the run it belongs to
            error.run_dir = str(run.path)
        raise
    folders = [worker_dir(run.path, w) for w in range(len(parts))]
    rows = merge_rows([read_metrics(f) for f in folders], [part.num_seeds for part in parts])
    for written in ("metrics.csv", "tensorboard"):  # rewritten whole, a resumed run's too
        target = run.path / written
        shutil.rmtree(target) if target.is_dir() else target.unlink(missing_ok=True)
    merged = Run(run.path, run.config)
    for row in rows:
        merged.log(row)
    finals = [read_json(f / FINAL_RETURNS) for f in folders]
    solved = all(t["solved_env_steps"] is not None for t in timings)  # the run, once every worker
    latest = {
        name: max(t[name] for t in timings) for name in (*SOLVED, *TIMINGS) if solved or name in TIMINGS
    }
    result = TrainResult(None, int(rows[-1]["updates"]), float(rows[-1]["env_steps"]), {}, rows, **latest)
    returns = np.concatenate([np.asarray(f["returns"]) for f in finals])
    lengths = np.concatenate([np.asarray(f["lengths"]) for f in finals])
    return conclude(merged, result, returns, lengths, *SOLVED, *TIMINGS, workers=len(parts))


def train_worker(
    run_dir: str, w: int, runner: Any, resume: bool, progress: bool, train_one: Callable[..., Any]
) -> dict[str, Any]:
    """Worker ``w``'s seeds (``runner``) as a run in ``worker-<w>/``, resumed where it can be, trained
    by ``train_one(config, run, runner, resume=, progress=) -> TrainResult``; its timings (a finished
    worker's read back)."""
    folder = worker_dir(run_dir, w)
    done = folder / FINAL_RETURNS
    if done.is_file():
        return read_json(done)["timings"]
    config = read_config(run_dir)
    run, resumed = resume_or_restart(folder, {**config, "runner": dataclasses.asdict(runner)}, resume)
    result = train_one(config, run, runner, resume=resumed, progress=progress)
    timings = {name: getattr(result, name) for name in (*SOLVED, *TIMINGS)}
    returns, lengths = result.final_returns
    finals = {"returns": returns.tolist(), "lengths": lengths.tolist(), "timings": timings, "node": node()}
    write_json(done, finals)
    return timings


def resume_or_restart(folder: Path, config: dict[str, Any], resume: bool = True) -> tuple[Any, bool]:
    """``(run, resumed)``: the run in ``folder`` where ``resume`` and it has a checkpoint, else a new
    run of ``config`` there."""
    if resume and (folder / "config.json").is_file() and bool(checkpoints(folder)):
        return Run.open(folder), True
    if folder.exists():
        shutil.rmtree(folder)
    return Run.create(folder, config), False
