"""Process-wide XLA set-up: the CPU hang cure and the persistent compilation cache.

**The hang** (DESIGN.md, "Known hazards"): on a 2-core machine, XLA's CPU backend (jaxlib 0.10.2)
was seen to stop for good — 0 % CPU, waiting in ``BlockUntilReady`` — on the first or second call
of a jitted PPO train program vmapped over seeds (11 of 12 processes). XLA flags that limit its
thread pools did not help; pinning the process to one CPU before jax started did (8 of 8 calls
completed at the same throughput; later the compiled runner's 8-seed PPO program: 7 of 7
unpinned processes hung, 7 of 7 pinned ones finished).

What matters is the CPU count XLA sees **when jax creates its CPU client**: it sizes its thread
pool by it (one ``tf_XLAEigen`` thread instead of two here), and the hang came only with two.
Pinning the threads later does not help: with the client already made, every thread of the
process pinned to one CPU, the same program hung in 6 of 6 processes. Leaving the threads free
afterwards does not hurt: a client made on one CPU, every thread then given both CPUs back, ran
it to the end in 10 of 10 processes (39 calls each), faster (13-17 s against 23 s). Hence
:func:`create_cpu_client_on_one_cpu`, which ``agentax/__init__.py`` calls first thing: the client
is made on one CPU whenever jax makes it, and no thread stays pinned, so actors, learners and env
threads may use every core. (XLA's intra-op pool keeps one thread, as under the process-wide
pin.)

The cure patches a private API, so it says when it cannot: a ``RuntimeWarning`` where jax's
backend registry is not there (a jax upgrade), and another where :func:`let_xla_use_every_cpu`
comes after the one-CPU client exists. The other order has no cure: a process whose client a host
runner made for every CPU (:func:`let_xla_use_every_cpu`) and that then trains on the compiled runner
can hang there (seen in one test process: EnvPool's compiled Hopper, then a compiled PPO); the test
suite makes its client on one CPU first. (``benchmarks/_pin.py``'s ``pinned_to_one_cpu``, which pins
every thread for the length of a block, is measurement machinery built on the helpers here.)

The one CPU is chosen so that two trainings or two test workers do not share one core: a
pytest-xdist worker's by its number, else the CPU the calling thread last ran on (the kernel picks
an idle one; choosing by pid put two trainings on one core while the other idled).
``AGENTAX_PIN_CPU=0`` turns pinning off, ``AGENTAX_PIN_CPU=1`` forces it even where an accelerator
plugin is installed (where it is off by default, since the hang is a CPU-backend one).

**The compilation cache**: :func:`enable_compilation_cache` keeps compiled programs on disk
(``~/.cache/agentax/jax``, or ``$AGENTAX_JAX_CACHE``; ``none`` disables it), with the size and
compile-time thresholds lowered so that CPU programs, which compile in seconds, are cached too:
a repeated ``agentax train`` skips compilation.
"""

from __future__ import annotations

import importlib.util
import os
import re
import warnings
from pathlib import Path

_ACCELERATOR_PLUGINS = ("jax_cuda12_plugin", "jax_cuda13_plugin", "jax_rocm60_plugin", "libtpu")


def _accelerator_expected() -> bool:
    platforms = os.environ.get("JAX_PLATFORMS", "").lower()
    if platforms:
        return platforms.split(",")[0] not in ("cpu", "")
    return any(importlib.util.find_spec(name) is not None for name in _ACCELERATOR_PLUGINS)


def pin_wanted() -> bool:
    """Whether to pin: not with ``AGENTAX_PIN_CPU=0``, nor (unless ``=1``) where an accelerator is
    expected, nor without ``sched_setaffinity`` and ``/proc``."""
    setting = os.environ.get("AGENTAX_PIN_CPU", "auto").lower()
    if setting in ("0", "false", "no", "off"):
        return False
    if setting == "auto" and _accelerator_expected():
        return False
    return hasattr(os, "sched_setaffinity") and os.path.isdir("/proc/self/task")


