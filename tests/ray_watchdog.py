"""No test Ray outlives its test process, even one killed by a timeout (SIGKILL runs no teardown).

Every Ray the tests start (the 2-node fixture cluster, ``ray start``, the CLI's own) runs with a
``RAY_TMPDIR`` under one prefix of the test process; :func:`start` launches this file as a process of
its own session that waits for the test process to end, then kills every process whose ``RAY_TMPDIR``
starts with the prefix (:func:`sweep`), so that a killed ``make test`` leaves no cluster behind for the
next run to trip over. ``python tests/ray_watchdog.py PID PREFIX``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import psutil


def of_prefix(prefix: str) -> list[psutil.Process]:
    """Live processes (not this one) started with a ``RAY_TMPDIR`` under ``prefix``, with their children."""
    found: dict[int, psutil.Process] = {}
    for process in psutil.process_iter(["pid"]):
        try:
            if process.pid != os.getpid() and process.environ().get("RAY_TMPDIR", "").startswith(prefix):
                found[process.pid] = process
                found.update({child.pid: child for child in process.children(recursive=True)})
        except psutil.Error:
            continue
    found.pop(os.getpid(), None)
    return list(found.values())


def sweep(prefix: str) -> int:
    """Kill every process of the Rays under ``prefix``; how many there were."""
    processes = of_prefix(prefix)
    for process in processes:
        try:
            process.kill()
        except psutil.Error:
            continue
    return len(processes)


def start(prefix: str, pid: int | None = None) -> subprocess.Popen:
    """The watchdog of the Rays of process ``pid`` (default this one), ``RAY_TMPDIR`` left out of its
    own environment."""
    env = {key: value for key, value in os.environ.items() if key != "RAY_TMPDIR"}
    watched = str(pid or os.getpid())
    return subprocess.Popen([sys.executable, __file__, watched, prefix], env=env, start_new_session=True)


def alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def watch(pid: int, prefix: str, poll: float = 0.5) -> None:
    """Wait for ``pid`` to end, then sweep ``prefix``."""
    while alive(pid):
        time.sleep(poll)
    sweep(prefix)


if __name__ == "__main__":
    watch(int(sys.argv[1]), sys.argv[2])
