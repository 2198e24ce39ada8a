"""Golden metrics rows: short trainings whose ``metrics.csv`` must not move when code moves.

Each case in :data:`CASES` is a short training through the public API only (``agentax.train``), so
the test survives a reorganisation of the runners behind it. Its rows were recorded with the code
of the time in ``tests/golden/<case>.csv`` (the run's ``metrics.csv`` as written); the test trains
again with exactly the same settings and compares:

* the same columns (in any order) and the same number of rows (at least 3);
* the count columns (:data:`COUNT_COLUMNS`: env steps, updates, learning steps, ...) exactly;
* every other column to ``rtol=1e-5, atol=1e-6`` (blank cells, NaN, must stay blank). Not bit for
  bit: a restructured program lets XLA fuse and reorder float operations differently, which moves
  the last bits of a loss, and metrics.csv rounds to 6 decimals, so one such bit can flip the last
  digit written (1e-6, inside ``atol``). A real change of behaviour moves the numbers far more;
* not the columns that measure time or speed (:data:`TIME_COLUMNS`).

Recording (only when a change of the numbers is intended, and say why in the commit; or for a new
case: its row in :data:`CASES`, then ``--write`` with its name; it writes this CPU's width's files,
so record the other width's on such a CPU too)::

    PYTHONPATH=src python tests/test_golden.py --write            # every case
    PYTHONPATH=src python tests/test_golden.py --write ppo_host   # some cases

Each case trains in a fresh Python process (on CPU, ``JAX_PLATFORMS=cpu``) that makes jax's CPU
client first, on one CPU (:func:`make_one_cpu_client`), in the test and in the writer alike. The
numbers depend on the CPUs that client saw when jax made it: XLA sizes its thread pool by them, and
the Atari CNN's update comes out differently with 1 and 2 CPUs. Within a test process that depends
on what ran before (the compiled runner keeps agentax's one-CPU client; the host, parallel and
compiled Atari runners ask for every CPU when they come first); a fresh process has a one-CPU
client whatever ran before and however many cores the machine has.

They also depend on the width of the CPU's float vectors, to which XLA and its dot kernels split
sums: CPUs of one width give the same rows, and the files are kept by width
(``tests/golden/<width>/``, :func:`vector_width`). ``avx512`` was recorded on an Intel Xeon (AVX-512,
AMX) and gave the same rows on an AMD EPYC Zen 4; ``avx2`` on an AMD EPYC Zen 3 (AVX2, no AVX-512),
where three of the ``avx512`` cases come out beyond the tolerance. A CPU of another width skips
the comparison, saying how to record its rows.

Each case was trained twice with the recording code and gave the same rows (the parallel runner's
on-policy lag is exact: rollout ``k`` is always collected with parameter version ``k - policy_lag``,
whatever the threads' timing). Run alone: ``pytest tests/test_golden.py -p no:xdist -q``.
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

GOLDEN = Path(__file__).resolve().parent / "golden"
WIDTHS = {path.name for path in GOLDEN.iterdir() if path.is_dir()}
"""The vector widths whose rows are recorded (:func:`vector_width`)."""

# The settings of each case: agentax.train's arguments (algo and env apart), shared by the writer and
# the test. The host runners log a row every 2,048 env steps, the compiled ones every chunk of updates
# (updates_per_chunk of the preset); each case logs at least 3 rows and learns (nonzero losses).
OFF_POLICY: dict[str, Any] = {
    "env": "Pendulum-v1",
    "preset": "default",
    "hidden": (64, 64),
    "batch_size": 64,
    "num_envs": 4,
    "train_frequency": 8,
    "utd": 0.25,
    "learning_starts": 256,
    "buffer_size": 8_192,
}
"""SAC's and TD3's cases: Pendulum, small networks, 4 envs x 8 steps a phase of 8 learning steps."""

CASES: dict[str, dict[str, Any]] = {
    # cartpole-fast: 8 envs x 32 steps an update, a row every 10 updates (2,560 steps)
    "ppo_compiled": {"algo": "ppo", "runner": "compiled", "seeds": 2, "total_steps": 7_680},
    # the default preset: 4 envs x 64 steps an update, a row every 4; learning from 1,000 steps
    "dqn_compiled": {"algo": "dqn", "runner": "compiled", "total_steps": 4_096},
    # 4 episodes of at most 100 steps an update, a row every 10 updates
    "reinforce_compiled": {
        "algo": "reinforce",
        "runner": "compiled",
        "total_steps": 12_000,
        "episodes_per_update": 4,
        "max_steps": 100,
    },
    "ppo_host": {"algo": "ppo", "runner": "host", "total_steps": 6_144},
    "dqn_host": {"algo": "dqn", "runner": "host", "total_steps": 6_144},
    "ppo_parallel": {"algo": "ppo", "runner": "parallel", "actors": 2, "policy_lag": 1, "total_steps": 6_144},
    # 4 envs x 16 steps an update, a row (and an evaluation) every 20 updates (1,280 steps)
    "pqn_compiled": {
        "algo": "pqn",
        "runner": "compiled",
        "total_steps": 3_840,
        "num_envs": 4,
        "num_steps": 16,
    },
    "pqn_host": {"algo": "pqn", "runner": "host", "total_steps": 6_144, "num_envs": 4, "num_steps": 16},
    # the default preset's 10 phases a row (320 steps) on the compiled runner; the host cases replay
    # with priorities (dqn_host pins uniform replay's batches drawn ahead by as_dataset)
    "sac_compiled": {"algo": "sac", "runner": "compiled", **OFF_POLICY, "total_steps": 1_280},
    "sac_host": {"algo": "sac", "runner": "host", **OFF_POLICY, "total_steps": 6_144, "prioritized": True},
    "td3_compiled": {"algo": "td3", "runner": "compiled", **OFF_POLICY, "total_steps": 1_280},
    "td3_host": {"algo": "td3", "runner": "host", **OFF_POLICY, "total_steps": 6_144, "prioritized": True},
    # EnvPool's step inside the program: 2 envs x 32 steps an iteration, 96 iterations
    "ppo_atari_compiled": {
        "algo": "ppo",
        "env": "ALE/Breakout-v5",
        "runner": "compiled",
        "total_steps": 6_144,
        "num_envs": 2,
        "num_steps": 32,
        "num_minibatches": 2,
        "update_epochs": 1,
        "policy_lag": 0,  # one program an iteration, as before policy lag 1 (the default) existed
    },
}

TIME_COLUMNS = frozenset(
    {
        "wall_seconds",
        "steps_per_second",
        "actor_steps_per_second",
        "learner_updates_per_second",
        "actor_wait_fraction",  # shares of wall-clock time the threads waited
        "learner_wait_fraction",
    }
)
"""Columns that measure time or speed: not compared."""

COUNT_COLUMNS = frozenset(
    {"env_steps", "updates", "learning_steps", "episodes", "frames", "replay_size", "replay_bytes", "frozen"}
)
"""Columns that count (where a case has them): compared exactly."""

pytestmark = [pytest.mark.timeout(180), pytest.mark.xdist_group("golden")]


def train_case(name: str, out: Path) -> Path:
    """Train case ``name`` into the run folder ``out`` in this process; its ``metrics.csv``."""
    import agentax

    settings = dict(CASES[name])
    algo, env = settings.pop("algo"), settings.pop("env", "CartPole-v1")
    agentax.train(algo, env=env, out=str(out), progress=False, stop_at_return="none", **settings)
    return out / "metrics.csv"


def train_in_fresh_process(name: str, out: Path) -> Path:
    """Train case ``name`` into ``out`` in a new Python process with a one-CPU jax client; its
    ``metrics.csv``. The golden rows were recorded with XLA's convolutions, so the Atari cases keep
    them (``AGENTAX_CONV=xla``): oneDNN's (agentax.kernels) sum in another order, 1e-3 apart."""
    command = [sys.executable, str(Path(__file__).resolve()), "--train", name, str(out)]
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "AGENTAX_CONV": "xla"}
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=170)
    assert done.returncode == 0, f"training {name} failed:\n{done.stderr[-4000:]}"
    return out / "metrics.csv"


