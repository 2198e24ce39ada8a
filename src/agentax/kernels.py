"""oneDNN on the CPU: the Nature CNN's convolutions, its dense layer and their gradients as XLA FFI calls.

XLA's CPU convolutions are what bound the Atari learners (a Nature-CNN DQN update of batch 32 took
29 ms here, torch's oneDNN 18.5 ms in f32 and 11.5 ms in bf16 on AMX). :func:`conv2d` calls oneDNN
(``csrc/onednn_conv.cc``, compiled by ``make`` into ``_onednn_conv.so`` beside this file) for the
forward convolution, the input gradient and the weight gradient, and :func:`dense` for the 3136 → 512
layer's product and both of its gradients (AMX's bfloat16 tiles where XLA's f32 product ran on
AVX-512); on any other platform, and where the library is missing, they are
``lax.conv_general_dilated`` and ``jnp.matmul`` exactly.

``AGENTAX_CONV`` chooses, read when a program is traced:

- ``xla``: XLA's convolutions and products everywhere (the golden numbers were made with them);
- ``onednn``: oneDNN in float32 (fails loudly where the library could not be loaded);
- ``onednn-bf16``: oneDNN computing in bfloat16 (AMX on Sapphire Rapids, AVX-512 BF16 on Zen 4);
  inputs, weights and gradients stay float32 outside, rounded to bfloat16 inside, accumulated in
  float32;
- ``auto`` (the default): the fastest of the candidates this machine can run, measured once per
  machine (:func:`choice`): ``xla``; ``onednn`` where the library loads on an x86-64 CPU;
  ``onednn-bf16`` where oneDNN also has a bfloat16 implementation (not its reference one) of every
  convolution and product. The measure is a Nature-CNN DQN update of batch 32 (target network
  forward, online forward and backward, an SGD step): the candidates compiled in a fresh process
  (never in this one, which may be tracing), timed there in interleaved rounds, the fastest round
  of each kept; ~10-15 s. The choice is kept in ``~/.cache/agentax/kernels.json``
  (``$AGENTAX_KERNELS_CACHE``; ``none``: kept nowhere), keyed by the CPU's name and flags, the
  library's size and time, jax's version, oneDNN's threads, the CPUs and the measured shape;
  ``agentax kernels`` shows it, ``--measure`` measures again. ``AGENTAX_KERNELS_MEASURE=0`` (the
  test suite's) never measures: the kept choice, else the CPU flags' (bfloat16 where the CPU has
  ``amx_bf16`` or ``avx512_bf16``). Stored programs are named without measuring
  (:func:`known_backend`), so a run without convolutions measures nothing. Without the library, on
  a CPU other than x86-64, or with jax on an accelerator: ``xla``, unmeasured.

  One CPU flag was the rule before, and it chose the slower path on the next CPU: on an AMD EPYC
  (Zen 4, AVX-512 BF16, no AMX) oneDNN bfloat16 took 19.0 ms per update against 28.6 in float32 and
  29.5 with XLA's (issue 29's ``benchmarks/run.py learner``). On that CPU (``lscpu``: "AMD EPYC",
  2 cores, shared with other jobs, 2026-12-04) ``auto`` timed XLA 34.1 ms, oneDNN f32 25.1 and bf16
  17.0 and chose bf16, the fastest of the same learner run on both clients (bf16 22.6 / 19.9 ms,
  f32 29.7 / 28.1, XLA 40.5 / 37.0 on every CPU / one CPU); ``agentax kernels`` took 10.5 s to
  measure. bfloat16 learns: PQN's
  ``breakout-hour`` preset with it scored 52.1 ± 9.8 on Breakout in 26 minutes on AMX, and each
  convolution and gradient stays within 2 % of float32's (``tests/test_kernels.py``, on the CPU at
  hand).

``AGENTAX_CONV_THREADS`` sets oneDNN's OpenMP threads (default 1; ``OMP_WAIT_POLICY`` defaults to
``PASSIVE``, so that idle OpenMP threads sleep instead of spinning on a core that XLA or an env
thread needs). One thread, because two gained nothing here and could stall: with one core busy
elsewhere, a DQN update took 30.4 ms with two threads against 28.7 with one in float32, and 276 ms
against 19 in bfloat16, nearly all of it in the AMX weight gradient of the third convolution
(oneDNN 3.2, 2026-12-02). The compiled Atari runner's other work (EnvPool's threads, XLA's
elementwise ops) has the other core.

Under ``jax.vmap`` (seeds vmapped by the compiled runner) the FFI calls get the batch as leading
dimensions (``vmap_method="expand_dims"``): with shared weights it folds into the convolution's
batch, with one set of weights per seed the kernel runs one convolution per seed.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from agentax import _xla
from agentax.errors import UsageError

try:
    import fcntl
except ImportError:  # not on Windows: measuring processes there do not wait for each other
    fcntl = None

LIBRARY = Path(__file__).with_name("_onednn_conv.so")
"""Where ``make`` puts the compiled kernel (``AGENTAX_ONEDNN_LIB`` names another)."""
TARGETS = ("agentax_conv_fwd", "agentax_conv_bwd_data", "agentax_conv_bwd_w", "agentax_matmul")
MODES = ("auto", "xla", "onednn", "onednn-bf16")
NHWC = ("NHWC", "HWIO", "NHWC")


def mode() -> str:
    """``AGENTAX_CONV`` as given (default ``auto``); an unknown value is a ``UsageError`` naming the
    choices (the CLI's one line, not a traceback from inside the program being traced)."""
    value = os.environ.get("AGENTAX_CONV", "auto").strip().lower() or "auto"
    if value not in MODES:
        raise UsageError(f"AGENTAX_CONV={value!r} is not one of {', '.join(MODES)}")
    return value


@functools.cache
def _load() -> tuple[ctypes.CDLL | None, str]:
    """The kernel library with its FFI targets registered for the CPU, or None and why not."""
    path = Path(os.environ.get("AGENTAX_ONEDNN_LIB", LIBRARY))
    if not path.is_file():
        return None, f"{path} is missing (make builds it from csrc/onednn_conv.cc)"
    # OpenMP threads that sleep between convolutions rather than spin: spinning ones take the core
    # from XLA's own thread and the env threads (read when libgomp starts, so set before loading).
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    try:
        library = ctypes.CDLL(str(path))
    except OSError as error:
        return None, f"{path} does not load: {error}"
    for name in TARGETS:
        jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(getattr(library, name)), platform="cpu")
    threads = os.environ.get("AGENTAX_CONV_THREADS", "1")
    if not threads.isdigit() or int(threads) < 1:
        raise UsageError(f"AGENTAX_CONV_THREADS={threads!r}: give a whole number of threads, at least 1")
    library.agentax_conv_set_threads(ctypes.c_int(int(threads)))
    return library, ""


