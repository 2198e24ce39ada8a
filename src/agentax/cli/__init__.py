"""The ``agentax`` command: ``agentax COMMAND [ARGS]``.

Each command lives in its own module under ``agentax.cli`` and exposes ``main(argv) -> int | None``
built with tyro from typed arguments; this dispatcher imports only the command asked for, so
start-up stays fast. The errors of :mod:`agentax.errors` become one line on stderr and an exit code:

- :class:`~agentax.errors.UsageError` (bad input): ``agentax CMD: error: MESSAGE``, exit code 2;
- :class:`~agentax.errors.TrainingDiverged` (a NaN or infinite loss): the same line, exit code 3;
- :class:`~agentax.errors.StorageFull` (the disk filled while writing): the same line, naming the
  bytes needed and the last complete checkpoint, exit code 4;
- :class:`~agentax.errors.NodeLost` (a Ray node lost, the run cannot go on): the same line and
  ``continue with: agentax train --resume RUN_DIR``, exit code 5;
- :class:`~agentax.errors.TrainingInterrupted` (Ctrl-C in a training): ``agentax CMD: interrupted;
  continue with: agentax train --resume RUN_DIR``, exit code 130 (128 + SIGINT, as a shell reports it);
  any other ``KeyboardInterrupt``: ``agentax CMD: interrupted``, exit code 130.
- SIGTERM (what ``kill`` and schedulers send) is handled as Ctrl-C is — the run stops at its next
  safe point and says how to continue — and exits with 143 (128 + SIGTERM).
"""

from __future__ import annotations

import contextlib
import importlib
import shlex
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

from agentax.errors import NodeLost, StorageFull, TrainingDiverged, TrainingInterrupted, UsageError

COMMANDS: dict[str, str] = {
    "envs": "list the environments with their observation and action spaces",
    "kernels": "the convolution kernels AGENTAX_CONV=auto measured and chose on this machine, and why",
    "evaluate": "evaluate a policy (basic, random, or a trained run) over N episodes",
    "play": "play one episode and write it as a GIF or MP4",
    "export": "write a trained run's policy as an ONNX or StableHLO file, with a model card beside it",
    "demo": "the main job: train an agent on CartPole and show the result",
    "train": "train an agent (reinforce, ppo, dqn) into a run folder; --config FILE trains a run file",
    "plot": "overlay the learning curves of run folders into one PNG",
    "presets": "list the tuned presets; ALGO NAME writes one as a run file for agentax train --config",
    "report": "compare runs across seeds: IQM, mean, median with 95 % bootstrap intervals",
    "search": "policy search: (p, r) of the vacuum robot by grid/random search; GA or CEM on CartPole",
    "sweep": "hyperparameter settings × seeds in one compiled program, reported with IQM and intervals",
    "solve": "solve a tabular MDP: value / Q-value iteration, TD, Q-learning, SARSA (--plot compares)",
}


def version() -> str:
    """The installed distribution's version (importlib.metadata), else the package's ``__version__``."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed_version

    try:
        return installed_version("agentax")
    except PackageNotFoundError:  # run from a source tree that was never installed
        from agentax import __version__

        return __version__


def usage() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: agentax [--version] COMMAND [ARGS] (agentax COMMAND --help for its arguments)", ""]
    lines += ["commands:"]
    lines += [f"  {name:<{width}}  {summary}" for name, summary in COMMANDS.items()]
    return "\n".join(lines)


EXIT_CODES: dict[type, int] = {UsageError: 2, TrainingDiverged: 3, StorageFull: 4, NodeLost: 5}
"""The exit code of each error a user can cause and fix (see the module docstring)."""


def resume_hint(run_dir: str | None) -> str:
    """``; continue with: agentax train --resume RUN_DIR``, or nothing without a run folder."""
    if run_dir is None:
        return ""
    return f"; continue with: agentax train --resume {shlex.quote(str(run_dir))}"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    if argv[0] in ("-V", "--version"):
        print(f"agentax {version()}")
        return 0
    name, args = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"agentax: error: unknown command {name!r}; choose from {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    command = importlib.import_module(f"agentax.cli.{name}")
    with terminate_as_interrupt() as signals:
        code = _run(name, command, args, signals)
    return 128 + signal.SIGTERM if signals and code == 130 else code


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[list[int]]:
    """While inside, SIGTERM acts as Ctrl-C does, so a run stops at its safe point (each runner
    already ends cleanly on it: a checkpoint, its threads and actors joined); the list holds the
    signals seen. It calls the SIGINT handler in force, or raises ``KeyboardInterrupt`` where SIGINT
    is ignored: a job started with ``&`` by a script (``nohup agentax train ... &``) inherits an
    ignored SIGINT, and a raised SIGINT would then be lost."""
    seen: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield seen
        return

    def forward(signum, frame):
        seen.append(signum)
        handler = signal.getsignal(signal.SIGINT)
        if not callable(handler):
            raise KeyboardInterrupt
        handler(signal.SIGINT, frame)

    previous = signal.signal(signal.SIGTERM, forward)
    try:
        yield seen
    finally:
        signal.signal(signal.SIGTERM, previous)


def _run(name: str, command: Any, args: list[str], signals: list[int]) -> int:
    """``command.main(args)``, its errors as one line and an exit code (see the module docstring)."""
    try:
        return command.main(args) or 0
    except tuple(EXIT_CODES) as error:
        print(
            f"agentax {name}: error: {error}{resume_hint(getattr(error, 'run_dir', None))}", file=sys.stderr
        )
        return next(code for kind, code in EXIT_CODES.items() if isinstance(error, kind))
    except TrainingInterrupted as interrupt:  # a KeyboardInterrupt, so caught before that one
        stopped = "terminated" if signals else "interrupted"
        print(f"agentax {name}: {stopped}{resume_hint(interrupt.run_dir)}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print(f"agentax {name}: {'terminated' if signals else 'interrupted'}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
