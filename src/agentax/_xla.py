"""Process-wide XLA set-up: the CPU hang cure and the persistent compilation cache.

**The hang** (DESIGN.md, "Known hazards"): on a 2-core machine, XLA's CPU backend (jaxlib 0.10.2)
was seen to stop for good — 0 % CPU, waiting in ``BlockUntilReady`` — on the first or second call
of a jitted PPO train program vmapped over seeds (11 of 12 processes). XLA flags that limit its
thread pools did not help; pinning the process to one CPU did (8 of 8 calls completed at the
same throughput). Reproduced again with jaxlib 0.10.2: the compiled runner's 8-seed PPO
program hung in 7 of 7 unpinned processes (every XLA thread idle, the main thread in
``BlockUntilReady`` fetching a result), and finished in 7 of 7 pinned ones (6 of them 41 calls
each); small hand-written vmapped PPO chunks did not hang either way. :func:`pin_cpu` applies
the cure. It must run before jax creates its CPU client, because only threads created after
``sched_setaffinity`` inherit the mask (checked: all 14 threads of a process that ran a jitted,
vmapped program carry the one-CPU mask).
``agentax/__init__.py`` calls it first thing, so every program that imports agentax gets it.

Processes are spread over the allowed CPUs, so two trainings or two test workers do not share
one core: a pytest-xdist worker by its number, any other process on the CPU the kernel started it
on (it picks an idle one; choosing by pid put two trainings on one core while the other idled).
``AGENTAX_PIN_CPU=0`` turns the pin off, ``AGENTAX_PIN_CPU=1`` forces it even where an accelerator
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
from pathlib import Path

_ACCELERATOR_PLUGINS = ("jax_cuda12_plugin", "jax_cuda13_plugin", "jax_rocm60_plugin", "libtpu")


def _accelerator_expected() -> bool:
    platforms = os.environ.get("JAX_PLATFORMS", "").lower()
    if platforms:
        return platforms.split(",")[0] not in ("cpu", "")
    return any(importlib.util.find_spec(name) is not None for name in _ACCELERATOR_PLUGINS)


UNPINNED_CPUS: set[int] = set()
"""The CPUs this process could use before :func:`pin_cpu` (empty if it did not pin): for Python
threads that run no XLA code, such as :func:`agentax.runs.preload_plotting`."""


def pin_cpu() -> int | None:
    """Pin this process (and the threads it creates later) to one allowed CPU; return it.

    Returns None where pinning is off or impossible (``AGENTAX_PIN_CPU=0``, an accelerator
    backend, a platform without ``sched_setaffinity``, or a single allowed CPU already).
    """
    setting = os.environ.get("AGENTAX_PIN_CPU", "auto").lower()
    if setting in ("0", "false", "no", "off"):
        return None
    if setting == "auto" and _accelerator_expected():
        return None
    if not hasattr(os, "sched_setaffinity"):
        return None
    allowed = sorted(os.sched_getaffinity(0))
    UNPINNED_CPUS.update(allowed)
    if len(allowed) == 1:
        return allowed[0]
    worker = re.fullmatch(r"gw(\d+)", os.environ.get("PYTEST_XDIST_WORKER", ""))
    current = _current_cpu()
    if worker or current not in allowed:
        cpu = allowed[(int(worker.group(1)) if worker else os.getpid()) % len(allowed)]
    else:
        cpu = current
    os.sched_setaffinity(0, {cpu})
    return cpu


def _current_cpu() -> int | None:
    """The CPU this process last ran on (``/proc/self/stat``'s 39th field), None if unknown."""
    try:
        with open("/proc/self/stat") as f:
            return int(f.read().rsplit(")", 1)[1].split()[36])
    except (OSError, IndexError, ValueError):
        return None


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
