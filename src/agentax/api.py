"""One Python call for what ``agentax train`` does, and the trained run as an object.

::

    import agentax

    run = agentax.train("ppo", env="CartPole-v1", seeds=4, total_steps=50_000, learning_rate=1e-3)
    run.evaluate(episodes=100, seed=1).mean_return   # the statistics `agentax evaluate` prints
    run.metrics[-1]["mean_return"]                    # the rows of metrics.csv
    run.plot("curve.png"); run.video("episode.gif")
    run = agentax.load(run.path)                      # the same, from the folder, later

:func:`train` picks the preset and the runner exactly as ``agentax train`` does (the compiled
runner for agentax's JAX envs, the host runner for other ids; ``runner="parallel"``,
``actors=...``, ``policy_lag=...`` as the flags); keyword arguments beyond its own override fields of
the algorithm's config (``learning_rate=...``) or of :class:`RunArgs` (``env_backend=...``). The
command line is a thin layer over this module: ``agentax train`` parses its flags into a
:class:`RunArgs` and the algorithm's config with tyro, then calls :func:`start` (``--resume``:
:func:`resume`), the functions :func:`train` calls.

:func:`restore_policy` rebuilds the greedy policy of any run folder (any algorithm, any runner, or a
policy search), for ``Run.policy`` and ``agentax evaluate/play --policy DIR``.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import sys
import time
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from agentax.agents import algorithm, algorithm_config, config_from_dict, config_to_dict
from agentax.errors import TrainingInterrupted, UsageError
from agentax.evaluate import EvalStats
from agentax.policies import Policy
from agentax.runfile import RunArgs, choose_preset
from agentax.runners import RUNNERS

if TYPE_CHECKING:
    from agentax.agents.presets import Preset


# The trained run.


class Run:
    """A run folder written by :func:`train` (or ``agentax train``), with what a user asks of it.

    ``policy`` is the greedy policy (the best seed by the final evaluation); ``evaluate`` plays it
    on fresh episodes; ``metrics`` are the rows of metrics.csv; ``final_eval`` is eval.json (the
    evaluation at the end of training); ``plot`` and ``video`` write the learning curve and one
    episode. ``result`` is the runner's :class:`~agentax.runners.session.TrainResult` when this
    process trained the run, else ``None``.
    (Not to be confused with :class:`agentax.runs.Run`, the writer a runner logs through.)
    """

    def __init__(
        self,
        path: str | Path,
        config: dict[str, Any] | None = None,
        result: Any = None,
        seconds: float | None = None,
        greedy: Policy | None = None,
    ):
        from agentax.runs import read_config

        self.path = Path(path)
        self.config = read_config(self.path) if config is None else config
        self.result = result
        self.seconds = seconds
        if greedy is not None:
            self.__dict__["policy"] = greedy  # fills the cached property: the trained state, in memory

    @property
    def algo(self) -> str:
        return self.config["algo"]

    @property
    def env(self) -> str:
        """The env id the run trained on."""
        return self.config["env"]

    @property
    def runner_kind(self) -> str:
        return self.config.get("runner_kind", "compiled")

    @cached_property
    def policy(self) -> Policy:
        """The greedy policy ``(obs, key) -> action`` of the run's best seed, from its newest checkpoint."""
        return _restore_learned(self.path, self.config)

    def evaluate(self, episodes: int = 100, seed: int = 0) -> EvalStats:
        """The policy's returns over ``episodes`` fresh episodes: what ``agentax evaluate --policy DIR
        --episodes N --seed S`` prints (``mean_return``, ``std_return``, ...)."""
        from agentax.envs import make
        from agentax.evaluate import check_policy_fits, evaluate

        if episodes <= 0:
            raise UsageError(f"episodes must be at least 1, not {episodes}")
        env = make(self.env, num_envs=min(episodes, 16))
        check_policy_fits(env, self.policy, self.env)
        return evaluate(env, self.policy, episodes, seed)

    @property
    def metrics(self) -> list[dict[str, float]]:
        """The rows of metrics.csv (env_steps, mean_return, return_seed<k>, ...), as floats."""
        from agentax.runs import read_metrics

        return read_metrics(self.path)

    @property
    def final_eval(self) -> dict[str, Any]:
        """eval.json: the evaluation at the end of training, pooled and ``per_seed``."""

        path = self.path / "eval.json"
        if not path.is_file():
            raise UsageError(f"{self.path} has no eval.json yet (its training has not finished)")
        return json.loads(path.read_text())

    def plot(self, path: str | Path | None = None) -> Path:
        """Write the learning curve (mean over seeds, 95 % band) as a PNG; default ``<run>/curve.png``."""
        from agentax.curves import plot_curves

        return plot_curves([self.path], self.path / "curve.png" if path is None else path)

    def video(self, path: str | Path | None = None, seed: int = 0) -> Path:
        """Play one episode of the policy and write it as a .gif or .mp4; default ``<run>/episode.gif``."""
        from agentax.envs import make
        from agentax.render import check_video_path, save_episode

        path = check_video_path(self.path / "episode.gif" if path is None else path)
        written, _ = save_episode(make(self.env, 1), self.policy, path, seed)
        return written

    def export(
        self, path: str | Path | None = None, format: str = "onnx", *, stochastic: bool = False
    ) -> Path:
        """Write the policy as one ONNX or StableHLO file, its model card beside it: what ``agentax
        export DIR`` does (see :mod:`agentax.export`); the file's path."""
        from agentax import _xla
        from agentax.export import export_run

        _xla.enable_compilation_cache()  # jax2onnx compiles ~70 small programs the first time it runs
        greedy = lambda: self.policy  # noqa: E731  (restored only once the format is checked)
        restore = functools.partial(_restore_learned, self.path, self.config, True) if stochastic else greedy
        return export_run(self.path, self.config, restore, format, path, stochastic)

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r}, algo={self.algo!r}, env={self.env!r}, runner={self.runner_kind!r})"


