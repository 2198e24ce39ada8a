"""Shared test setup. Every test runs under pytest-timeout (pyproject.toml): an XLA hang fails fast."""

import os

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
os.environ.setdefault("MPLBACKEND", "Agg")
