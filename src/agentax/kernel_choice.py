"""Which convolution backend (:data:`agentax.kernels.BACKENDS`) a run uses, chosen once by the entry
point before anything is traced (:func:`backend_for`) and handed down to the networks.

``AGENTAX_CONV``, read here and only here:

- ``xla``, ``onednn``, ``onednn-bf16``: that backend (see :mod:`agentax.kernels`);
- ``auto`` (the default): the fastest of the candidates this machine can run, measured once per
  machine (:func:`choice`): ``xla``; ``onednn`` where the library loads on an x86-64 CPU;
  ``onednn-bf16`` where oneDNN also has a bfloat16 implementation (not its reference one) of every
  convolution and product. The measure is a Nature-CNN DQN update of batch 32 (target network
  forward, online forward and backward, an SGD step; :func:`dqn_update`): the candidates compiled
  in a fresh process (never in this one), timed there in interleaved rounds, the fastest round of
  each kept; ~10-15 s. The choice is kept in ``~/.cache/agentax/kernels.json``
  (``$AGENTAX_KERNELS_CACHE``; ``none``: kept nowhere), keyed by the CPU's name and flags, the
  library's size and time, jax's version, oneDNN's threads, the CPUs and the measured shape;
  ``agentax kernels`` shows it, ``--measure`` measures again. ``AGENTAX_KERNELS_MEASURE=0`` (the
  test suite's) never measures: the kept choice, else the CPU flags' (bfloat16 where the CPU has
  ``amx_bf16`` or ``avx512_bf16``). Stored programs are named without measuring
  (:func:`known_backend`), and a run without convolutions measures nothing (:func:`backend_for`).
  Without the library, on a CPU other than x86-64, or with jax on an accelerator: ``xla``, unmeasured.

One CPU flag was the rule before, and it chose the slower path on the next CPU (an AMD EPYC with
AVX-512 BF16 and no AMX); the timings are on docs/benchmarks.md.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from agentax import _xla, kernels
from agentax.errors import UsageError
from agentax.kernels import (
    BACKENDS,
    LIBRARY,
    PRECISIONS,
    available,
    check,
    conv2d,
    dense,
    implementation,
    learning_loop,
    matmul,
    unavailable_reason,
)

try:
    import fcntl
except ImportError:  # not on Windows: measuring processes there do not wait for each other
    fcntl = None

MODES = ("auto", *BACKENDS)


def mode() -> str:
    """``AGENTAX_CONV`` as given (default ``auto``); an unknown value is a ``UsageError`` naming the
    choices (the CLI's one line, read by the entry point before anything is traced)."""
    value = os.environ.get("AGENTAX_CONV", "auto").strip().lower() or "auto"
    if value not in MODES:
        raise UsageError(f"AGENTAX_CONV={value!r} is not one of {', '.join(MODES)}")
    return value


CHOICE_BATCH = 32
"""The batch of the update :func:`choice` times: DQN's minibatch (its Atari presets')."""
MEASURE_TIMEOUT_S = 180.0
"""How long the measuring process may take (~10 s on a quiet 2-core CPU) before ``auto`` gives up
and takes :func:`flag_rule`'s choice."""
BF16_FLAGS = ("amx_bf16", "avx512_bf16")
"""The CPU flags of bfloat16 arithmetic that oneDNN uses (AMX's tiles, AVX-512's dot products)."""


@functools.cache
def cpu_info() -> tuple[str, frozenset[str]]:
    """This CPU's model name and flags (Linux's /proc/cpuinfo; elsewhere ``platform``'s name, no flags)."""
    name, flags = "", frozenset()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            field, _, value = line.partition(":")
            if field.strip() == "model name" and not name:
                name = value.strip()
            elif field.strip() == "flags" and not flags:
                flags = frozenset(value.split())
    except OSError:
        pass
    return name or platform.processor() or platform.machine() or "unknown", flags


@functools.cache
def bf16_runs() -> bool:
    """Whether oneDNN has a bfloat16 implementation, other than its slow reference one, of each of
    the Nature CNN's convolutions (forward and both gradients) and of its dense product."""
    found = [
        implementation(kind, (CHOICE_BATCH, side, side, c), (k, o, s), bf16=True)
        for kind in ("fwd", "bwd_data", "bwd_w")
        for c, o, k, s, side in NATURE
    ]
    found.append(implementation("matmul", (CHOICE_BATCH, 3136), (512,), bf16=True))
    return all(name not in ("none", "unavailable") and not name.startswith("ref") for name in found)


def candidates() -> tuple[list[str], dict[str, str]]:
    """The backends ``auto`` may choose from here, and why each other one is left out."""
    machine = platform.machine().lower()
    if machine not in ("x86_64", "amd64"):
        why = f"not an x86-64 CPU ({machine or 'unknown'})"
        return ["xla"], {"onednn": why, "onednn-bf16": why}
    if not available():
        return ["xla"], {"onednn": unavailable_reason(), "onednn-bf16": unavailable_reason()}
    if not bf16_runs():
        return ["xla", "onednn"], {"onednn-bf16": "oneDNN has no bfloat16 implementation on this CPU"}
    return ["xla", "onednn", "onednn-bf16"], {}


def flag_rule(runnable: list[str], flags: frozenset[str]) -> str:
    """The choice without a measurement: bfloat16 where the CPU has bfloat16 arithmetic, oneDNN
    float32 on another x86-64 CPU, else XLA's."""
    if "onednn-bf16" in runnable and flags & set(BF16_FLAGS):
        return "onednn-bf16"
    return "onednn" if "onednn" in runnable else "xla"


def fastest(timings: dict[str, float]) -> str:
    """The backend with the fewest ms per update (``timings``: backend → ms)."""
    return min(timings, key=timings.__getitem__)


def cache_path() -> Path | None:
    """Where ``auto``'s choices are kept (``$AGENTAX_KERNELS_CACHE``, else
    ``~/.cache/agentax/kernels.json`` beside jax's compiled programs; ``none``: nowhere)."""
    setting = os.environ.get("AGENTAX_KERNELS_CACHE", "")
    if setting.lower() == "none":
        return None
    return Path(setting) if setting else Path.home() / ".cache" / "agentax" / "kernels.json"


def choice_fields(
    cpu: tuple[str, frozenset[str]], batch: int = CHOICE_BATCH, shape: str | None = None
) -> dict[str, str]:
    """What a measured choice depends on: the CPU's name and flags, the kernel library (its size and
    time, so a rebuild measures again), jax, oneDNN's threads, the CPUs and the measured ``shape``
    (default: the convolution backends' update of ``batch``)."""
    import jaxlib

    name, flags = cpu
    library = Path(os.environ.get("AGENTAX_ONEDNN_LIB", LIBRARY))
    try:
        stat = library.stat()
        built = f"{library} {stat.st_size} bytes, mtime {stat.st_mtime_ns}"
    except OSError:
        built = f"{library} missing"
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {
        "cpu": name,
        "flags": hashlib.sha256(" ".join(sorted(flags)).encode()).hexdigest()[:16],
        "library": built,
        "jax": f"{jax.__version__} (jaxlib {jaxlib.__version__})",
        "threads": os.environ.get("AGENTAX_CONV_THREADS", "1"),
        "cpus": str(cpus),
        "shape": shape or f"Nature-CNN DQN update, batch {batch}",
    }


def choice_key(fields: dict[str, str]) -> str:
    """The cache's key of a choice: its :func:`choice_fields`, hashed."""
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:24]


