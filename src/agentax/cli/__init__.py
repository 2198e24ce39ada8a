"""The ``agentax`` command: ``agentax COMMAND [ARGS]``.

Each command lives in its own module under ``agentax.cli`` and exposes ``main(argv) -> int | None``
built with tyro from typed arguments; this dispatcher imports only the command asked for, so
start-up stays fast. The errors of :mod:`agentax.errors` become one line on stderr and an exit code:

- :class:`~agentax.errors.UsageError` (bad input): ``agentax CMD: error: MESSAGE``, exit code 2;
- :class:`~agentax.errors.TrainingDiverged` (a NaN or infinite loss): the same line, exit code 3;
- :class:`~agentax.errors.NodeLost` (a Ray node lost, the run cannot go on): the same line and
  ``continue with: agentax train --resume RUN_DIR``, exit code 4;
- :class:`~agentax.errors.TrainingInterrupted` (Ctrl-C in a training): ``agentax CMD: interrupted;
  continue with: agentax train --resume RUN_DIR``, exit code 130 (128 + SIGINT, as a shell reports it);
  any other ``KeyboardInterrupt``: ``agentax CMD: interrupted``, exit code 130.
"""

from __future__ import annotations

import importlib
import shlex
import sys

from agentax.errors import NodeLost, TrainingDiverged, TrainingInterrupted, UsageError

COMMANDS: dict[str, str] = {
    "envs": "list the environments with their observation and action spaces",
    "evaluate": "evaluate a policy (basic, random, or a trained run) over N episodes",
    "play": "play one episode and write it as a GIF or MP4",
    "demo": "the main job: train an agent on CartPole and show the result",
    "train": "train an agent (reinforce, ppo, dqn) into a run folder; --resume DIR continues one",
    "plot": "overlay the learning curves of run folders into one PNG",
    "report": "compare runs across seeds: IQM, mean, median with 95 % bootstrap intervals",
    "search": "policy search: (p, r) of the vacuum robot by grid/random search; GA or CEM on CartPole",
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
    try:
        return command.main(args) or 0
    except UsageError as error:
        print(f"agentax {name}: error: {error}", file=sys.stderr)
        return 2
    except TrainingDiverged as error:
        print(f"agentax {name}: error: {error}", file=sys.stderr)
        return 3
    except NodeLost as error:
        print(f"agentax {name}: error: {error}{resume_hint(error.run_dir)}", file=sys.stderr)
        return 4
    except TrainingInterrupted as interrupt:  # a KeyboardInterrupt, so caught before that one
        print(f"agentax {name}: interrupted{resume_hint(interrupt.run_dir)}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print(f"agentax {name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