def available() -> bool:
    """Whether the oneDNN kernel loaded (see :func:`unavailable_reason` when not)."""
    return _load()[0] is not None


def unavailable_reason() -> str:
    """Why the oneDNN kernel is not available ("" when it is)."""
    return _load()[1]


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


def choice_fields(cpu: tuple[str, frozenset[str]], batch: int = CHOICE_BATCH) -> dict[str, str]:
    """What a measured choice depends on: the CPU's name and flags, the kernel library (its size and
    time, so a rebuild measures again), jax, oneDNN's threads, the CPUs and the measured shape."""
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
        "shape": f"Nature-CNN DQN update, batch {batch}",
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
    """A kept entry if it is whole and chose a backend that may still run here, else None."""
    if entry is None or entry.get("backend") not in runnable or not isinstance(entry.get("ms"), dict):
        return None
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


def measure(runnable: list[str], batch: int = CHOICE_BATCH) -> tuple[dict[str, float], dict[str, str]]:
    """ms per Nature-CNN DQN update of ``batch`` for each backend of ``runnable``, timed in a fresh
    process (:func:`time_updates`), and why any could not be timed. Not in this one: it may be
    tracing a program now (jax would stage the measurement into it), and the measurement's programs
    stay out of its memory; a process that hangs or fails gives no timings."""
    source = str(Path(__file__).resolve().parents[1])  # this agentax, whatever sys.path holds
    env = {
        **os.environ,
        "JAX_PLATFORMS": "cpu",
        "PYTHONPATH": os.pathsep.join([source, *filter(None, [os.environ.get("PYTHONPATH")])]),
    }
    script = "import sys; from agentax import kernels; kernels.print_update_times(sys.argv[1:])"
    command = [sys.executable, "-c", script, str(batch), *runnable]
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
    """ms per DQN update (:func:`dqn_update`) of ``batch`` with each backend: each compiled under its
    ``AGENTAX_CONV``, then ``rounds`` rounds of ``loop`` calls of each in turn (so that another
    process's load falls on all alike), the fastest round kept; and why any failed."""
    rng = np.random.default_rng(0)
    obs, next_obs = (jnp.asarray(rng.integers(0, 256, (batch, 4, 84, 84), dtype=np.uint8)) for _ in range(2))
    action = jnp.asarray(rng.integers(0, 4, batch), jnp.int32)
    params = nature_q_params(jax.random.key(0))
    updates, errors = {}, {}
    previous = os.environ.get("AGENTAX_CONV")
    for name in backends:
        os.environ["AGENTAX_CONV"] = name
        try:
            update = jax.jit(dqn_update())  # a new function: traced under this backend
            jax.block_until_ready(update(params, params, obs, next_obs, action))
            updates[name] = update
        except Exception as error:  # a kernel that fails here is no candidate
            errors[name] = f"{type(error).__name__}: {error}"[:300]
    if previous is None:
        os.environ.pop("AGENTAX_CONV", None)
    else:
        os.environ["AGENTAX_CONV"] = previous
    best = dict.fromkeys(updates, float("inf"))
    for _ in range(rounds):
        for name, update in updates.items():
            state = params
            start = time.perf_counter()
            for _ in range(loop):
                state = update(state, params, obs, next_obs, action)
            jax.block_until_ready(state)
            best[name] = min(best[name], (time.perf_counter() - start) / loop * 1e3)
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