def read_choices(path: Path | None) -> dict[str, dict]:
    """The kept choices (key → entry); a missing, unreadable or malformed file is none (JSON only:
    reading it runs no code)."""
    if path is None:
        return {}
    try:
        kept = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    choices = kept.get("choices") if isinstance(kept, dict) else None
    return {k: v for k, v in choices.items() if isinstance(v, dict)} if isinstance(choices, dict) else {}


def write_choices(path: Path | None, choices: dict[str, dict], keep: int = 32) -> None:
    """Keep ``choices`` (the newest ``keep``) in ``path``: written beside it, then renamed over it,
    so a reader never sees half a file. A read-only cache keeps nothing (the next process measures)."""
    if path is None:
        return
    newest = dict(sorted(choices.items(), key=lambda kv: str(kv[1].get("measured", "")))[-keep:])
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary.write_text(json.dumps({"format": 1, "choices": newest}, indent=1, sort_keys=True))
        os.replace(temporary, path)
    except OSError:
        temporary.unlink(missing_ok=True)


def _kept(entry: dict | None, runnable: list[str]) -> dict | None:
    """A kept entry if it is whole, chose a backend that may still run here and timed (or tried) every
    candidate runnable now, else None."""
    if entry is None or entry.get("backend") not in runnable or not isinstance(entry.get("ms"), dict):
        return None
    known = entry.get("candidates") or [*entry["ms"], *entry.get("errors", {})]
    if not set(runnable) <= set(known):
        return None  # a candidate new since it was measured
    if not all(isinstance(ms, (int, float)) for ms in entry["ms"].values()):
        return None
    return entry