def load(run_dir: str | Path) -> Run:
    """The run in ``run_dir`` (written by :func:`train` or ``agentax train``)."""
    return Run(run_dir)


def restore_policy(run_dir: str | Path) -> tuple[str, Policy]:
    """``(env_id, policy)`` of a trained run: a learning algorithm's greedy policy (its best seed, from
    its newest good checkpoint) or a policy search's (its module's ``load_policy``)."""
    import importlib

    from agentax.agents import ALGORITHMS
    from agentax.runs import read_config
    from agentax.search import METHODS

    config = read_config(run_dir)
    algo = config["algo"]
    if algo in ALGORITHMS:
        return config["env"], _restore_learned(Path(run_dir), config)
    if algo not in METHODS:
        known = ", ".join([*ALGORITHMS, *METHODS])
        raise UsageError(f"{run_dir}: unknown algorithm {algo!r} in config.json; known: {known}")
    return config["env"], importlib.import_module(METHODS[algo]).load_policy(Path(run_dir), config)


RUNNER_SETTINGS_ONCE_IN_CONFIG = ("freeze_at_return", "freeze_episodes")
"""Settings that runs written before 2026-12 kept in the algorithm's config (DQN's per-seed early
stop) and that now belong to the compiled runner's."""


def _upgraded(config: dict[str, Any]) -> dict[str, Any]:
    """``config.json`` of an older run in today's layout (the runner's settings in "runner")."""
    moved = {k: config["config"][k] for k in RUNNER_SETTINGS_ONCE_IN_CONFIG if k in config.get("config", {})}
    if not moved:
        return config
    settings = {k: v for k, v in config["config"].items() if k not in moved}
    runner = dict(config.get("runner", {}))
    if not RUNNERS[config.get("runner_kind", "compiled")].host_loop:
        runner.update(moved)
    return {**config, "config": settings, "runner": runner}


def compiled_program(module: Any, env: Any, cfg: Any, runner: Any = None) -> Any:
    """The compiled runner's program of ``module``'s agent on the JAX env ``env`` (with the per-seed
    early stop of ``runner``, a ``RunnerConfig``, if given)."""
    from agentax.agents.protocol import EnvSpec
    from agentax.runners.compiled import freeze_of
    from agentax.runners.rollout import program

    agent = agent_maker(module, EnvSpec.of(env), cfg)()
    try:
        return program(agent, env, freeze=None if runner is None else freeze_of(runner))
    except ValueError as error:
        raise UsageError(f"--freeze-at-return: {error}") from None


def _best_seed(run_dir: Path) -> int:
    """The index of the run's best seed by its final evaluation (eval.json), else 0."""
    path = Path(run_dir) / "eval.json"
    per_seed = json.loads(path.read_text()).get("per_seed", []) if path.is_file() else []
    return int(np.argmax([s["mean_return"] for s in per_seed])) if per_seed else 0


