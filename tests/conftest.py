"""Shared test setup. Every test runs under pytest-timeout (pyproject.toml): an XLA hang fails fast."""

import os
import signal
import sys
from pathlib import Path

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
os.environ.setdefault("MPLBACKEND", "Agg")

REPO_ROOT = str(Path(__file__).resolve().parents[1])
if REPO_ROOT not in sys.path:
    sys.path.append(REPO_ROOT)  # for benchmarks/_pin.py (``from benchmarks import _pin``)


def ignore_sigint() -> None:
    """A ``preexec_fn``: the child starts with SIGINT ignored, as a shell without job control starts
    ``cmd &`` (``nohup agentax train ... &`` in a script)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
