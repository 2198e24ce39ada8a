"""``agentax train ALGO --env ID [--runner compiled|host|parallel|ray] [--preset NAME] [--seeds N] ...``.

Also ``agentax train --config FILE [flags]`` (a run file, :mod:`agentax.runfile`: its fields are
the flags' defaults, so the flags given override them) and ``agentax train --resume DIR`` (continue
an interrupted run from its newest good checkpoint).
The algorithm's config dataclass becomes flags (``--learning-rate``, ``--num-envs``, ...), its
defaults taken from the preset. ``--runner auto`` trains agentax's JAX envs on the compiled runner
(all seeds in one vmapped program) and other ids on the host runner; ``host``, ``parallel``
(``--actors N --envs-per-actor M --policy-lag L``) and ``ray`` (the same, ``--ray-address A``) take
any env id, agentax's own stepped on the host.

The algorithms are those of ``agentax.agents.ALGORITHMS``; each follows
``agentax.agents.protocol``. A config's ``validate()`` raises UsageError on bad values (not
``__post_init__``: tyro would turn that error into a multi-line box).

This module only parses: :class:`~agentax.api.RunArgs` and the training itself live in
:mod:`agentax.api`, the code path of ``agentax.train(...)`` too.
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Annotated, Any

import tyro

from agentax import api, runfile
from agentax.agents import ALGORITHMS, algorithm_config, presets_of
from agentax.api import RunArgs
from agentax.errors import UsageError


def _option(argv: list[str], name: str, default: str) -> str:
    """The value of ``--name V`` / ``--name=V`` in argv (read before tyro, to pick the defaults)."""
    for i, arg in enumerate(argv):
        if arg == name and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(name + "="):
            return arg.split("=", 1)[1]
    return default


ALIASES: dict[str, dict[str, tuple[str, ...]]] = {
    "dqn": {"target_update_period": ("--target-update",), "prioritized": ("--per",)},
}
"""Short flags besides the generated ones: algorithm → config field → its extra flags."""


def with_aliases(config_type: type, aliases: dict[str, tuple[str, ...]]) -> type:
    """``config_type`` as tyro parses it: a subclass whose ``aliases`` fields are annotated with
    ``tyro.conf.arg(aliases=...)``. The fields keep their order and defaults, and tyro reads their
    docstrings from the base class, so ``--help`` reads as the config's own."""
    if not aliases:
        return config_type
    hints = typing.get_type_hints(config_type)
    defaults = {field.name: field.default for field in dataclasses.fields(config_type)}
    fields = [
        (
            name,
            Annotated[hints[name], tyro.conf.arg(aliases=flags)],
            dataclasses.field(default=defaults[name]),
        )
        for name, flags in aliases.items()
    ]
    namespace = {"__doc__": config_type.__doc__, "__module__": config_type.__module__}
    return dataclasses.make_dataclass(
        config_type.__name__, fields, bases=(config_type,), frozen=True, namespace=namespace
    )


def _encoder_pairs(args: list[str]) -> dict[str, str]:
    """``--encoder KEY=CHOICE`` as ``{KEY: CHOICE}`` (no ``=``: an empty choice, refused with the
    choices there are once the env's keys are known)."""
    return {key: choice for key, _, choice in (arg.partition("=") for arg in args)}


ENCODER_FLAG = tyro.constructors.PrimitiveConstructorSpec(
    nargs=1,
    metavar="KEY=CHOICE",
    instance_from_str=_encoder_pairs,
    is_instance=lambda value: isinstance(value, dict),
    str_from_instance=lambda pairs: [f"{key}={choice}" for key, choice in pairs.items()],
    _action="append",  # repeatable, each adding to the run file's table (tyro's own dict flags' action)
)
"""``RunArgs.encoders`` on the command line: ``--encoder image=flat --encoder 0=scalar``. A
primitive spec, not tyro's dict rule: that one turns a non-empty default (a run file's table) into
one flag per key, and no key could be added."""


def cli_run_args() -> type:
    """:class:`RunArgs` as tyro parses it: ``encoders`` as the repeatable ``--encoder KEY=CHOICE``
    (:data:`ENCODER_FLAG`); the other fields, defaults and docstrings as RunArgs's own."""
    flag = Annotated[dict[str, str], ENCODER_FLAG, tyro.conf.arg(name="encoder")]
    field = dataclasses.field(default_factory=dict)
    namespace = {"__doc__": RunArgs.__doc__, "__module__": RunArgs.__module__}
    return dataclasses.make_dataclass(
        RunArgs.__name__, [("encoders", flag, field)], bases=(RunArgs,), frozen=True, namespace=namespace
    )


def _as(cls: type, value: Any) -> Any:
    """``value``, a config of ``cls`` or of a class with the same fields, as a ``cls``."""
    if type(value) is cls:
        return value
    return cls(**{field.name: getattr(value, field.name) for field in dataclasses.fields(cls)})