def _restore_learned(run_dir: Path, config: dict[str, Any], stochastic: bool = False) -> Policy:
    """The greedy policy of a learning algorithm's run (its best seed), from its newest good checkpoint;
    ``stochastic``: its sampling head instead (:class:`agentax.export.SamplingAlgorithm`)."""

    config = _upgraded(config)
    module = algorithm(config["algo"])
    if stochastic:
        from agentax.export import SamplingAlgorithm

        module = SamplingAlgorithm(module)
    cfg = config_from_dict(algorithm_config(config["algo"]), config["config"])
    spec = RUNNERS[config.get("runner_kind", "compiled")]
    if not spec.host_loop:
        from agentax.envs import make_jax
        from agentax.runners.compiled import RunnerConfig
        from agentax.runners.compiled import restore_policy as restore_compiled

        env, runner = make_jax(config["env"]), RunnerConfig(**config["runner"])
        if runner.workers > 1:  # the best seed's worker
            from agentax.runners.workers import split, worker_dir

            parts = split(runner)
            best = _best_seed(run_dir)
            w = next(w for w, part in enumerate(parts) if best < part.seed - runner.seed + part.num_seeds)
            local = best - (parts[w].seed - runner.seed)
            program = compiled_program(module, env, cfg, parts[w])
            return restore_compiled(worker_dir(run_dir, w), program, parts[w], local)
        return restore_compiled(run_dir, compiled_program(module, env, cfg, runner), runner)
    from agentax.runners.host import restore_policy as restore_host

    runner = config.get("runner", {})
    env_spec, _ = host_env_spec(
        config["env"], runner.get("env_backend", "auto"), runner.get("sticky_actions", 0.25)
    )
    return restore_host(run_dir, module.make_agent(env_spec, cfg))


def host_env_spec(env_id: str, backend: str, sticky_actions: float) -> tuple[Any, Any]:
    """``(EnvSpec, Gymnasium's EnvSpec or None)`` of ``env_id`` as the host runners make it."""
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_host_env

    probe = make_host_env(env_id, 1, backend=backend, sticky_actions=sticky_actions)
    specs = EnvSpec.of(probe), getattr(getattr(probe, "vector_env", None), "spec", None)
    probe.close()
    return specs


# Choosing the settings (shared with ``agentax train``).


def parse_stop(value: str, preset: Any, env: Any) -> float | None:
    if value == "none":
        return None
    if value == "auto":
        solved = getattr(env, "reward_threshold", None)
        return float(solved) if preset.stop_at_solved and solved is not None else None
    try:
        return float(value)
    except ValueError:
        raise UsageError(f"--stop-at-return must be a number, 'none' or 'auto', got {value!r}") from None


def _is_jax_env(env_id: str) -> bool:
    from agentax.envs import JAX_ENVS

    return env_id in JAX_ENVS


def _jax_env_ids() -> list[str]:
    from agentax.envs import JAX_ENVS

    return list(JAX_ENVS)


def _is_atari(env_id: str) -> bool:
    from agentax.envs.atari import is_atari_id

    return is_atari_id(env_id)


def _is_envpool_mujoco(env_id: str) -> bool:
    from agentax.envs.envpool_xla import is_envpool_mujoco_id

    return is_envpool_mujoco_id(env_id)


def runner_kind(run_args: RunArgs) -> str:
    """The runner a training uses: ``--runner``, or compiled for a JAX env and host for others."""
    if run_args.runner == "auto":
        return "compiled" if _is_jax_env(run_args.env) else "host"
    from agentax.runners import CHOICES

    if run_args.runner not in CHOICES:
        raise UsageError(f"unknown runner {run_args.runner!r}; choose from {', '.join(CHOICES)}")
    if run_args.runner == "compiled" and _is_atari(run_args.env):
        return "compiled-atari"  # PPO's rollout and EnvPool's step in one program, one seed per process
    if run_args.runner == "compiled" and _is_envpool_mujoco(run_args.env):
        return "compiled-mujoco"  # the same with EnvPool's MuJoCo task (--runner auto: Gymnasium's, host)
    if run_args.runner == "compiled" and not _is_jax_env(run_args.env):
        raise UsageError(
            f"the compiled runner needs one of agentax's JAX envs ({', '.join(_jax_env_ids())}); "
            f"train {run_args.env} with --runner host or --runner parallel"
        )
    return run_args.runner