@contextlib.contextmanager
def _locked(path: Path | None) -> Iterator[None]:
    """While inside, no other process measures into ``path`` (two test workers starting together
    measure once, not twice against each other)."""
    if path is None or fcntl is None:
        yield
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = open(path.with_name(f".{path.name}.lock"), "a")  # noqa: SIM115 (held while inside)
    except OSError:
        yield
        return
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def measure(
    runnable: list[str],
    batch: int = CHOICE_BATCH,
    printer: str = "print_update_times",
    cpu_only: bool = True,
    shape: tuple[int, ...] = (),
) -> tuple[dict[str, float], dict[str, str]]:
    """ms per Nature-CNN DQN update of ``batch`` for each backend of ``runnable``, timed in a fresh
    process (:func:`time_updates`), and why any could not be timed. Not in this one: it may be
    tracing a program now (jax would stage the measurement into it), and the measurement's programs
    stay out of its memory; a process that hangs or fails gives no timings. ``printer``: the
    function of this module the process runs (another choice's timings, :func:`print_precision_times`,
    handed ``shape`` after the batch), on jax's CPU backend where ``cpu_only``."""
    source = str(Path(__file__).resolve().parents[1])  # this agentax, whatever sys.path holds
    env = {
        **os.environ,
        **({"JAX_PLATFORMS": "cpu"} if cpu_only else {}),
        "PYTHONPATH": os.pathsep.join([source, *filter(None, [os.environ.get("PYTHONPATH")])]),
    }
    script = f"import sys; from agentax import kernel_choice; kernel_choice.{printer}(sys.argv[1:])"
    command = [sys.executable, "-c", script, str(batch), *map(str, shape), *runnable]
    try:
        done = subprocess.run(
            command,
            env=env,
            capture_output=True,
            text=True,
            timeout=MEASURE_TIMEOUT_S,
            stdin=subprocess.DEVNULL,
        )
    except subprocess.TimeoutExpired:
        return {}, {name: f"no result in {MEASURE_TIMEOUT_S:.0f} s" for name in runnable}
    try:
        result = json.loads(done.stdout.strip().splitlines()[-1])
        return result["ms"], result["errors"]
    except (IndexError, ValueError, KeyError, TypeError):
        why = (done.stderr.strip().splitlines() or [f"exit code {done.returncode}"])[-1]
        return {}, {name: f"the measuring process failed: {why}" for name in runnable}


def print_update_times(argv: list[str]) -> None:
    """The measuring process of :func:`measure`: ``argv`` is the batch then the backends; prints
    ``{"ms": {backend: ms}, "errors": {backend: why}}`` as its last line."""
    ms, errors = time_updates(argv[1:], int(argv[0]))
    print(json.dumps({"ms": ms, "errors": errors}))