def choose_cpu(allowed: list[int]) -> int:
    """A pytest-xdist worker's CPU by its number, else the CPU the calling thread last ran on
    (the kernel picks an idle one; choosing by pid put two trainings on one core while the other
    idled), so that two trainings or two test workers do not share one core."""
    worker = re.fullmatch(r"gw(\d+)", os.environ.get("PYTEST_XDIST_WORKER", ""))
    current = _current_cpu()
    if worker or current not in allowed:
        return allowed[(int(worker.group(1)) if worker else os.getpid()) % len(allowed)]
    return current


def thread_ids() -> list[int]:
    """The ids of this process's threads, from ``/proc/self/task``."""
    return [int(tid) for tid in os.listdir("/proc/self/task")]


def set_affinity(tid: int, cpus: set[int]) -> None:
    """Give thread ``tid`` the CPUs ``cpus``, if it still runs."""
    try:
        os.sched_setaffinity(tid, cpus)
    except OSError:  # the thread ended meanwhile (ProcessLookupError is an OSError)
        pass


_one_cpu_client = True
"""Read when jax creates its CPU client: on one CPU (the hang's cure), unless a runner that steps
envs on the host asked for every CPU first (:func:`let_xla_use_every_cpu`)."""

_client_made_on_one_cpu = False
"""Whether jax's CPU client exists and was made on one CPU (by the wrapped factory)."""


def let_xla_use_every_cpu(warn: bool = True) -> bool:
    """Have jax create its CPU client for every CPU, if it has not created it yet; returns whether it
    takes effect. With one CPU at creation XLA runs one program at a time, so a parallel runner's
    actors would wait behind the learner's update (measured: parallel no faster than sequential). The
    host and parallel runners ask for it; the hang was seen only with the compiled runner's
    vmapped-over-seeds program, which keeps the one-CPU client.

    Too late once the client exists: then, if it was made on one CPU, a ``RuntimeWarning`` says so
    (something in this process called jax first: a notebook that evaluated a policy, a compiled run),
    unless ``warn`` is False."""
    global _one_cpu_client
    from jax._src import xla_bridge

    if "cpu" in getattr(xla_bridge, "_backends", {}):
        if warn and _client_made_on_one_cpu:
            warnings.warn(
                "jax's CPU client already exists, made on one CPU (agentax's cure for the XLA CPU hang), "
                "so XLA runs one program at a time: actors wait behind the learner and the parallel "
                "runner will run no faster than sequential. Train before anything else in this process "
                "calls jax, or set AGENTAX_PIN_CPU=0.",
                RuntimeWarning,
                stacklevel=2,
            )
        return False
    _one_cpu_client = False
    return True


def create_cpu_client_on_one_cpu() -> bool:
    """Have jax create its CPU client, whenever it does, on one CPU: the cure for the XLA CPU hang.

    Wraps jax's CPU backend factory (before anything creates the client): the thread that creates
    the client is pinned to one CPU while it does, so XLA sizes its thread pool for one CPU; then
    that thread, and the threads the client started, get the process's mask back, so every
    thread (the runner's, actors, a learner) may run on all CPUs. Returns whether the factory is
    wrapped: not where pinning is off (:func:`pin_wanted`), nor once the CPU client exists (too
    late), nor where jax's private backend registry is not there, which a ``RuntimeWarning`` says:
    the hang may then come back.
    """
    if not pin_wanted():
        return False
    try:
        from jax._src import xla_bridge
    except ImportError:
        xla_bridge = None
    registration = getattr(xla_bridge, "_backend_factories", {}).get("cpu")
    backends = getattr(xla_bridge, "_backends", None)
    if registration is None or not hasattr(registration, "factory") or not isinstance(backends, dict):
        warnings.warn(
            "agentax cannot make jax's CPU client on one CPU: jax's private backend registry "
            "(jax._src.xla_bridge._backend_factories['cpu'], _backends) is not there in this jax version. "
            "The XLA CPU hang of programs vmapped over seeds may return (see agentax/_xla.py); set "
            "AGENTAX_PIN_CPU=0 to silence this warning.",
            RuntimeWarning,
            stacklevel=2,
        )
        return False
    if "cpu" in backends:
        return False
    original = registration.factory
    if getattr(original, "agentax_one_cpu", False):
        return True

    def factory():
        global _client_made_on_one_cpu
        allowed = os.sched_getaffinity(0)
        if len(allowed) == 1 or not _one_cpu_client:
            return original()
        before = set(thread_ids())
        os.sched_setaffinity(0, {choose_cpu(sorted(allowed))})  # the calling thread only
        try:
            client = original()
            _client_made_on_one_cpu = True
            return client
        finally:
            os.sched_setaffinity(0, allowed)
            for tid in set(thread_ids()) - before:  # the client's threads inherited the one CPU
                set_affinity(tid, allowed)

    factory.agentax_one_cpu = True  # type: ignore[attr-defined]
    registration.factory = factory
    return True