def make_one_cpu_client() -> None:
    """Have jax create its CPU client now, while this process is pinned to one CPU (so XLA sizes
    its thread pool for one), then give every thread the process's CPUs back. Call before anything
    imports jax. The CPU: an xdist worker's by its number, else one by the pid."""
    if not hasattr(os, "sched_setaffinity"):
        import jax

        jax.devices("cpu")
        return
    allowed = os.sched_getaffinity(0)
    cpus = sorted(allowed)
    worker = re.fullmatch(r"gw(\d+)", os.environ.get("PYTEST_XDIST_WORKER", ""))
    os.sched_setaffinity(0, {cpus[(int(worker.group(1)) if worker else os.getpid()) % len(cpus)]})
    import jax

    jax.devices("cpu")  # the client, and its threads, on the one CPU
    for thread in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(thread), allowed)
        except OSError:  # the thread ended meanwhile
            pass


def vector_width() -> str:
    """The golden set for this CPU: ``avx512`` (AVX-512 float vectors), ``avx2`` (AVX2 with FMA), else
    the machine's architecture, for which no rows are recorded."""
    from agentax.kernel_choice import cpu_info

    flags = cpu_info()[1]
    if "avx512f" in flags:
        return "avx512"
    if {"avx2", "fma"} <= flags:
        return "avx2"
    return platform.machine().lower() or "unknown"