# Training: the one code path of agentax.train and `agentax train`.


DEFAULT_ACTORS = 2
"""Actors of the parallel and Ray runners when ``--actors`` is not given (and the envs split in two)."""


def agent_maker(module: Any, spec: Any, cfg: Any) -> Any:
    """``make()``: the algorithm's agent for ``spec``, learning in the loop this platform runs best
    (a picklable callable: Ray's actor processes build the agent with it)."""
    from agentax import kernels

    return functools.partial(module.make_agent, spec, cfg, loop=kernels.learning_loop(spec.obs_shape))


def _announce(message: str, quiet: bool) -> None:
    if not quiet:
        print(message, file=sys.stderr)


def _create(out: Path, algo: str, run_args: RunArgs, cfg: Any, kind: str, runner: Any) -> Any:
    """The new run folder ``out``: config.json, and run.toml (the run file that repeats it)."""
    from agentax import runfile
    from agentax.runs import Run as RunFolder
    from agentax.runs import run_config

    config = run_config(algo, run_args.env, run_args.preset, kind, runner, config_to_dict(cfg))
    run = RunFolder.create(out, config)
    header = f"the run in {out}: agentax train --config {out / RUN_FILE} --out NEW_FOLDER repeats it"
    resolved = dataclasses.replace(run_args, preset=choose_preset(algo, run_args.env, run_args.preset)[0])
    runfile.write(out / RUN_FILE, algo, resolved, cfg, header)
    return run


RUN_FILE = "run.toml"
"""The run file (:mod:`agentax.runfile`) every run folder holds beside config.json."""


def start(algo: str, run_args: RunArgs, cfg: Any, preset: Preset, *, quiet: bool = False) -> Run:
    """Create the run folder and train ``cfg`` of ``algo`` as ``run_args`` say; the trained :class:`Run`."""
    from agentax import _xla
    from agentax.runs import default_run_dir

    module = algorithm(algo)
    _xla.enable_compilation_cache()
    out = Path(run_args.out) if run_args.out else default_run_dir(algo, run_args.env)
    kind = runner_kind(run_args)
    if kind == "compiled":
        from agentax.envs import make_jax
        from agentax.runners.compiled import RunnerConfig, check_fits

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
            workers=run_args.workers,
            ray_address=run_args.ray_address,
        )
        # refused before anything is written: what the program cannot do, more seeds than memory holds
        check_fits(compiled_program(module, env, cfg, runner), runner)
        if runner.ray_address is not None and runner.workers == 1:
            raise UsageError(
                "--ray-address sends the compiled runner's --workers to a Ray cluster: give --workers N "
                "(or --runner ray for the Ray runner's actors)"
            )
        run = _create(out, algo, run_args, cfg, "compiled", runner)
        from agentax.runners.workers import split

        shown = f", {len(split(runner))} workers" if runner.workers > 1 else ""
        _announce(f"training {algo} on {run_args.env} ({run_args.seeds} seed(s){shown}) into {out}", quiet)
        if runner.workers > 1:
            return _train_workers(run, runner, resume=False, progress=run_args.progress)
        return _train_compiled(module, env, cfg, runner, run, resume=False, progress=run_args.progress)
    if run_args.workers > 1:
        raise UsageError(
            f"--workers splits the compiled runner's seeds over processes; the {kind} runner trains one "
            "seed (train a JAX env with --runner compiled, or drop the flag)"
        )
    return _start_host(algo, module, run_args, cfg, preset, kind, out, quiet)