def nature_q_values(params: list, frames: jax.Array) -> jax.Array:
    """Q-values ``[N, num_actions]`` of uint8 frames ``[N, 4, 84, 84]`` through this module's
    convolutions and dense product (the Nature CNN of ``agentax.nets``, without flax)."""
    x = jnp.transpose(frames.astype(jnp.float32) / 255.0, (0, 2, 3, 1))
    for (w, b), (*_, stride, _) in zip(params[:3], NATURE, strict=True):
        x = jax.nn.relu(conv2d(x, w, (stride, stride)) + b)
    w, b = params[3]
    x = jax.nn.relu(dense(x.reshape(x.shape[0], -1), w) + b)
    w, b = params[4]
    return x @ w + b


def dqn_update() -> Callable:
    """A new DQN learner update ``(params, target_params, obs, next_obs, action) -> params``: the
    target network's forward pass, the online forward and backward, an SGD step (a learner's
    shapes and kernels; the reward is 1 at every step)."""

    def update(params, target_params, obs, next_obs, action):
        def loss(params):
            q = nature_q_values(params, obs)[jnp.arange(obs.shape[0]), action]
            target = 1.0 + 0.99 * jnp.max(nature_q_values(target_params, next_obs), axis=-1)
            return jnp.mean((q - lax.stop_gradient(target)) ** 2)

        return jax.tree.map(lambda p, g: p - 1e-4 * g, params, jax.grad(loss)(params))

    return update


