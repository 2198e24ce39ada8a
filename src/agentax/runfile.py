"""One training as one file: the run description (:class:`RunArgs` and the algorithm's config) as TOML.

::

    algo = "ppo"
    env = "CartPole-v1"
    preset = "cartpole-fast"
    seeds = 2
    ...
    [config]               # PPOConfig: every field, as --help lists them
    learning_rate = 0.003
    hidden = [64, 64]

``agentax train --config FILE [--flag V ...]`` trains it, the flags overriding its fields; every
run folder holds its own as ``run.toml`` beside config.json (so ``agentax train --config
runs/X/run.toml --out Y`` repeats the run), ``agentax sweep`` writes ``best.toml`` and ``agentax
presets ALGO NAME`` prints a preset's. The top-level keys are :class:`RunArgs`'s fields (the flags'
names with ``_``), ``[config]`` the algorithm's config dataclass's; a key left out keeps the preset's
value (or RunArgs's default). A ``X | None`` field holds ``"none"`` for None (TOML has no null), as
its flag does; ``encoders`` is a table, ``encoders = {image = "flat"}`` (its flag ``--encoder
image=flat``, repeated for each key, adds to the file's).

The checks are the flags' own: a value's type is checked against the same dataclass annotation
tyro builds the flag from, and ranges by the same ``RunArgs.check`` and ``validate()`` the flags
pass through; each bad file is one :class:`~agentax.errors.UsageError` line naming the file and the
key. TOML (Python's own ``tomllib``) rather than YAML: it needs no dependency, has no implicit
typing (YAML 1.1 reads ``no`` as false and ``1e-3`` as a string) and its tables map one to one onto
the two dataclasses; it is written here by :func:`dumps` (a few value kinds, no library needed).
"""

from __future__ import annotations

import dataclasses
import json
import re
import tomllib
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from agentax.agents import ALGORITHMS, algorithm_config, presets_of
from agentax.errors import UsageError
from agentax.kernels import PRECISIONS

if TYPE_CHECKING:
    from agentax.agents.presets import Preset


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
    workers: int | None = None
    """compiled runner: processes the seeds are split over, one per core; default: every core once
    the seeds' program cost (XLA's flops) reaches the measured break-even in a run without
    --stop-at-return, else
    1 (the same split gives the same numbers; --stop-at-return then stops each worker once its own
    seeds reach the return)"""
    stop_at_return: str = "auto"
    """stop once the evaluation mean reaches this number; 'none' trains for all of total_steps; 'auto' uses
    the env's solved threshold in solving presets"""
    out: str | None = None
    """run folder (default runs/<algo>-<env>-<time>)"""
    progress: bool = True
    """show a progress bar"""
    runner: str = "auto"
    """compiled (JAX envs, seeds vmapped; Atari and MuJoCo v5: PPO with EnvPool's step inside the
    program), host (any env, one step after the other), parallel (actor
    threads beside a learner), ray (the parallel runner's actors as Ray actor processes, on any node
    of a cluster); auto: compiled for agentax's JAX envs, else host"""
    actors: int | None = None
    """parallel and ray runners: actors (the envs are split evenly between them); default 2, or 1
    when the preset's envs do not split in two (DQN's Atari presets step one env)"""
    envs_per_actor: int | None = None
    """parallel and ray runners: envs per actor (sets the algorithm's number of envs to actors × this)"""
    policy_lag: int = 1
    """parallel runner (on-policy) and compiled runner on Atari and MuJoCo: parameter versions between
    collecting and learning (0: one after the other)"""
    ray_address: str | None = None
    """ray runner: the Ray cluster to join ('auto', or HOST:PORT of `ray start --head`); default: a
    local Ray for this run, shut down after it. Compiled runner: run the --workers as Ray tasks there"""
    cpus_per_actor: float = 1.0
    """ray runner: CPUs Ray reserves for each actor process"""
    env_backend: str = "auto"
    """Atari: envpool or ale (ale-py with Gymnasium's wrappers); auto: envpool where it is installed.
    MuJoCo: auto is Gymnasium's (mujoco) on the host runners, EnvPool's with --runner compiled"""
    checkpoint_replay: bool = True
    """off-policy (host, parallel): save the replay buffer with the checkpoints (--no-checkpoint-replay)"""
    sticky_actions: float = 0.25
    """Atari: probability that the emulator repeats the last action (0.25 as Gymnasium's v5; 0 as
    CleanRL's and EnvPool's published figures)"""
    freeze_at_return: str = "auto"
    """compiled runner, off-policy agents: each seed stops learning once its greedy policy's last
    freeze_episodes side episodes all return at least this; 'none': never; 'auto': the preset's"""
    freeze_episodes: int = 8
    """compiled runner: the greedy side episodes behind --freeze-at-return"""
    encoders: dict[str, str] = dataclasses.field(default_factory=dict)
    """the encoder of an observation's leaf, by its key (a Dict key, a Tuple position, 'obs' for one
    leaf): images auto, nature, small or flat; Discrete and MultiDiscrete auto, one_hot or scalar;
    vectors and MultiBinary auto or flat (docs/howto/spaces.md)"""
    precision: str = "f32"
    """the networks' products: f32 (float32, today's numbers exactly), bf16 (bfloat16 operands summed
    in float32; parameters, optimizer state, targets and replay stay float32) or auto (bf16 where a
    learning step of the run's width measures faster on this machine, measured once and kept); the
    run folder records the one used"""

    def check(self) -> RunArgs:
        """Raise ``UsageError`` on a value no runner accepts; return ``self``."""
        if self.seeds < 1:
            raise UsageError(f"--seeds must be at least 1, got {self.seeds}")
        if self.workers is not None and self.workers < 1:
            raise UsageError(f"--workers must be at least 1, got {self.workers}")
        if self.precision not in PRECISION_MODES:
            choices = ", ".join(PRECISION_MODES)
            raise UsageError(f"--precision must be one of {choices}, got {self.precision!r}")
        if self.freeze_at_return not in ("auto", "none"):
            try:
                float(self.freeze_at_return)
            except ValueError:
                raise UsageError(
                    f"--freeze-at-return must be a number, 'none' or 'auto', got {self.freeze_at_return!r}"
                ) from None
        return self