def time_updates(
    backends: list[str], batch: int = CHOICE_BATCH, rounds: int = 8, loop: int = 3
) -> tuple[dict[str, float], dict[str, str]]:
    """ms per DQN update (:func:`dqn_update`) of ``batch`` with each backend: each compiled on it,
    then ``rounds`` rounds of ``loop`` calls of each in turn (so that another process's load falls
    on all alike), the fastest round kept; and why any failed."""
    rng = np.random.default_rng(0)
    obs, next_obs = (jnp.asarray(rng.integers(0, 256, (batch, 4, 84, 84), dtype=np.uint8)) for _ in range(2))
    action = jnp.asarray(rng.integers(0, 4, batch), jnp.int32)
    params = nature_q_params(jax.random.key(0))
    updates, errors = {}, {}
    for name in backends:
        try:
            update = jax.jit(dqn_update(name))
            jax.block_until_ready(update(params, params, obs, next_obs, action))
            updates[name] = update
        except Exception as error:  # a kernel that fails here is no candidate
            errors[name] = f"{type(error).__name__}: {error}"[:300]

    def step(update, state):
        return update(state, params, obs, next_obs, action)

    best = _interleaved(updates, step, params, rounds, loop)
    return {name: round(ms, 2) for name, ms in best.items()}, errors


NATURE = ((4, 32, 8, 4, 84), (32, 64, 4, 2, 20), (64, 64, 3, 1, 9))
"""The Nature CNN's convolutions: (in channels, out channels, size, stride, input side)."""


def nature_q_params(key: jax.Array, num_actions: int = 4) -> list[tuple[jax.Array, jax.Array]]:
    """(weights, bias) of the Nature CNN's layers and a Q head, scaled by fan-in."""
    shapes = [(k, k, c, o) for c, o, k, _, _ in NATURE] + [(3136, 512), (512, num_actions)]
    keys = jax.random.split(key, len(shapes))
    return [
        (jax.random.normal(k, s) / np.sqrt(np.prod(s[:-1])), jnp.zeros(s[-1]))
        for k, s in zip(keys, shapes, strict=True)
    ]


def nature_q_values(params: list, frames: jax.Array, backend: str = "xla") -> jax.Array:
    """Q-values ``[N, num_actions]`` of uint8 frames ``[N, 4, 84, 84]`` through the kernels'
    convolutions and dense product on ``backend`` (the Nature CNN of ``agentax.nets``, without flax)."""
    x = jnp.transpose(frames.astype(jnp.float32) / 255.0, (0, 2, 3, 1))
    for (w, b), (*_, stride, _) in zip(params[:3], NATURE, strict=True):
        x = jax.nn.relu(conv2d(x, w, (stride, stride), backend) + b)
    w, b = params[3]
    x = jax.nn.relu(dense(x.reshape(x.shape[0], -1), w, backend) + b)
    w, b = params[4]
    return x @ w + b


def dqn_update(backend: str = "xla") -> Callable:
    """A DQN learner update on ``backend`` ``(params, target_params, obs, next_obs, action) -> params``: the
    target network's forward pass, the online forward and backward, an SGD step (a learner's
    shapes and kernels; the reward is 1 at every step)."""

    def update(params, target_params, obs, next_obs, action):
        def loss(params):
            q = nature_q_values(params, obs, backend)[jnp.arange(obs.shape[0]), action]
            target = 1.0 + 0.99 * jnp.max(nature_q_values(target_params, next_obs, backend), axis=-1)
            return jnp.mean((q - lax.stop_gradient(target)) ** 2)

        return jax.tree.map(lambda p, g: p - 1e-4 * g, params, jax.grad(loss)(params))

    return update


@dataclass(frozen=True)
class Question:
    """What an ``auto`` choice measures and how it falls back: the convolution backend's
    (:data:`CONV`) or the networks' precision (:data:`PRECISION`), one cache and one mechanism."""

    shape: str
    """what is timed (in the cache's key: another shape is measured apart)"""
    batch: int
    """the batch the timer is handed"""
    timer: Callable[[list[str], int], tuple[dict[str, float], dict[str, str]]]
    """``timer(runnable, batch) -> (ms, errors)``, in a fresh process"""
    unmeasured: Callable[[list[str], frozenset[str]], str]
    """the choice where nothing is kept and nothing may be (or could be) measured"""
    unmeasured_why: str
    """why, in words"""
    on_accelerator: str | None = "xla"
    """the choice where jax runs on an accelerator, unmeasured (None: measured there too)"""