def _start_host(
    algo: str, module: Any, run_args: RunArgs, cfg: Any, preset: Preset, kind: str, out: Path, quiet: bool
) -> Run:
    """The host, parallel, ray or compiled Atari runner: one seed per process."""
    from agentax.agents.protocol import OffPolicy
    from agentax.runners import compiled_atari
    from agentax.runners.host import HostRunnerConfig
    from agentax.runners.parallel import ParallelRunnerConfig

    run_args.freeze(preset, kind)  # refused here before anything is made
    if run_args.seeds != 1 and RUNNERS[kind].envs == "any":  # (the compiled Atari check says why)
        raise UsageError(
            f"the {kind} runner trains one seed per process (--seeds 1); --seeds N is compiled-only"
        )
    if kind in ("parallel", "ray") and run_args.envs_per_actor is not None:
        envs = "num_envs" if hasattr(cfg, "num_envs") else "episodes_per_update"
        actors = run_args.actors or DEFAULT_ACTORS
        cfg = dataclasses.replace(cfg, **{envs: actors * run_args.envs_per_actor}).validate()
    atari = {"env_backend": run_args.env_backend, "sticky_actions": run_args.sticky_actions}
    spec, env_spec = host_env_spec(run_args.env, run_args.env_backend, run_args.sticky_actions)
    remake = agent_maker(module, spec, cfg)
    agent = remake()  # refuses what the agent cannot train before anything is written
    stop = parse_stop(run_args.stop_at_return, preset, env_spec)
    common = {
        "seed": run_args.seed,
        "eval_episodes": preset.eval_episodes,
        "stop_at_return": stop,
        "checkpoint_replay": run_args.checkpoint_replay,
        **atari,
    }
    if kind in ("parallel", "ray"):
        actors = run_args.actors or (DEFAULT_ACTORS if agent.experience.num_envs % DEFAULT_ACTORS == 0 else 1)
        parallel = {"actors": actors, "policy_lag": run_args.policy_lag}
        if kind == "ray":
            from agentax.runners.ray import RayRunnerConfig

            ray = {"ray_address": run_args.ray_address, "cpus_per_actor": run_args.cpus_per_actor}
            runner = RayRunnerConfig(**common, **parallel, **ray)
        else:
            runner = ParallelRunnerConfig(**common, **parallel)
        runner.check(agent)
        where = f"{runner.actors} {'Ray ' if kind == 'ray' else ''}actor{'s' if runner.actors > 1 else ''}"
        if not isinstance(agent.experience, OffPolicy):
            where += f", policy lag {runner.policy_lag}"
    else:
        runner, where = HostRunnerConfig(**common), "host"
        if RUNNERS[kind].envs in ("atari", "mujoco"):
            compiled_atari.check(agent, run_args.env, runner, run_args.seeds)
            where = "compiled, EnvPool inside the program"
    run = _create(out, algo, run_args, cfg, kind, runner)
    _announce(f"training {algo} on {run_args.env} ({where}) into {out}", quiet)
    return _train_host(agent, remake, kind, runner, run, resume=False, progress=run_args.progress)


def _train_host(
    agent: Any, remake: Any, kind: str, runner: Any, run: Any, *, resume: bool, progress: bool
) -> Run:
    """A runner that steps its envs outside one program; ``remake()`` builds ``agent`` again (in the
    actor processes of a runner that has them)."""
    start_time = time.perf_counter()
    spec = RUNNERS[kind]
    options = {
        "resume": resume,
        "progress": progress,
        **({"make_agent": remake} if spec.remakes_agent else {}),
    }
    result = spec.load().train(agent, run.config["env"], runner, run, **options)
    seconds = time.perf_counter() - start_time
    return Run(run.path, run.config, result, seconds, greedy=agent.greedy_policy(result.state))


def _train_compiled(
    module: Any, env: Any, cfg: Any, runner: Any, run: Any, *, resume: bool, progress: bool
) -> Run:
    from agentax.runners.compiled import train

    start_time = time.perf_counter()
    # algo, env id, config and the freeze determine the program (agentax's own envs take no params)
    description = {key: run.config[key] for key in ("algo", "env", "config")}
    description["freeze"] = [runner.freeze_at_return, runner.freeze_episodes]
    compiled_algorithm = compiled_program(module, env, cfg, runner)
    result = train(
        compiled_algorithm,
        env,
        runner,
        run,
        resume=resume,
        progress=progress,
        program_description=description,
    )
    seconds = time.perf_counter() - start_time
    per_seed = result.eval.get("per_seed", [])
    best = int(np.argmax([s["mean_return"] for s in per_seed])) if per_seed else 0  # as restore_policy
    greedy = compiled_algorithm.greedy_policy(jax.tree.map(lambda x: x[best], result.state))
    return Run(run.path, run.config, result, seconds, greedy=greedy)