def _current_cpu() -> int | None:
    """The CPU the calling thread last ran on (``/proc/thread-self/stat``'s 39th field), or None."""
    try:
        with open("/proc/thread-self/stat") as f:
            return int(f.read().rsplit(")", 1)[1].split()[36])
    except (OSError, IndexError, ValueError):
        return None


L2_FALLBACK = 1 << 20
"""A core's L2 cache where the OS does not say (1 MiB, the smallest of the x86 cores agentax meets)."""


def l2_cache_bytes() -> int:
    """The L2 cache of one core of this machine, from ``/sys`` (``L2_FALLBACK`` where it says nothing)."""
    units = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}
    for index in sorted(Path("/sys/devices/system/cpu/cpu0/cache").glob("index*")):
        try:
            if (index / "level").read_text().strip() == "2":
                size = (index / "size").read_text().strip()
                return int(size.rstrip("KMG")) * units.get(size[-1], 1)
        except (OSError, ValueError):
            break
    return L2_FALLBACK


def compilation_cache_dir() -> Path | None:
    """Where compiled programs are kept (``$AGENTAX_JAX_CACHE`` or ``~/.cache/agentax/jax``)."""
    setting = os.environ.get("AGENTAX_JAX_CACHE", "")
    if setting.lower() == "none":
        return None
    return Path(setting) if setting else Path.home() / ".cache" / "agentax" / "jax"


def enable_compilation_cache() -> Path | None:
    """Turn on jax's persistent compilation cache for every program, however small or quick.

    Where the folder cannot be made (a read-only home, say) training goes on without it.
    """
    import jax

    path = compilation_cache_dir()
    if path is None:
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    return path


def scan(f, init, xs=None, length: int | None = None, *, python_loop: bool = False):
    """``jax.lax.scan(f, init, xs)``, or, with ``python_loop``, the same steps written out one after
    the other in the traced program (same results; a longer compile).

    XLA's CPU backend runs convolutions many times slower inside a loop body, and a fully unrolled
    ``lax.scan`` (``unroll=True``) is no cure: a Nature-CNN DQN learning step took 338 ms inside a
    one-step scan with ``unroll=True`` and 33 ms outside any (jaxlib 0.10.2, 2 cores). The learning
    loops of CNN agents on XLA's convolutions therefore use ``python_loop=True``
    (:func:`agentax.kernels.learning_loop`)."""
    import jax
    import jax.numpy as jnp

    if not python_loop:
        return jax.lax.scan(f, init, xs, length)
    length = jax.tree.leaves(xs)[0].shape[0] if length is None else length
    outputs = []
    for i in range(length):
        init, output = f(init, None if xs is None else jax.tree.map(lambda x, i=i: x[i], xs))
        outputs.append(output)
    return init, jax.tree.map(lambda *ys: jnp.stack(ys), *outputs)