CONV = Question(
    f"Nature-CNN DQN update, batch {CHOICE_BATCH}",
    CHOICE_BATCH,
    lambda runnable, batch: measure(runnable, batch),
    flag_rule,
    "not measured (AGENTAX_KERNELS_MEASURE=0): the CPU flags' choice",
)
"""The convolution backend's question (:func:`choice`)."""


def resolve(
    runnable: list[str],
    excluded: dict[str, str],
    *,
    timer: Callable | None = None,
    path: Path | None = None,
    cpu: tuple[str, frozenset[str]] | None = None,
    again: bool = False,
    measuring: bool = True,
    question: Question = CONV,
) -> dict[str, Any]:
    """``auto``'s choice among ``runnable``: the kept one for this machine (:func:`choice_fields`),
    else the fastest that ``timer(runnable, batch) -> (ms, errors)`` (default the ``question``'s,
    :func:`measure`) finds, kept in ``path`` for the next process (``again``: measured afresh).
    Where nothing could be timed, the question's ``unmeasured`` choice (:func:`flag_rule`'s for the
    backend); without ``measuring``, where nothing is kept, the same, kept nowhere (``source``:
    ``unmeasured``). The choice is under ``backend`` whatever the question."""
    name, flags = cpu or cpu_info()
    about = {"mode": "auto", "cpu": name, "candidates": runnable, "excluded": excluded}
    about["cache"] = None if path is None else str(path)
    if question.on_accelerator is not None and _xla._accelerator_expected():
        why = f"jax runs on an accelerator: {question.on_accelerator}, unmeasured"
        return {**about, "backend": question.on_accelerator, "why": why, "ms": {}}
    if len(runnable) == 1:
        why = next(iter(excluded.values()), "no other candidate")
        return {**about, "backend": runnable[0], "why": f"the only candidate ({why})", "ms": {}}
    fields = choice_fields((name, flags), question.batch, question.shape)
    key = choice_key(fields)
    with _locked(path):
        choices = read_choices(path)
        entry = None if again else _kept(choices.get(key), runnable)
        source = "kept"
        if entry is None and not measuring:
            return {
                **about,
                "backend": question.unmeasured(runnable, flags),
                "why": question.unmeasured_why,
                "ms": {},
                "source": "unmeasured",
            }
        if entry is None:
            ms, errors = (timer or question.timer)(runnable, question.batch)
            entry = {
                "fields": fields,
                "candidates": runnable,
                "ms": ms,
                "errors": errors,
                "measured": time.strftime("%Y-%m-%d %H:%M:%S"),
            }
            if ms:
                entry["backend"] = fastest(ms)
                entry["why"] = f"the fastest of {len(ms)} measured"
            else:
                entry["backend"] = question.unmeasured(runnable, flags)
                entry["why"] = (
                    f"nothing could be timed: {question.unmeasured_why.split(': ', 1)[-1]} "
                    "(`agentax kernels --measure` tries again)"
                )
            write_choices(path, {**choices, key: entry})
            source = "measured"
    return {**about, **entry, "source": source}


_resolved: dict[tuple, dict[str, Any]] = {}
"""``auto``'s choice, once per process, per set of candidates (and why not the others) and cache file."""


def _memo_key(runnable: list[str], excluded: dict[str, str], path: Path | None) -> tuple:
    return tuple(runnable), tuple(excluded.items()), str(path)


def measuring() -> bool:
    """Whether ``auto`` may measure (``AGENTAX_KERNELS_MEASURE``, default 1; the test suite sets 0:
    then a kept choice serves, else the CPU flags')."""
    return os.environ.get("AGENTAX_KERNELS_MEASURE", "1").strip().lower() not in ("0", "false", "no", "off")


