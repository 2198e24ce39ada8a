"""``agentax train ALGO --env ID [--runner compiled|host|parallel] [--preset NAME] [--seeds N] ...``.

Also ``agentax train --resume DIR`` (continue an interrupted run from its newest good checkpoint).
The algorithm's config dataclass becomes flags (``--learning-rate``, ``--num-envs``, ...), its
defaults taken from the preset. ``--runner auto`` trains agentax's JAX envs on the compiled runner
(all seeds in one vmapped program) and other ids on the host runner; ``host`` and ``parallel``
(``--actors N --envs-per-actor M --policy-lag L``) take any env id, agentax's own stepped on the host.

The algorithms are those of ``agentax.agents.ALGORITHMS``; each follows
``agentax.agents.protocol``. A config's ``validate()`` raises UsageError on bad values (not
``__post_init__``: tyro would turn that error into a multi-line box).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import tyro

from agentax.agents import ALGORITHMS, algorithm
from agentax.errors import UsageError


@dataclass(frozen=True)
class RunArgs:
    """Where and how to train (the algorithm's own settings follow)."""

    env: str = "CartPole-v1"
    """environment id (agentax's JAX envs train compiled; other Gymnasium ids on the host)"""
    preset: str = "auto"
    """named, tuned settings to start from; 'auto' picks the algorithm's preset for the env, else 'default'"""
    seed: int = 0
    """seed of the first agent (agent k uses seed + k)"""
    seeds: int = 1
    """independent agents trained together (vmapped into one program)"""
    stop_at_return: str = "auto"
    """stop once the evaluation mean reaches this number; 'none' trains for all of total_steps; 'auto' uses
    the env's solved threshold in solving presets"""
    out: str | None = None
    """run folder (default runs/<algo>-<env>-<time>)"""
    progress: bool = True
    """show a progress bar"""
    runner: str = "auto"
    """compiled (JAX envs, seeds vmapped), host (any env, one step after the other), parallel (actor
    threads beside a learner); auto: compiled for agentax's JAX envs, else host"""
    actors: int = 2
    """parallel runner: actor threads (the envs are split evenly between them)"""
    envs_per_actor: int | None = None
    """parallel runner: envs per actor (sets the algorithm's number of envs to actors × this)"""
    policy_lag: int = 1
    """parallel runner, on-policy: parameter versions between collecting and learning (0: sequential)"""
    env_backend: str = "auto"
    """Atari: envpool or ale (ale-py with Gymnasium's wrappers); auto: envpool where it is installed"""
    checkpoint_replay: bool = True
    """off-policy (host, parallel): save the replay buffer with the checkpoints (--no-checkpoint-replay)"""
    sticky_actions: float = 0.25
    """Atari: probability that the emulator repeats the last action (0.25 as Gymnasium's v5; 0 as
    CleanRL's and EnvPool's published figures)"""


_module = algorithm


def _option(argv: list[str], name: str, default: str) -> str:
    """The value of ``--name V`` / ``--name=V`` in argv (read before tyro, to pick the defaults)."""
    for i, arg in enumerate(argv):
        if arg == name and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(name + "="):
            return arg.split("=", 1)[1]
    return default


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


def parse(algo: str, argv: list[str]) -> tuple[RunArgs, Any, Any]:
    """``(run_args, algorithm config, preset)`` from the command line."""
    module = _module(algo)
    preset_name = _option(argv, "--preset", "auto")
    if preset_name == "auto":
        env_id = _option(argv, "--env", RunArgs.env)
        from agentax.envs.atari import is_atari_id

        key = "atari" if is_atari_id(env_id) else env_id
        preset_name = getattr(module, "DEFAULT_PRESETS", {}).get(key, "default")
    if preset_name not in module.PRESETS:
        raise UsageError(f"unknown {algo} preset {preset_name!r}; choose from {', '.join(module.PRESETS)}")
    preset = module.PRESETS[preset_name]
    config_type = type(preset.config)

    Args = dataclasses.make_dataclass(
        "Args",
        [
            ("run", Annotated[RunArgs, tyro.conf.OmitArgPrefixes]),
            ("config", Annotated[config_type, tyro.conf.OmitArgPrefixes]),
        ],
        frozen=True,
    )

    args = tyro.cli(
        Args,
        args=argv,
        prog=f"agentax train {algo}",
        default=Args(RunArgs(preset=preset_name), preset.config),
        description=f"Train {algo}. Presets: "
        + "; ".join(f"{name}: {p.description}" for name, p in module.PRESETS.items()),
    )
    if hasattr(args.config, "validate"):
        args.config.validate()
    if args.run.seeds < 1:
        raise UsageError(f"--seeds must be at least 1, got {args.run.seeds}")
    return args.run, args.config, preset


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: agentax train ALGO [--env ID] [--preset NAME] [--seed S] [--seeds N] [--total-steps N]")
        print("                         [--stop-at-return R|none] [--out DIR] [algorithm flags...]")
        print("       agentax train --resume DIR")
        print("                         [--runner compiled|host|parallel] [--actors N] [--policy-lag L]")
        print(f"algorithms: {', '.join(ALGORITHMS)} (agentax train ALGO --help for its flags and presets)")
        return 0
    if argv[0] == "--resume" or argv[0].startswith("--resume="):
        run_dir = argv[1] if argv[0] == "--resume" and len(argv) > 1 else argv[0].partition("=")[2]
        if not run_dir:
            raise UsageError("--resume needs the run folder: agentax train --resume DIR")
        return resume(Path(run_dir), progress="--no-progress" not in argv)
    algo, rest = argv[0], argv[1:]
    run_args, cfg, preset = parse(algo, rest)
    return start(algo, run_args, cfg, preset)


def _is_jax_env(env_id: str) -> bool:
    from agentax.envs import JAX_ENVS

    return env_id in JAX_ENVS


def runner_kind(run_args: RunArgs) -> str:
    """The runner a training uses: ``--runner``, or compiled for a JAX env and host for others."""
    if run_args.runner == "auto":
        return "compiled" if _is_jax_env(run_args.env) else "host"
    from agentax.train import RUNNERS

    if run_args.runner not in RUNNERS:
        raise UsageError(f"unknown runner {run_args.runner!r}; choose from {', '.join(RUNNERS)}")
    if run_args.runner == "compiled" and not _is_jax_env(run_args.env):
        raise UsageError(
            f"the compiled runner needs one of agentax's JAX envs ({', '.join(_jax_env_ids())}); "
            f"train {run_args.env} with --runner host or --runner parallel"
        )
    return run_args.runner


def start(algo: str, run_args: RunArgs, cfg: Any, preset: Any) -> int:
    """Create the run folder and train."""
    from agentax import _xla
    from agentax.runs import Run, default_run_dir, run_config

    module = _module(algo)
    _xla.enable_compilation_cache()
    out = Path(run_args.out) if run_args.out else default_run_dir(algo, run_args.env)
    kind = runner_kind(run_args)
    if kind == "compiled":
        from agentax.envs import make_jax
        from agentax.train.compiled import RunnerConfig

        env = make_jax(run_args.env)
        stop = parse_stop(run_args.stop_at_return, preset, env)
        runner = RunnerConfig(
            seed=run_args.seed,
            num_seeds=run_args.seeds,
            updates_per_chunk=preset.updates_per_chunk,
            eval_every_chunks=preset.eval_every_chunks,
            eval_episodes=preset.eval_episodes,
            stop_at_return=stop,
        )
        settings = module.config_to_dict(cfg)
        run = Run.create(out, run_config(algo, run_args.env, run_args.preset, "compiled", runner, settings))
        print(f"training {algo} on {run_args.env} ({run_args.seeds} seed(s)) into {out}", file=sys.stderr)
        return _train_compiled(module, env, cfg, runner, run, resume=False, progress=run_args.progress)
    return _start_host(algo, module, run_args, cfg, preset, kind, out)


def _start_host(algo, module, run_args: RunArgs, cfg, preset, kind: str, out: Path) -> int:
    """The host or parallel runner: one seed per process, any env id."""
    from agentax.agents.protocol import EnvSpec, OffPolicy
    from agentax.runs import Run, run_config
    from agentax.train.host import HostRunnerConfig, make_host_env
    from agentax.train.parallel import ParallelRunnerConfig

    if run_args.seeds != 1:
        raise UsageError(
            f"the {kind} runner trains one seed per process (--seeds 1); --seeds N is compiled-only"
        )
    if kind == "parallel" and run_args.envs_per_actor is not None:
        envs = "num_envs" if hasattr(cfg, "num_envs") else "episodes_per_update"
        cfg = dataclasses.replace(cfg, **{envs: run_args.actors * run_args.envs_per_actor}).validate()
    atari = {"env_backend": run_args.env_backend, "sticky_actions": run_args.sticky_actions}
    probe = make_host_env(
        run_args.env, 1, backend=run_args.env_backend, sticky_actions=run_args.sticky_actions
    )
    spec, env_spec = EnvSpec.of(probe), getattr(getattr(probe, "vector_env", None), "spec", None)
    probe.close()
    agent = module.make_agent(spec, cfg)  # refuses what the agent cannot train before anything is written
    stop = parse_stop(run_args.stop_at_return, preset, env_spec)
    common = {
        "seed": run_args.seed,
        "eval_episodes": preset.eval_episodes,
        "stop_at_return": stop,
        "checkpoint_replay": run_args.checkpoint_replay,
        **atari,
    }
    if kind == "parallel":
        runner = ParallelRunnerConfig(**common, actors=run_args.actors, policy_lag=run_args.policy_lag)
        runner.check(agent)
        where = f"{runner.actors} actor{'s' if runner.actors > 1 else ''}"
        if not isinstance(agent.experience, OffPolicy):
            where += f", policy lag {runner.policy_lag}"
    else:
        runner, where = HostRunnerConfig(**common), "host"
    run = Run.create(
        out, run_config(algo, run_args.env, run_args.preset, kind, runner, module.config_to_dict(cfg))
    )
    print(f"training {algo} on {run_args.env} ({where}) into {out}", file=sys.stderr)
    return _train_host(agent, kind, runner, run, resume=False, progress=run_args.progress)


def _train_host(agent, kind: str, runner, run, *, resume: bool, progress: bool) -> int:
    from agentax.train import host, parallel

    start_time = time.perf_counter()
    train = parallel.train if kind == "parallel" else host.train
    result = train(agent, run.config["env"], runner, run, resume=resume, progress=progress)
    report(result.eval, run.path, time.perf_counter() - start_time)
    return 0


def _jax_env_ids() -> list[str]:
    from agentax.envs import JAX_ENVS

    return list(JAX_ENVS)


def _train_compiled(module, env, cfg, runner, run, *, resume: bool, progress: bool) -> int:
    from agentax.train.compiled import train

    start_time = time.perf_counter()
    # algo, env id and config determine the program (agentax's own envs take no outside params)
    description = {key: run.config[key] for key in ("algo", "env", "config")}
    result = train(
        module.make_train(env, cfg),
        env,
        runner,
        run,
        resume=resume,
        progress=progress,
        program_description=description,
    )
    report(result.eval, run.path, time.perf_counter() - start_time, result)
    return 0


def report(evaluation: dict, path: Path, seconds: float, result: Any = None) -> None:
    """Print the final evaluation and where the run lives."""
    line = (
        f"evaluation: mean return {evaluation['mean_return']:.1f} ± {evaluation['std_return']:.1f} "
        f"(min {evaluation['min_return']:.0f}, max {evaluation['max_return']:.0f}, "
        f"{evaluation['episodes']} episodes"
    )
    per_seed = evaluation.get("per_seed", [])
    if len(per_seed) > 1:
        line += ", per seed " + " ".join(f"{s['mean_return']:.1f}" for s in per_seed)
    print(line + ")")
    if result is not None:
        if result.solved_env_steps is not None:
            print(f"solved after {result.solved_env_steps:,.0f} env steps, {result.solved_seconds:.1f} s")
        print(
            f"{result.env_steps:,.0f} env steps; compile {result.compile_seconds:.1f} s, "
            f"training {result.train_seconds:.1f} s, total {seconds:.1f} s"
        )
    print(f"run folder: {path} (curve.png, eval.json, metrics.csv)")


def resume(run_dir: Path, progress: bool = True) -> int:
    """Continue the run in ``run_dir`` from its newest good checkpoint."""
    from agentax import _xla
    from agentax.runs import Run, latest_checkpoint, read_config

    config = read_config(run_dir)
    latest_checkpoint(run_dir)  # a clear error before anything starts if there is none
    algo = config["algo"]
    module = _module(algo)
    cfg = module.config_from_dict(config["config"])
    _xla.enable_compilation_cache()
    kind = config.get("runner_kind", "compiled")
    print(f"resuming {algo} on {config['env']} ({kind} runner) from {run_dir}", file=sys.stderr)
    try:
        if kind in ("host", "parallel"):
            from agentax.agents.protocol import EnvSpec
            from agentax.train.host import HostRunnerConfig, make_host_env
            from agentax.train.parallel import ParallelRunnerConfig

            runner = (ParallelRunnerConfig if kind == "parallel" else HostRunnerConfig)(**config["runner"])
            probe = make_host_env(
                config["env"], 1, backend=runner.env_backend, sticky_actions=runner.sticky_actions
            )
            spec = EnvSpec.of(probe)
            probe.close()
            agent = module.make_agent(spec, cfg)
            return _train_host(agent, kind, runner, Run.open(run_dir), resume=True, progress=progress)
        from agentax.envs import make_jax
        from agentax.train.compiled import RunnerConfig

        runner = RunnerConfig(**config["runner"])
    except (KeyError, TypeError) as error:
        raise UsageError(f"{run_dir}/config.json has no valid 'runner' settings ({error})") from None
    env = make_jax(config["env"])
    return _train_compiled(module, env, cfg, runner, Run.open(run_dir), resume=True, progress=progress)