def resume(run_dir: str | Path, progress: bool = True, *, quiet: bool = False) -> Run:
    """Continue the run in ``run_dir`` from its newest good checkpoint; the trained :class:`Run`. A
    run stopped before its first checkpoint loses nothing by starting again: it trains from its
    config.json (its rows, if any, dropped)."""
    from agentax import _xla
    from agentax.runs import Run as RunFolder
    from agentax.runs import checkpoints, read_config

    run_dir = Path(run_dir)
    config = _upgraded(read_config(run_dir))
    # (a run of workers decides worker by worker: those without a checkpoint start again)
    resume = config.get("runner", {}).get("workers", 1) > 1 or bool(checkpoints(run_dir))
    algo = config["algo"]
    module = algorithm(algo)
    cfg = config_from_dict(algorithm_config(algo), config["config"])
    _xla.enable_compilation_cache()
    kind = config.get("runner_kind", "compiled")
    _announce(f"resuming {algo} on {config['env']} ({kind} runner) from {run_dir}", quiet)
    if not resume:
        _announce(f"{run_dir} has no checkpoint yet: training it from its config.json", quiet)
        RunFolder.open(run_dir).truncate_metrics(0)
    if kind not in RUNNERS:
        raise UsageError(
            f"{run_dir}/config.json names an unknown runner {kind!r}; known: {', '.join(RUNNERS)}"
        )
    try:
        runner = RUNNERS[kind].config_type()(**config["runner"])
    except (KeyError, TypeError) as error:
        raise UsageError(f"{run_dir}/config.json has no valid 'runner' settings ({error})") from None
    if RUNNERS[kind].host_loop:
        env_spec, _ = host_env_spec(config["env"], runner.env_backend, runner.sticky_actions)
        remake = agent_maker(module, env_spec, cfg)
        return _train_host(
            remake(), remake, kind, runner, RunFolder.open(run_dir), resume=resume, progress=progress
        )
    from agentax.envs import make_jax

    if runner.workers > 1:
        return _train_workers(RunFolder.open(run_dir), runner, resume=True, progress=progress)
    env = make_jax(config["env"])
    return _train_compiled(
        module, env, cfg, runner, RunFolder.open(run_dir), resume=resume, progress=progress
    )


def _train_workers(run: Any, runner: Any, *, resume: bool, progress: bool) -> Run:
    """Train the seeds of ``runner`` split over ``runner.workers`` processes
    (:mod:`agentax.runners.workers`), each in ``worker-<w>/`` (resumed, or read back where it
    finished), then write the run's merged metrics, eval.json and curve.png."""
    import shutil

    from agentax.curves import plot_curves
    from agentax.runners.session import TrainResult
    from agentax.runners.workers import FINAL_RETURNS, map_processes, merge_rows, split, worker_dir
    from agentax.runs import Run as RunFolder
    from agentax.runs import read_json, read_metrics

    start_time = time.perf_counter()
    parts = split(runner)
    jobs = [(str(run.path.resolve()), w, part, resume, progress and w == 0) for w, part in enumerate(parts)]
    try:
        timings = map_processes(_train_worker, jobs, runner.ray_address)
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
    merged = RunFolder(run.path, run.config)
    for row in rows:
        merged.log(row)
    finals = [read_json(f / FINAL_RETURNS) for f in folders]
    solved = [t["solved_env_steps"] for t in timings]
    result = TrainResult(
        state=None,
        updates=int(rows[-1]["updates"]),
        env_steps=float(rows[-1]["env_steps"]),
        eval={},
        rows=rows,
        solved_env_steps=None if None in solved else max(solved),
        solved_seconds=None if None in solved else max(t["solved_seconds"] for t in timings),
        compile_seconds=max(t["compile_seconds"] for t in timings),
        train_seconds=max(t["train_seconds"] for t in timings),
    )
    result.eval = merged.write_eval(
        np.concatenate([np.asarray(f["returns"]) for f in finals]),
        np.concatenate([np.asarray(f["lengths"]) for f in finals]),
        env_steps=result.env_steps,
        updates=result.updates,
        solved_env_steps=result.solved_env_steps,
        solved_seconds=result.solved_seconds,
        compile_seconds=result.compile_seconds,
        train_seconds=result.train_seconds,
        workers=len(parts),
    )
    merged.close()
    plot_curves([run.path], run.path / "curve.png")
    return Run(run.path, run.config, result, time.perf_counter() - start_time)