def choice(again: bool = False) -> dict[str, Any]:
    """What :func:`backend` uses and why (a dict for a run's config and ``agentax kernels``):
    ``mode`` (``AGENTAX_CONV``), ``backend``, ``why``, ``cpu``, ``candidates``, ``excluded``
    (backend → why not), and with ``auto`` the measured ``ms`` per backend, ``cache`` (the file)
    and ``source`` (``kept``, ``measured`` or ``unmeasured``). Measures once per machine
    (:func:`resolve`), in another process; ``again``: afresh."""
    chosen = mode()
    if chosen != "auto":
        return {"mode": chosen, "backend": backend(), "why": f"AGENTAX_CONV={chosen}", "cpu": cpu_info()[0]}
    runnable, excluded = candidates()
    path = cache_path()
    memo = _memo_key(runnable, excluded, path)
    if again or memo not in _resolved:
        _resolved[memo] = resolve(runnable, excluded, path=path, again=again, measuring=again or measuring())
    return _resolved[memo]


def known_backend() -> str:
    """:func:`backend` where it is known without measuring (a mode other than ``auto``, or ``auto``'s
    choice made, kept or not to be measured), else ``"auto, unmeasured"``. It names the stored
    programs (``agentax.runners.programs``): a program without convolutions costs no measurement."""
    if mode() != "auto":
        return backend()
    runnable, excluded = candidates()
    path = cache_path()
    about = _resolved.get(_memo_key(runnable, excluded, path))
    if about is None:
        about = resolve(runnable, excluded, path=path, measuring=False)
        if about.get("source") == "unmeasured" and measuring():
            return "auto, unmeasured"
    return about["backend"]


def backend() -> str:
    """The backend ``AGENTAX_CONV`` asks for here: ``xla``, ``onednn`` or ``onednn-bf16`` (with
    ``auto``, :func:`choice`'s, which may measure); a backend that cannot run is a ``UsageError``."""
    chosen = mode()
    if chosen == "auto":
        return choice()["backend"]
    if chosen != "xla" and not available():
        raise UsageError(
            f"AGENTAX_CONV={chosen} but the oneDNN kernel is unavailable: {unavailable_reason()}"
        )
    return check(chosen)


def backend_for(obs_shape: Sequence[int]) -> str:
    """The entry point's choice for an agent on observations of ``obs_shape``, made once before any
    program is traced: :func:`backend` for stacked frames ``[C, H, W]`` (the Nature CNN's input),
    ``xla`` for every other shape (no convolution to choose for, so nothing is measured)."""
    return backend() if len(obs_shape) == 3 else "xla"


def learning_loop_for(obs_shape: Sequence[int]) -> Callable:
    """:func:`agentax.kernels.learning_loop` for the backend :func:`backend_for` chose (the entry
    point's choice, kept for the process: nothing is measured again)."""
    return learning_loop(obs_shape, backend_for(obs_shape))


# The networks' precision: the same mechanism, another question.

PRECISION_BATCH = 256
"""The batch of the learning step :func:`precision_choice` times (SAC's and TD3's minibatch)."""
PRECISION_MODES = ("auto", *PRECISIONS)


def precision_question(width: int) -> Question:
    """The precision's question for networks of hidden ``width``: which of :data:`PRECISIONS` takes
    fewer ms per MLP learning step (:func:`time_precisions`); ``f32`` unmeasured (never a CPU flag's
    guess), measured on an accelerator too."""
    return Question(
        f"MLP learning step, batch {PRECISION_BATCH}, 2 hidden layers of {width}",
        PRECISION_BATCH,
        lambda runnable, batch: measure(runnable, batch, "print_precision_times", False, (width,)),
        lambda runnable, flags: "f32",
        "not measured (AGENTAX_KERNELS_MEASURE=0): f32, the float32 products",
        on_accelerator=None,
    )


def print_precision_times(argv: list[str]) -> None:
    """The measuring process of :func:`precision_question`: ``argv`` is the batch, the width, then
    the precisions; prints ``{"ms": {precision: ms}, "errors": {precision: why}}`` as its last line."""
    ms, errors = time_precisions(argv[2:], int(argv[0]), int(argv[1]))
    print(json.dumps({"ms": ms, "errors": errors}))