def resolve(
    runnable: list[str],
    excluded: dict[str, str],
    *,
    timer: Callable | None = None,
    path: Path | None = None,
    cpu: tuple[str, frozenset[str]] | None = None,
    again: bool = False,
    measuring: bool = True,
) -> dict[str, Any]:
    """``auto``'s choice among ``runnable``: the kept one for this machine (:func:`choice_fields`),
    else the fastest that ``timer(runnable, batch) -> (ms, errors)`` (default :func:`measure`)
    finds, kept in ``path`` for the next process (``again``: measured afresh). Where nothing could
    be timed, :func:`flag_rule`'s; without ``measuring``, where nothing is kept, :func:`flag_rule`'s
    too, kept nowhere (``source``: ``unmeasured``)."""
    name, flags = cpu or cpu_info()
    about = {"mode": "auto", "cpu": name, "candidates": runnable, "excluded": excluded}
    about["cache"] = None if path is None else str(path)
    if _xla._accelerator_expected():
        return {**about, "backend": "xla", "why": "jax runs on an accelerator: XLA's convolutions", "ms": {}}
    if runnable == ["xla"]:
        why = next(iter(excluded.values()), "no other candidate")
        return {**about, "backend": "xla", "why": f"the only candidate ({why})", "ms": {}}
    fields = choice_fields((name, flags))
    key = choice_key(fields)
    with _locked(path):
        choices = read_choices(path)
        entry = None if again else _kept(choices.get(key), runnable)
        source = "kept"
        if entry is None and not measuring:
            why = "not measured (AGENTAX_KERNELS_MEASURE=0): the CPU flags' choice"
            return {
                **about,
                "backend": flag_rule(runnable, flags),
                "why": why,
                "ms": {},
                "source": "unmeasured",
            }
        if entry is None:
            ms, errors = (timer or measure)(runnable, CHOICE_BATCH)
            entry = {
                "fields": fields,
                "ms": ms,
                "errors": errors,
                "measured": time.strftime("%Y-%m-%d %H:%M:%S"),
            }
            if ms:
                entry["backend"] = fastest(ms)
                entry["why"] = f"the fastest of {len(ms)} measured"
            else:
                entry["backend"] = flag_rule(runnable, flags)
                entry["why"] = (
                    "nothing could be timed: the CPU flags' choice (`agentax kernels --measure` tries again)"
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
    """What :func:`conv2d` uses on the CPU now: ``xla``, ``onednn`` or ``onednn-bf16``
    (with ``auto``, :func:`choice`'s)."""
    chosen = mode()
    if chosen == "auto":
        return choice()["backend"]
    if chosen != "xla" and not available():
        raise UsageError(
            f"AGENTAX_CONV={chosen} but the oneDNN kernel is unavailable: {unavailable_reason()}"
        )
    return chosen


def implementation(kind: str, shape: tuple[int, ...], kernel: tuple[int, ...], bf16: bool) -> str:
    """oneDNN's name for the implementation it picks (``kind``: fwd, bwd_data, bwd_w) for input
    ``shape`` ``(N, H, W, C)`` and ``kernel`` ``(size, out_channels, stride)``, or (``kind`` matmul)
    for ``[M, K] @ [K, N]`` with ``shape`` ``(M, K)`` and ``kernel`` ``(N,)``: for the benchmark notes."""
    library = _load()[0]
    if library is None:
        return "unavailable"
    name = ctypes.create_string_buffer(128)
    if kind == "matmul":
        args = [ctypes.c_int64(v) for v in (*shape, *kernel)]
        found = library.agentax_matmul_impl(*args, ctypes.c_int(bf16), name, 128)
    else:
        size, out, stride = kernel
        args = [ctypes.c_int64(v) for v in (*shape[:3], shape[3], size, size, out, stride)]
        found = library.agentax_conv_impl(
            ctypes.c_int(("fwd", "bwd_data", "bwd_w").index(kind)), *args, ctypes.c_int(bf16), name, 128
        )
    return name.value.decode() if found else "none"


def xla_conv2d(x: jax.Array, w: jax.Array, stride: tuple[int, int]) -> jax.Array:
    """XLA's VALID convolution: ``x [N, H, W, C]``, ``w [KH, KW, C, O]`` → ``[N, OH, OW, O]``."""
    return lax.conv_general_dilated(x, w, stride, "VALID", dimension_numbers=NHWC)


def _call(target: str, out: jax.ShapeDtypeStruct, a: jax.Array, b: jax.Array, stride) -> jax.Array:
    call = jax.ffi.ffi_call(target, out, vmap_method="expand_dims")
    return call(a, b, stride_h=np.int64(stride[0]), stride_w=np.int64(stride[1]))


def _out_shape(x_shape, w_shape, stride) -> tuple[int, ...]:
    n, h, w, _ = x_shape
    kh, kw, _, o = w_shape
    return (n, (h - kh) // stride[0] + 1, (w - kw) // stride[1] + 1, o)


@functools.partial(jax.custom_vjp, nondiff_argnums=(2, 3))
def _onednn_conv2d(x: jax.Array, w: jax.Array, stride: tuple[int, int], bf16: bool) -> jax.Array:
    return _onednn_forward(x, w, stride, bf16)[0]


def _compute(x: jax.Array, bf16: bool) -> jax.Array:
    """``x`` in the type the kernel computes in (the weights are converted inside, once per call)."""
    return x.astype(jnp.bfloat16) if bf16 else x


def _onednn_forward(x, w, stride, bf16):
    out = jax.ShapeDtypeStruct(_out_shape(x.shape, w.shape, stride), x.dtype)
    return _call("agentax_conv_fwd", out, _compute(x, bf16), w, stride), (x, w)


def _onednn_backward(stride, bf16, residuals, dy):
    x, w = residuals
    dyc = _compute(dy, bf16)
    # In bf16 the input gradient comes back in bf16 (oneDNN 3.2 has no bf16 -> f32 variant of it).
    dx = _call("agentax_conv_bwd_data", jax.ShapeDtypeStruct(x.shape, dyc.dtype), dyc, w, stride)
    dw = _call("agentax_conv_bwd_w", jax.ShapeDtypeStruct(w.shape, w.dtype), _compute(x, bf16), dyc, stride)
    return dx.astype(x.dtype), dw


_onednn_conv2d.defvjp(_onednn_forward, _onednn_backward)


def conv2d(x: jax.Array, w: jax.Array, stride: tuple[int, int]) -> jax.Array:
    """A VALID convolution ``x [N, H, W, C]`` (float32), ``w [KH, KW, C, O]`` → ``[N, OH, OW, O]``:
    oneDNN on the CPU as :func:`backend` says, XLA's on every other platform; differentiable."""
    stride = tuple(int(s) for s in stride)
    return _on_the_cpu(
        lambda x, w, bf16: _onednn_conv2d(x, w, stride, bf16), lambda x, w: xla_conv2d(x, w, stride), x, w
    )


def _on_the_cpu(onednn: Callable, xla: Callable, a: jax.Array, b: jax.Array) -> jax.Array:
    """``onednn(a, b, bf16)`` on the CPU where :func:`backend` chooses oneDNN and both arrays are
    float32, ``xla(a, b)`` everywhere else (other platforms, ``xla``, other types)."""
    chosen = backend()
    if chosen == "xla" or a.dtype != jnp.float32 or b.dtype != jnp.float32:
        return xla(a, b)
    bf16 = chosen == "onednn-bf16"
    return lax.platform_dependent(a, b, cpu=lambda a, b: onednn(a, b, bf16), default=xla)


def _matmul(a: jax.Array, b: jax.Array, bf16: bool, transpose_a=False, transpose_b=False) -> jax.Array:
    """oneDNN's ``op(a) @ op(b)`` of float32 matrices (``op``: transposed where asked), computed in
    bfloat16 with ``bf16``."""
    m = a.shape[1] if transpose_a else a.shape[0]
    n = b.shape[0] if transpose_b else b.shape[1]
    call = jax.ffi.ffi_call(
        "agentax_matmul", jax.ShapeDtypeStruct((m, n), jnp.float32), vmap_method="expand_dims"
    )
    return call(
        a, b, transpose_a=np.int64(transpose_a), transpose_b=np.int64(transpose_b), bf16=np.int64(bf16)
    )


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _onednn_dense(x: jax.Array, w: jax.Array, bf16: bool) -> jax.Array:
    return _matmul(x, w, bf16)


def _onednn_dense_forward(x, w, bf16):
    return _matmul(x, w, bf16), (x, w)


def _onednn_dense_backward(bf16, residuals, dy):
    x, w = residuals
    return _matmul(dy, w, bf16, transpose_b=True), _matmul(x, dy, bf16, transpose_a=True)


_onednn_dense.defvjp(_onednn_dense_forward, _onednn_dense_backward)


def dense(x: jax.Array, w: jax.Array) -> jax.Array:
    """``x [..., K] @ w [K, N]`` → ``[..., N]`` (float32): oneDNN on the CPU as :func:`backend` says
    (bfloat16 inside with ``onednn-bf16``, accumulated in float32), XLA's product on every other
    platform; differentiable."""
    if w.ndim != 2:
        return jnp.matmul(x, w)

    def onednn(x, w, bf16):
        return _onednn_dense(x.reshape(-1, x.shape[-1]), w, bf16).reshape(*x.shape[:-1], w.shape[1])

    return _on_the_cpu(onednn, jnp.matmul, x, w)


def dot_general(lhs, rhs, dimension_numbers, precision=None, preferred_element_type=None):
    """``lax.dot_general``'s signature (flax ``nn.Dense(dot_general=...)``): a dense layer's product
    (``lhs [..., K]`` contracted with a ``[K, N]`` kernel, default precision) goes to :func:`dense`,
    every other one to ``lax.dot_general`` unchanged."""
    plain = (
        rhs.ndim == 2
        and dimension_numbers == (((lhs.ndim - 1,), (0,)), ((), ()))
        and precision is None
        and preferred_element_type is None
    )
    if plain:
        return dense(lhs, rhs)
    return lax.dot_general(lhs, rhs, dimension_numbers, precision, preferred_element_type)


def conv_general_dilated(
    lhs,
    rhs,
    window_strides,
    padding,
    lhs_dilation=None,
    rhs_dilation=None,
    dimension_numbers=None,
    feature_group_count=1,
    precision=None,
):
    """``lax.conv_general_dilated``'s signature (flax ``nn.Conv(conv_general_dilated=...)``): the
    convolutions :func:`conv2d` covers (2-d, VALID, NHWC/HWIO, no dilation or groups, default
    precision) go to it, every other one to ``lax.conv_general_dilated`` unchanged."""
    plain = (
        lhs.ndim == 4
        and padding in ("VALID", ((0, 0), (0, 0)), [(0, 0), (0, 0)])
        and all(d in (None, (1, 1), [1, 1]) for d in (lhs_dilation, rhs_dilation))
        and feature_group_count == 1
        and precision is None
        and dimension_numbers == lax.conv_dimension_numbers(lhs.shape, rhs.shape, NHWC)
    )
    if plain:
        return conv2d(lhs, rhs, window_strides)
    return lax.conv_general_dilated(
        lhs,
        rhs,
        window_strides,
        padding,
        lhs_dilation=lhs_dilation,
        rhs_dilation=rhs_dilation,
        dimension_numbers=dimension_numbers,
        feature_group_count=feature_group_count,
        precision=precision,
    )


def learning_loop(obs_shape: tuple[int, ...]) -> Callable:
    """The loop for an agent's learning steps on observations of ``obs_shape`` (``lax.scan``'s
    signature): the steps written out (:func:`agentax._xla.scan` with ``python_loop``) for stacked
    frames ``[C, H, W]`` whose convolutions are XLA's on its CPU backend, where a convolution inside
    a loop body runs many times slower (4 Nature-CNN gradient steps of batch 256 took 51 s in a
    ``lax.scan``); ``jax.lax.scan`` everywhere else, oneDNN's convolutions included (as fast in a
    scan as written out, and the program compiles in seconds, not minutes).

    Both are asked when the loop is traced, not here: asking for the platform creates jax's client,
    and the runner decides first how (:func:`agentax._xla.let_xla_use_every_cpu`)."""
    if len(obs_shape) != 3:
        return lax.scan

    def loop(f, init, xs=None, length=None):
        written_out = jax.default_backend() == "cpu" and backend() == "xla"
        return _xla.scan(f, init, xs, length, python_loop=written_out)

    return loop
