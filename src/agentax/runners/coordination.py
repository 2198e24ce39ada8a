"""What the parallel runner's threads share: a coordinator that stops them all, a parameter channel,
a rate limiter and queue calls; every wait looks every :data:`POLL_SECONDS` whether the run stops.
"""

from __future__ import annotations

import queue
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

POLL_SECONDS = 0.05  # how often a blocked thread looks whether the run has stopped


class Stopped(Exception):
    """Raised inside a thread's wait once the run is stopping."""


class Coordinator:
    """The run's stop flag and the first error of any thread."""

    def __init__(self):
        self.stop = threading.Event()
        self.error: BaseException | None = None

    def fail(self, error: BaseException) -> None:
        if self.error is None:
            self.error = error
        self.stop.set()

    def check(self) -> None:
        """Raise the first thread's error in the caller (the learner), or ``Stopped``."""
        if self.error is not None:
            raise self.error
        if self.stop.is_set():
            raise Stopped

    def wait_until(self, condition: threading.Condition, ready: Callable[[], bool]) -> float:
        """Wait on ``condition`` (held) until ``ready()``; returns the seconds waited."""
        start = time.perf_counter()
        self.check()  # also when never waiting: a busy learner still ends with the run
        while not ready():
            condition.wait(POLL_SECONDS)
            self.check()
        return time.perf_counter() - start


@contextmanager
def interrupted_at_a_safe_point(coordinator: Coordinator) -> Iterator[None]:
    """Ctrl-C ends the run where the learner next checks the coordinator (a Ray call interrupted
    inside left ``ray.shutdown`` hanging); a second Ctrl-C interrupts at once. Main thread only."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)

    def interrupt(signum, frame):
        signal.signal(signal.SIGINT, previous)
        coordinator.fail(KeyboardInterrupt())

    signal.signal(signal.SIGINT, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


class ParameterChannel:
    """Published agent states by version, the ``keep`` newest, as ``share(version, state)`` makes them
    for the actors (the state itself for threads, a reference into Ray's object store)."""

    def __init__(
        self, coordinator: Coordinator, version: int, state: Any, keep: int, share: Callable[[int, Any], Any]
    ):
        self.coordinator, self.keep, self.share = coordinator, keep, share
        self.versions = {version: share(version, state)}
        self.condition = threading.Condition()

    def publish(self, version: int, state: Any) -> None:
        shared = self.share(version, state)  # outside the lock: actors may read older versions meanwhile
        with self.condition:
            self.versions[version] = shared
            for old in [v for v in self.versions if v <= version - self.keep]:
                del self.versions[old]
            self.condition.notify_all()

    def get(self, version: int) -> tuple[Any, float]:
        """The state of ``version`` (waiting for it) and the seconds waited."""
        with self.condition:
            waited = self.coordinator.wait_until(self.condition, lambda: version in self.versions)
            return self.versions[version], waited

    def latest(self) -> tuple[int, Any]:
        with self.condition:
            version = max(self.versions)
            return version, self.versions[version]


class RateLimiter:
    """Keeps ``learned ≈ ratio × (inserted − min_inserts)`` (Reverb's SampleToInsertRatio): the learner
    starts a phase while ``learned ≤`` that, actors insert while less than ``slack`` steps ahead."""

    def __init__(self, coordinator: Coordinator, ratio: float, min_inserts: int, slack: int):
        self.coordinator, self.ratio, self.min_inserts, self.slack = coordinator, ratio, min_inserts, slack
        self.inserted = self.learned = 0
        self.closed = False  # no more inserts: the learner catches up and ends
        self.condition = threading.Condition()

    def learn_ready(self) -> bool:
        started = self.inserted >= max(self.min_inserts, 1)
        return started and self.learned <= self.ratio * (self.inserted - self.min_inserts)

    def insert_ready(self) -> bool:
        caught_up = self.min_inserts + self.learned / self.ratio
        return self.inserted < self.min_inserts or self.inserted < caught_up + self.slack

    def await_insert(self) -> float:
        with self.condition:
            return self.coordinator.wait_until(self.condition, self.insert_ready)

    def inserted_steps(self, count: int) -> None:
        with self.condition:
            self.inserted += count
            self.condition.notify_all()

    def await_learn(self) -> tuple[bool, float]:
        """Wait for a learning phase; ``(False, waited)`` once inserts are closed and it is caught up."""
        with self.condition:
            waited = self.coordinator.wait_until(self.condition, lambda: self.learn_ready() or self.closed)
            return self.learn_ready(), waited

    def learned_steps(self, count: int) -> None:
        with self.condition:
            self.learned += count
            self.condition.notify_all()


def put(items: queue.Queue, item: Any, coordinator: Coordinator) -> float:
    """Put into a bounded queue, giving up once the run stops; returns the seconds waited."""
    start = time.perf_counter()
    while True:
        coordinator.check()
        try:
            items.put(item, timeout=POLL_SECONDS)
            return time.perf_counter() - start
        except queue.Full:
            continue


def take(items: queue.Queue, coordinator: Coordinator) -> tuple[Any, float]:
    start = time.perf_counter()
    while True:
        coordinator.check()
        try:
            return items.get(timeout=POLL_SECONDS), time.perf_counter() - start
        except queue.Empty:
            continue