def mlp_update(precision: str) -> Callable:
    """An MLP learning step in ``precision`` ``(params, x [B, in], y [B, out]) -> params``: forward,
    backward of the squared error, an SGD step (a critic's products; :func:`agentax.kernels.matmul`)."""

    def forward(params, x):
        for w, b in params[:-1]:
            x = jax.nn.relu(matmul(x, w, precision) + b)
        w, b = params[-1]
        return matmul(x, w, precision) + b

    def update(params, x, y):
        grads = jax.grad(lambda p: jnp.mean((forward(p, x) - y) ** 2))(params)
        return jax.tree.map(lambda p, g: p - 1e-4 * g, params, grads)

    return update


def time_precisions(
    precisions: list[str], batch: int, width: int, rounds: int = 8, loop: int = 10
) -> tuple[dict[str, float], dict[str, str]]:
    """ms per MLP learning step (:func:`mlp_update`; 32 inputs, two hidden layers of ``width``, 8
    outputs) of ``batch`` in each precision, interleaved in ``rounds`` rounds of ``loop`` calls,
    the fastest round of each kept; and why any failed."""
    sizes = (32, width, width, 8)
    keys = jax.random.split(jax.random.key(0), len(sizes))
    params = [
        (jax.random.normal(k, (a, b)) / np.sqrt(a), jnp.zeros(b))
        for k, a, b in zip(keys, sizes[:-1], sizes[1:], strict=False)
    ]
    x, y = jax.random.normal(keys[-1], (batch, sizes[0])), jnp.zeros((batch, sizes[-1]))
    updates, errors = {}, {}
    for name in precisions:
        try:
            update = jax.jit(mlp_update(name))
            jax.block_until_ready(update(params, x, y))
            updates[name] = update
        except Exception as error:  # a precision that fails here is no candidate
            errors[name] = f"{type(error).__name__}: {error}"[:300]
    return _interleaved(updates, lambda update, state: update(state, x, y), params, rounds, loop), errors


def _interleaved(calls: dict[str, Callable], step: Callable, state: Any, rounds: int, loop: int) -> dict:
    """ms per ``step(call, state) -> state`` of each of ``calls``: ``rounds`` rounds of ``loop`` steps
    of each in turn (another process's load falls on all alike), the fastest round kept."""
    best = dict.fromkeys(calls, float("inf"))
    for _ in range(rounds):
        for name, call in calls.items():
            current = state
            start = time.perf_counter()
            for _ in range(loop):
                current = step(call, current)
            jax.block_until_ready(current)
            best[name] = min(best[name], (time.perf_counter() - start) / loop * 1e3)
    return {name: round(ms, 3) for name, ms in best.items()}


def precision_choice(requested: str, width: int = 256, again: bool = False) -> dict[str, Any]:
    """The networks' precision for ``--precision requested`` and why (a dict for the run's config):
    ``f32`` or ``bf16`` as asked; ``auto``: the faster here of a learning step of networks of hidden
    ``width`` (:func:`precision_question`), measured once per machine and width in another process,
    kept with the convolution backend's choices (:func:`resolve`); ``precision`` holds the choice."""
    if requested not in PRECISION_MODES:
        raise UsageError(f"--precision must be one of {', '.join(PRECISION_MODES)}, got {requested!r}")
    if requested != "auto":
        return {"mode": requested, "precision": requested, "why": f"--precision {requested}"}
    runnable, path = list(PRECISIONS), cache_path()
    excluded = {}
    if not kernels.available():
        runnable.remove("bf16-onednn")
        excluded["bf16-onednn"] = f"the oneDNN kernel is unavailable: {kernels.unavailable_reason()}"
    memo = ("precision", width, str(path))
    if again or memo not in _resolved:
        question = precision_question(width)
        measure_now = again or measuring()
        about = resolve(runnable, excluded, path=path, again=again, measuring=measure_now, question=question)
        _resolved[memo] = {**about, "precision": about["backend"]}
    return _resolved[memo]
