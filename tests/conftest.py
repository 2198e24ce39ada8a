"""Shared test setup. Every test runs under pytest-timeout (pyproject.toml): an XLA hang fails fast."""

import os
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("AGENTAX_KERNELS_MEASURE", "0")  # AGENTAX_CONV=auto times nothing in tests

REPO_ROOT = str(Path(__file__).resolve().parents[1])
if REPO_ROOT not in sys.path:
    sys.path.append(REPO_ROOT)  # for benchmarks/_pin.py (``from benchmarks import _pin``)


def kernel_not_built() -> str | None:
    """The summary line when the oneDNN kernel is not built (its tests skip), else None."""
    from agentax import kernels

    if kernels.available():
        return None
    return f"agentax: the oneDNN kernel is not built, its tests skipped: {kernels.unavailable_reason()}"


def pytest_terminal_summary(terminalreporter):
    """A run without the kernel says so at its end (make test, CI), not only in skip reasons."""
    line = kernel_not_built()
    if line:
        terminalreporter.write_line(line, yellow=True, bold=True)


def with_sigint_ignored(command: list[str]) -> list[str]:
    """``command`` started as a shell script starts ``cmd &`` (``nohup agentax train ... &``): with
    SIGINT ignored, which the program inherits (a shell's ``trap '' INT``, then ``exec``: the same pid)."""
    return ["sh", "-c", 'trap "" INT; exec "$@"', "sh", *command]


def resume_to_the_end(out, env: dict[str, str], timeout: float = 150) -> subprocess.CompletedProcess:
    """``agentax train --resume OUT`` in a fresh process, which must finish the run."""
    done = subprocess.run(
        [sys.executable, "-m", "agentax.cli", "train", "--resume", str(out), "--no-progress"],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done