def golden_file(name: str) -> Path:
    return GOLDEN / vector_width() / f"{name}.csv"


def read_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), list(reader)


def as_float(cell: str) -> float:
    return float(cell) if cell != "" else float("nan")


def assert_same_rows(golden: Path, trained: Path) -> None:
    golden_columns, golden_rows = read_rows(golden)
    columns, rows = read_rows(trained)
    assert sorted(columns) == sorted(golden_columns), (columns, golden_columns)
    assert len(rows) == len(golden_rows) >= 3, (len(rows), len(golden_rows))
    for column in golden_columns:
        if column in TIME_COLUMNS:
            continue
        expected = np.array([as_float(row[column]) for row in golden_rows])
        actual = np.array([as_float(row[column]) for row in rows])
        if column in COUNT_COLUMNS:
            np.testing.assert_array_equal(actual, expected, err_msg=f"column {column}")
        else:
            np.testing.assert_allclose(actual, expected, rtol=1e-5, atol=1e-6, err_msg=f"column {column}")


LONG_CASES = {"ppo_atari_compiled"}  # ~110 s cold (the Nature CNN's compilation): make test-long


@pytest.mark.slow
@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.long) if n in LONG_CASES else n for n in CASES]
)
def test_metrics_rows_match_the_golden_file(name, tmp_path):
    if CASES[name].get("env", "").startswith("ALE/"):
        pytest.importorskip("envpool")
    golden = golden_file(name)
    if not golden.parent.is_dir():
        pytest.skip(
            f"no golden rows for {golden.parent.name} CPUs (recorded: {', '.join(sorted(WIDTHS))}); "
            "record them with python tests/test_golden.py --write"
        )
    assert golden.is_file(), f"no {golden}; record it with python tests/test_golden.py --write {name}"
    assert_same_rows(golden, train_in_fresh_process(name, tmp_path / name))


def test_the_golden_files_are_the_cases():
    """Each width's folder holds one file per case, and every column that looks like a time or a
    speed is in TIME_COLUMNS."""
    assert WIDTHS == {"avx512", "avx2"}, WIDTHS
    for width in WIDTHS:
        assert sorted(p.stem for p in (GOLDEN / width).glob("*.csv")) == sorted(CASES), width
    columns = {column for path in GOLDEN.glob("*/*.csv") for column in read_rows(path)[0]}
    timing = {c for c in columns if re.search(r"seconds|per_second|sps|wait|elapsed|time", c)}
    assert timing <= TIME_COLUMNS, timing - TIME_COLUMNS


def write(names: list[str]) -> None:
    """Train ``names`` and record their metrics.csv as this CPU's width's golden files."""
    with tempfile.TemporaryDirectory() as folder:
        for name in names:
            metrics = train_in_fresh_process(name, Path(folder) / name)
            golden = golden_file(name)
            golden.parent.mkdir(exist_ok=True)
            shutil.copyfile(metrics, golden)
            print(f"wrote {golden} ({len(read_rows(metrics)[1])} rows)", file=sys.stderr)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--train"]:  # the fresh process of train_in_fresh_process: NAME OUT
        make_one_cpu_client()
        train_case(sys.argv[2], Path(sys.argv[3]))
        sys.exit()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="record the golden files")
    parser.add_argument("names", nargs="*", help=f"cases (default: all): {', '.join(CASES)}")
    args = parser.parse_args()
    if not args.write:
        parser.error("nothing to do without --write (run the comparison with pytest)")
    if unknown := sorted(set(args.names) - set(CASES)):
        parser.error(f"unknown case(s) {', '.join(unknown)}; choose from {', '.join(CASES)}")
    write(args.names or list(CASES))
