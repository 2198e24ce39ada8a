"""Every thread of the process on one CPU for the length of a block: for measurements.

Benchmarks time agentax and its references on one core (``with pinned_to_one_cpu(): ...``), so that
a second core, or another process on it, does not blur the comparison; tests/test_compiled.py
checks the masks. It is no cure for the XLA CPU hang once jax's CPU client exists: that cure is
``agentax._xla.create_cpu_client_on_one_cpu``, whose helpers (which CPU, which threads, the
``AGENTAX_PIN_CPU`` setting) this module shares.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from agentax._xla import choose_cpu, pin_wanted, set_affinity, thread_ids

UNPINNED_CPUS: set[int] = set()
"""While :func:`pinned_to_one_cpu` is in force, the CPUs the process could use before it (else
empty): for Python threads started inside the block that run no XLA code, to leave the pinned CPU to
the others."""

_pin_lock = threading.Lock()
_pinned_cpu: int | None = None
_pin_depth = 0


@contextmanager
def pinned_to_one_cpu() -> Iterator[int | None]:
    """Run the block with every thread of the process pinned to one allowed CPU; yield that CPU.

    On entry every existing thread (the main one, XLA's thread pools, any other) is pinned to one
    CPU, so threads created inside the block inherit it; on exit each thread that existed before
    gets its own mask back, and each one created inside the block the mask the process had.
    The CPU is a pytest-xdist worker's by its number, else the one this thread last ran on.
    A nested use (from any thread) changes nothing and yields the CPU already pinned.
    Yields None where pinning is off or impossible (``AGENTAX_PIN_CPU=0``; an accelerator
    backend expected, unless ``AGENTAX_PIN_CPU=1``; no ``sched_setaffinity`` or ``/proc``).
    Where the process may use one CPU only, nothing changes and it yields that CPU.
    """
    global _pinned_cpu, _pin_depth
    saved: dict[int, set[int]] = {}
    allowed: set[int] = set()
    with _pin_lock:
        outer = _pin_depth == 0
        if outer:
            _pinned_cpu, saved, allowed = _pin_all_threads()
        _pin_depth += 1
        cpu = _pinned_cpu
    try:
        yield cpu
    finally:
        with _pin_lock:
            _pin_depth -= 1
            if outer:
                if saved:
                    _restore(saved, allowed)
                UNPINNED_CPUS.clear()
                _pinned_cpu = None


def _pin_all_threads() -> tuple[int | None, dict[int, set[int]], set[int]]:
    """Pin every thread to one CPU: (the CPU, each thread's previous mask, the process's mask)."""
    if not pin_wanted():
        return None, {}, set()
    allowed = os.sched_getaffinity(0)
    if len(allowed) == 1:
        return next(iter(allowed)), {}, allowed
    cpu = choose_cpu(sorted(allowed))
    saved: dict[int, set[int]] = {}
    new = thread_ids()
    while new:  # again until no thread appears that an unpinned one started meanwhile
        for tid in new:
            try:
                saved[tid] = os.sched_getaffinity(tid)
            except OSError:
                saved[tid] = set()  # ended meanwhile; nothing to restore
                continue
            set_affinity(tid, {cpu})
        new = [tid for tid in thread_ids() if tid not in saved]
    UNPINNED_CPUS.update(allowed)
    return cpu, saved, allowed


def _restore(saved: dict[int, set[int]], allowed: set[int]) -> None:
    for tid in thread_ids():
        mask = saved.get(tid) or allowed
        set_affinity(tid, mask)
