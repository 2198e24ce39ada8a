"""One Python call for what ``agentax train`` does, and the trained run as an object.

::

    import agentax

    run = agentax.train("ppo", env="CartPole-v1", seeds=4, total_steps=50_000, learning_rate=1e-3)
    run.evaluate(episodes=100, seed=1).mean_return   # the statistics `agentax evaluate` prints
    run.metrics[-1]["mean_return"]                    # the rows of metrics.csv
    run.plot("curve.png"); run.video("episode.gif")
    run = agentax.load(run.path)                      # the same, from the folder, later

``agentax train`` parses its flags into a :class:`RunArgs` and the algorithm's config, then calls
:func:`start` (``--resume``: :func:`resume`), as :func:`train` does. Both only read the runners'
table (:mod:`agentax.runners`): it picks the kind, whose launcher configures, trains and restores
it; :func:`restore_policy` rebuilds the greedy policy of any run folder.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from agentax.agents import algorithm, config_to_dict
from agentax.errors import UsageError
from agentax.evaluate import EvalStats
from agentax.policies import Policy
from agentax.runfile import RunArgs, choose_preset
from agentax.runners import algorithm_of, kind_for, kind_of, launch, resumes, runner_settings

if TYPE_CHECKING:
    from agentax.agents.presets import Preset


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
        return kind_of(self.config)

    @functools.cached_property
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
        # restored only once the format is checked, on XLA's convolutions (no FFI call in either format)
        restore = functools.partial(_restore_learned, self.path, self.config, stochastic, "xla")
        return export_run(self.path, self.config, restore, format, path, stochastic)

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r}, algo={self.algo!r}, env={self.env!r}, runner={self.runner_kind!r})"


def load(run_dir: str | Path) -> Run:
    """The run in ``run_dir`` (written by :func:`train` or ``agentax train``)."""
    return Run(run_dir)


def __getattr__(name: str) -> Any:  # names older code (the benchmarks) imports from here, now in the runners
    homes = {"compiled_program": "agentax.runners.compiled", "agent_maker": "agentax.runners.launch"}
    if name in homes:
        return getattr(importlib.import_module(homes[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def restore_policy(run_dir: str | Path) -> tuple[str, Policy]:
    """``(env_id, policy)`` of a trained run: a learning algorithm's greedy policy (its best seed, from
    its newest good checkpoint) or a policy search's (its module's ``load_policy``)."""
    from agentax.agents import ALGORITHMS
    from agentax.runs import read_config
    from agentax.search import load_policy

    config = read_config(run_dir)
    if config["algo"] in ALGORITHMS:
        return config["env"], _restore_learned(Path(run_dir), config)
    return config["env"], load_policy(Path(run_dir), config, also_known=tuple(ALGORITHMS))


def _restore_learned(
    run_dir: Path, config: dict[str, Any], stochastic: bool = False, conv: str | None = None
) -> Policy:
    """The greedy policy of a learning algorithm's run (its best seed), from its newest good checkpoint;
    ``stochastic``: its sampling head instead (:class:`agentax.export.SamplingAlgorithm`); ``conv``:
    its convolution backend (default: the run's entry point chooses)."""
    module, cfg = algorithm_of(config)
    if stochastic:
        from agentax.export import SamplingAlgorithm

        module = SamplingAlgorithm(module)
    return launch.restore(Path(run_dir), config, module, cfg, conv)


def _announce(message: str, quiet: bool) -> None:
    if not quiet:
        print(message, file=sys.stderr)


def _create(out: Path, algo: str, run_args: RunArgs, cfg: Any, kind: str, ready: launch.Launch) -> Any:
    """The new run folder ``out``: config.json (with the networks' precision, ``precision``, and how
    it was chosen, ``precision_choice``), and run.toml (the run file that repeats it)."""
    from agentax import runfile, runs

    runner, precision = ready.runner, ready.precision["precision"]
    settings = config_to_dict(cfg)
    config = runs.run_config(algo, run_args.env, run_args.preset, kind, runner, settings, run_args.encoders)
    config["precision"] = precision
    about = ready.precision
    config["precision_choice"] = {k: about[k] for k in ("mode", "why", "ms") if k in about}
    run = runs.Run.create(out, config)
    header = f"the run in {out}: agentax train --config {out / runs.RUN_FILE} --out NEW_FOLDER repeats it"
    preset = choose_preset(algo, run_args.env, run_args.preset)[0]
    workers = getattr(runner, "workers", run_args.workers)  # the compiled runner's, chosen or given
    resolved = dataclasses.replace(run_args, preset=preset, workers=workers, precision=precision)
    runfile.write(out / runs.RUN_FILE, algo, resolved, cfg, header)
    return run


def _trained(ready: launch.Launch, run: Any, *, resume: bool, progress: bool) -> Run:
    start_time = time.perf_counter()
    result = ready.train(run, resume, progress)
    return Run(run.path, run.config, result, time.perf_counter() - start_time, greedy=result.policy)


def start(algo: str, run_args: RunArgs, cfg: Any, preset: Preset, *, quiet: bool = False) -> Run:
    """Create the run folder and train ``cfg`` of ``algo`` as ``run_args`` say; the trained :class:`Run`."""
    from agentax import _xla, runs

    _xla.enable_compilation_cache()
    out = Path(run_args.out) if run_args.out else runs.default_run_dir(algo, run_args.env)
    kind = kind_for(run_args.runner, run_args.env)
    ready = launch.prepare(algorithm(algo), run_args, cfg, preset, kind)
    run = _create(out, algo, run_args, cfg, kind, ready)
    _announce(f"training {algo} on {run_args.env} ({ready.where}) into {out}", quiet)
    return _trained(ready, run, resume=False, progress=run_args.progress)


def resume(run_dir: str | Path, progress: bool = True, *, quiet: bool = False) -> Run:
    """Continue the run in ``run_dir`` from its newest good checkpoint; the trained :class:`Run`. A
    run stopped before its first checkpoint loses nothing by starting again: it trains from its
    config.json (its rows, if any, dropped)."""
    from agentax import _xla, runs

    run_dir = Path(run_dir)
    config = runs.read_config(run_dir)
    resume = resumes(run_dir, config)
    (module, cfg), algo, kind = algorithm_of(config), config["algo"], kind_of(config)
    _xla.enable_compilation_cache()
    _announce(f"resuming {algo} on {config['env']} ({kind} runner) from {run_dir}", quiet)
    if not resume:
        _announce(f"{run_dir} has no checkpoint yet: training it from its config.json", quiet)
        runs.Run.open(run_dir).truncate_metrics(0)
    runner = runner_settings(config, f"{run_dir}/config.json")
    ready = launch.reopen(config, module, cfg, runner)
    return _trained(ready, runs.Run.open(run_dir), resume=resume, progress=progress)


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
    """Train ``algo`` (a name of :data:`agentax.agents.ALGORITHMS`) on ``env`` into a run folder, as
    ``agentax train`` does.

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
    config_overrides = {
        k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items() if k in config_fields
    }
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
    cfg = dataclasses.replace(chosen.config, **config_overrides)  # (lists as tuples, as in config.json)
    cfg = cfg.validate() if hasattr(cfg, "validate") else cfg
    return start(algo, run_args, cfg, chosen, quiet=not progress)