def parse(algo: str, argv: list[str], base: runfile.RunFile | None = None) -> tuple[RunArgs, Any, Any]:
    """``(run_args, algorithm config, preset)`` from the command line; the flags' defaults are the
    preset's, or ``base``'s (a run file's) where given."""
    if base is None:
        preset_name, preset = api.choose_preset(
            algo, _option(argv, "--env", RunArgs.env), _option(argv, "--preset", "auto")
        )
        default_run, default_config = RunArgs(preset=preset_name), preset.config
    else:
        default_run, default_config, preset = base.run_args, base.config, base.preset
    presets = presets_of(algo)
    config_type = type(preset.config)
    check_core_flags(algo, config_type, argv)
    cli_type = with_aliases(config_type, ALIASES.get(algo, {}))
    run_type = cli_run_args()

    Args = dataclasses.make_dataclass(
        "Args",
        [
            ("run", Annotated[run_type, tyro.conf.OmitArgPrefixes]),
            ("config", Annotated[cli_type, tyro.conf.OmitArgPrefixes]),
        ],
        frozen=True,
    )

    args = tyro.cli(
        Args,
        args=argv,
        prog=f"agentax train {algo}",
        default=Args(_as(run_type, default_run), _as(cli_type, default_config)),
        description=f"Train {algo}. Presets: "
        + "; ".join(f"{name}: {p.description}" for name, p in presets.items()),
    )
    config = _as(config_type, args.config)
    if hasattr(config, "validate"):
        config.validate()
    if base is not None:  # --env or --preset beside --config: the preset of the run as it is
        preset = api.choose_preset(algo, args.run.env, args.run.preset)[1]
    return _as(RunArgs, args.run).check(), config, preset


CORE_FLAGS = ("--core", "--core-size", "--bptt")
"""The recurrent core's flags, which only the algorithms with a ``core`` field take."""


def check_core_flags(algo: str, config_type: type, argv: list[str]) -> None:
    """A one-line ``UsageError`` for a recurrent core's flag given to a feed-forward algorithm."""
    given = [flag for flag in CORE_FLAGS if any(a == flag or a.startswith(flag + "=") for a in argv)]
    if given and not has_core(config_type):
        raise UsageError(
            f"{given[0]}: {algo} has no recurrent core; {takers(has_core)} one (--core lstm|gru)"
        )
    if "--bptt" in given and not has_core(config_type, "bptt"):
        raise UsageError(
            f"--bptt: {algo} learns its core through whole episodes; {takers(lambda c: has_core(c, 'bptt'))} "
            "--bptt"
        )


def takers(takes: Any) -> str:
    """The algorithms whose config ``takes(config_type)``, as a sentence's subject: "ppo takes",
    "reinforce, ppo and pqn take"."""
    names = [name for name in ALGORITHMS if takes(algorithm_config(name))]
    return names[0] + " takes" if len(names) == 1 else ", ".join(names[:-1]) + f" and {names[-1]} take"


def has_core(config_type: type, field_name: str = "core") -> bool:
    """Whether ``config_type`` has the core's field ``field_name``."""
    return field_name in {field.name for field in dataclasses.fields(config_type)}


def parse_file(argv: list[str]) -> tuple[str, RunArgs, Any, Any]:
    """``(algo, run_args, config, preset)`` of ``[ALGO] --config FILE [flags]``: the run file's
    fields, the flags beside it overriding them (checked as the flags are, :mod:`agentax.runfile`)."""
    path, rest = _config_path(argv)
    base = runfile.load(path, env=_option(rest, "--env", ""), preset=_option(rest, "--preset", ""))
    if rest and not rest[0].startswith("-"):
        if rest[0] != base.algo:
            raise UsageError(f"--config {path} trains {base.algo}, not {rest[0]}: drop {rest[0]} or the file")
        rest = rest[1:]
    return (base.algo, *parse(base.algo, rest, base))


def _config_path(argv: list[str]) -> tuple[str, list[str]]:
    """The FILE of ``--config FILE`` / ``--config=FILE`` and argv without it."""
    for i, arg in enumerate(argv):
        if arg == "--config":
            if i + 1 >= len(argv):
                raise UsageError("--config needs the run file: agentax train --config FILE")
            return argv[i + 1], argv[:i] + argv[i + 2 :]
        if arg.startswith("--config="):
            return arg.partition("=")[2], argv[:i] + argv[i + 1 :]
    raise UsageError("no --config FILE")


def has_config(argv: list[str]) -> bool:
    return any(arg == "--config" or arg.startswith("--config=") for arg in argv)


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: agentax train ALGO [--env ID] [--preset NAME] [--seed S] [--seeds N] [--total-steps N]")
        print("                         [--stop-at-return R|none] [--out DIR] [algorithm flags...]")
        print("       agentax train --config FILE [flags overriding its fields]  (a run file, TOML)")
        print("       agentax train --resume DIR")
        print("                         [--runner compiled|host|parallel|ray] [--actors N] [--policy-lag L]")
        print("                         [--ray-address auto|HOST:PORT] [--cpus-per-actor C]")
        print("                         [--workers N]  (compiled runner: the seeds over N processes)")
        print(f"algorithms: {', '.join(ALGORITHMS)} (agentax train ALGO --help for its flags and presets)")
        return 0
    if argv[0] == "--resume" or argv[0].startswith("--resume="):
        run_dir = argv[1] if argv[0] == "--resume" and len(argv) > 1 else argv[0].partition("=")[2]
        if not run_dir:
            raise UsageError("--resume needs the run folder: agentax train --resume DIR")
        return resume(Path(run_dir), progress="--no-progress" not in argv)
    if has_config(argv):
        return start(*parse_file(argv))
    algo, rest = argv[0], argv[1:]
    run_args, cfg, preset = parse(algo, rest)
    return start(algo, run_args, cfg, preset)


def start(algo: str, run_args: RunArgs, cfg: Any, preset: Any) -> int:
    """Create the run folder, train (:func:`agentax.api.start`) and print the result."""
    return _print(api.start(algo, run_args, cfg, preset))


def resume(run_dir: Path, progress: bool = True) -> int:
    """Continue the run in ``run_dir`` (:func:`agentax.api.resume`) and print the result."""
    return _print(api.resume(run_dir, progress))


def _print(run: api.Run) -> int:
    compiled = run.result.compile_seconds > 0  # a runner that compiles one program: its timings
    report(run.result.eval, run.path, run.seconds, run.result if compiled else None)
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