def _train_worker(run_dir: str, w: int, runner: Any, resume: bool, progress: bool) -> dict[str, Any]:
    """Worker ``w`` of a run (in a process of its own): its seeds (``runner``) as a compiled run in
    ``worker-<w>/``, resumed from its checkpoint if there is one; its timings. A worker that had
    finished is only read back."""
    import shutil

    from agentax.envs import make_jax
    from agentax.runners.workers import FINAL_RETURNS, node, worker_dir
    from agentax.runs import Run as RunFolder
    from agentax.runs import checkpoints, read_config, read_json, write_json

    folder = worker_dir(run_dir, w)
    done = folder / FINAL_RETURNS
    if done.is_file():
        return read_json(done)["timings"]
    config = read_config(run_dir)
    module = algorithm(config["algo"])
    cfg = config_from_dict(algorithm_config(config["algo"]), config["config"])
    resumed = resume and (folder / "config.json").is_file() and bool(checkpoints(folder))
    if resumed:
        run = RunFolder.open(folder)
    else:
        if folder.exists():  # made but never checkpointed: start it again
            shutil.rmtree(folder)
        run = RunFolder.create(folder, {**config, "runner": dataclasses.asdict(runner)})
    trained = _train_compiled(
        module, make_jax(config["env"]), cfg, runner, run, resume=resumed, progress=progress
    )
    result = trained.result
    timings = {
        name: getattr(result, name)
        for name in ("solved_env_steps", "solved_seconds", "compile_seconds", "train_seconds")
    }
    returns, lengths = result.final_returns
    finals = {"returns": returns.tolist(), "lengths": lengths.tolist(), "timings": timings, "node": node()}
    write_json(done, finals)
    return timings


def _overridden(cfg: Any, overrides: dict[str, Any]) -> Any:
    """``cfg`` with ``overrides`` (lists become tuples, as in config.json), validated."""
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}
    cfg = dataclasses.replace(cfg, **values)
    return cfg.validate() if hasattr(cfg, "validate") else cfg


def train(
    algo: str,
    env: str = "CartPole-v1",
    *,
    seeds: int = 1,
    total_steps: int | None = None,
    preset: str = "auto",
    out: str | Path | None = None,
    seed: int = 0,
    runner: str = "auto",
    actors: int | None = None,
    policy_lag: int = 1,
    stop_at_return: float | str | None = "auto",
    progress: bool = True,
    **overrides: Any,
) -> Run:
    """Train ``algo`` ('reinforce', 'ppo', 'dqn') on ``env`` into a run folder, as ``agentax train`` does.

    ``preset`` ('auto': the algorithm's preset for the env) gives the starting config; ``total_steps``
    and any further keyword naming a field of the algorithm's config (``learning_rate=1e-3``,
    ``num_envs=8``) or of :class:`RunArgs` (``envs_per_actor=4``, ``env_backend='ale'``) override it;
    another name is a :class:`~agentax.errors.UsageError` listing the known ones. ``runner``:
    'auto' (compiled for agentax's JAX envs, else host), 'compiled', 'host' or 'parallel'.
    ``stop_at_return``: a number, ``None`` (train all ``total_steps``) or 'auto' (the env's solved
    threshold in solving presets). ``out``: the run folder (default ``runs/<algo>-<env>-<time>``).
    ``progress``: the progress bar and the line naming the folder, on stderr.
    """
    preset_name, chosen = choose_preset(algo, env, preset)
    run_fields = [f.name for f in dataclasses.fields(RunArgs)]
    config_fields = [f.name for f in dataclasses.fields(chosen.config)]
    unknown = sorted(set(overrides) - set(run_fields) - set(config_fields))
    if unknown:
        raise UsageError(
            f"unknown {algo} setting{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
            f"the {type(chosen.config).__name__} fields are {', '.join(config_fields)}; "
            f"the run's: {', '.join(run_fields)}"
        )
    config_overrides = {k: v for k, v in overrides.items() if k in config_fields}
    if total_steps is not None:
        config_overrides["total_steps"] = total_steps
    run_args = RunArgs(
        env=env,
        preset=preset_name,
        seed=seed,
        seeds=seeds,
        stop_at_return="none" if stop_at_return is None else str(stop_at_return),
        out=None if out is None else str(out),
        progress=progress,
        runner=runner,
        actors=actors,
        policy_lag=policy_lag,
        **{k: v for k, v in overrides.items() if k in run_fields},
    ).check()
    cfg = _overridden(chosen.config, config_overrides)
    return start(algo, run_args, cfg, chosen, quiet=not progress)