PRECISION_MODES = ("auto", *PRECISIONS)
"""What ``--precision`` takes: ``auto`` or one of :data:`agentax.kernels.PRECISIONS`."""
NOT_WRITTEN = ("out", "progress")
"""RunArgs fields of one invocation, not of the training: a written run file leaves them out."""


def choose_preset(algo: str, env_id: str, name: str = "auto") -> tuple[str, Preset]:
    """``(name, preset)``: ``name``, or for 'auto' the algorithm's preset for the env (any Atari id
    counts as 'atari'), else 'default'."""
    presets = presets_of(algo)
    if name == "auto":
        from agentax.agents.presets import DEFAULT_PRESETS
        from agentax.envs.atari import is_atari_id

        key = "atari" if is_atari_id(env_id) else env_id
        name = DEFAULT_PRESETS.get(algo, {}).get(key, "default")
    if name not in presets:
        raise UsageError(f"unknown {algo} preset {name!r}; choose from {', '.join(presets)}")
    return name, presets[name]


# Writing.


def dumps(algo: str, run_args: RunArgs, cfg: Any, header: str = "") -> str:
    """The run file of ``cfg`` of ``algo`` trained as ``run_args`` say (every field but
    :data:`NOT_WRITTEN`; a None whose default is None left out)."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines += [f"algo = {_value(algo)}"]
    lines += _table(run_args, skip=NOT_WRITTEN)
    lines += ["", f"[config]  # {type(cfg).__name__}: agentax train {algo} --help says what each field does"]
    lines += _table(cfg)
    return "\n".join(lines) + "\n"


def write(path: str | Path, algo: str, run_args: RunArgs, cfg: Any, header: str = "") -> Path:
    """Write :func:`dumps` to ``path`` atomically; the path."""
    from agentax.runs import write_atomic

    write_atomic(Path(path), dumps(algo, run_args, cfg, header).encode())
    return Path(path)


def _table(obj: Any, skip: tuple[str, ...] = ()) -> list[str]:
    rows = []
    for field in dataclasses.fields(obj):
        value = getattr(obj, field.name)
        if field.name in skip or (value is None and field.default is None) or value == {}:
            continue
        rows.append(f"{field.name} = {_value(value)}")
    return rows


def _value(value: Any) -> str:
    """One TOML value: a string (JSON's escapes are TOML's), bool, int, float (repr round-trips,
    nan and inf included), an array of them, or None as "none"."""
    if value is None:
        return '"none"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"{type(value).__name__} has no TOML form here")


def _key(key: str) -> str:
    """A TOML key: bare where it may be (letters, digits, ``_`` and ``-``), else quoted."""
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key, ensure_ascii=False)


# Reading.


@dataclass(frozen=True)
class RunFile:
    """A run file read and checked: what ``agentax train`` needs to start."""

    algo: str
    run_args: RunArgs
    config: Any
    preset: Preset


def read(path: str | Path) -> dict[str, Any]:
    """The TOML table in ``path``; one line for a file that cannot be read, is empty or is not TOML."""
    path = Path(path)
    try:
        text = path.read_bytes().decode()
    except (OSError, UnicodeDecodeError) as error:
        why = error.strerror if isinstance(error, OSError) and error.strerror else str(error)
        raise UsageError(f"--config {path}: cannot read the run file ({why})") from None
    if not text.strip():
        raise UsageError(f'--config {path}: the run file is empty; it needs at least algo = "NAME"')
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise UsageError(f"--config {path}: not valid TOML ({error})") from None


def load(path: str | Path, *, env: str | None = None, preset: str | None = None) -> RunFile:
    """Read and check the run file ``path``: its algorithm, :class:`RunArgs` and config (the preset's
    values under the file's); ``env`` and ``preset`` (flags given beside it) replace the file's
    before the preset is chosen. Every error is one line naming the file and the key."""
    table = read(path)
    where = f"--config {path}"
    if "algo" not in table:
        raise UsageError(f"{where}: missing the required key 'algo' (one of {', '.join(ALGORITHMS)})")
    algo = table.pop("algo")
    if algo not in ALGORITHMS:
        raise UsageError(f"{where}: unknown algorithm algo = {algo!r}; choose from {', '.join(ALGORITHMS)}")
    config = table.pop("config", {})
    if not isinstance(config, dict):
        raise UsageError(f"{where}: config must be a table ([config]), got {config!r}")
    run = typed(RunArgs, table, where, "")
    config = typed(algorithm_config(algo), config, where, "config.", algo)
    run = {**run, **({"env": env} if env else {}), **({"preset": preset} if preset else {})}
    try:
        name, chosen = choose_preset(algo, run.get("env", RunArgs.env), run.get("preset", "auto"))
        run_args = RunArgs(**{**run, "preset": name}).check()
        cfg = dataclasses.replace(chosen.config, **config)
        cfg = cfg.validate() if hasattr(cfg, "validate") else cfg
    except UsageError as error:
        raise UsageError(f"{where}: {error}") from None
    return RunFile(algo, run_args, cfg, chosen)


def typed(cls: type, values: dict[str, Any], where: str, prefix: str, algo: str = "") -> dict[str, Any]:
    """``values`` as the fields of dataclass ``cls`` (arrays as tuples, "none" as None, integers as
    floats where a float is asked), each checked against the field's annotation; one line naming the
    first unknown key or wrong type."""
    hints = typing.get_type_hints(cls)
    out = {}
    for key, value in values.items():
        if key not in hints:
            raise UsageError(f"{where}: unknown key {prefix}{key}{_belongs(key, algo, cls, prefix)}")
        out[key] = _typed(value, hints[key], f"{where}: {prefix}{key}")
    return out


def _belongs(key: str, algo: str, cls: type, prefix: str) -> str:
    """Where an unknown key would belong: another algorithm's config, the run's keys, or a list."""
    names = [f.name for f in dataclasses.fields(cls)]
    others = [a for a in ALGORITHMS if a != algo and key in typing.get_type_hints(algorithm_config(a))]
    if algo and others:
        return f" (a setting of {', '.join(others)}, not of {algo}'s {cls.__name__})"
    if algo and key in {f.name for f in dataclasses.fields(RunArgs)}:
        return f" ({key} is a run setting: put it above [config])"
    return f"; the {'[config] ' if prefix else ''}keys are {', '.join(names)}"


def _typed(value: Any, hint: Any, key: str) -> Any:
    """``value`` checked against the annotation ``hint`` (int, float, bool, str, tuple[X, ...], X | None)."""
    args = typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in args:
        inner = next(a for a in args if a is not type(None))
        return None if value == "none" and inner is not str else _typed(value, inner, key)
    if typing.get_origin(hint) is dict:
        if not isinstance(value, dict) or not all(isinstance(v, str) for v in value.values()):
            raise UsageError(f'{key} must be a table of strings ({{grid = "flat"}}), got {_shown(value)}')
        return dict(value)
    if typing.get_origin(hint) is tuple:
        if not isinstance(value, list):
            raise UsageError(f"{key} must be an array of {_kind(args[0])}, got {_shown(value)}")
        return tuple(_typed(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
    fits = {
        bool: isinstance(value, bool),
        int: isinstance(value, int) and not isinstance(value, bool),
        float: isinstance(value, int | float) and not isinstance(value, bool),
        str: isinstance(value, str),
    }
    if not fits.get(hint, False):
        raise UsageError(f"{key} must be {_kind(hint)}, got {_shown(value)}")
    return float(value) if hint is float else value


def _kind(hint: Any) -> str:
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(hint, str(hint))


def _shown(value: Any) -> str:
    """A TOML value as the file wrote it, and its kind: ``"fast" (str)``."""
    try:
        written = "a table" if isinstance(value, dict) else _value(value)
    except TypeError:  # a TOML date or time
        written = str(value)
    return f"{written} ({type(value).__name__})"


__all__ = ["RunArgs", "RunFile", "choose_preset", "dumps", "load", "read", "write"]
