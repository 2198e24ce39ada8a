"""Value iteration: agentax (jitted ``lax.while_loop``) against a plain NumPy loop and pymdptoolbox.

Same MDPs, same discount factor and tolerance, all in this process (pymdptoolbox in a subprocess of
the benchmark venv ``.bench-venv``, created here on first use; it never enters the core install).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agentax.envs.mdp import frozenlake, gridworld, lecture_mdp, random_mdp
from agentax.tabular.planning import _value_iteration

DISCOUNT_FACTOR = 0.9
TOL = 1e-4
MAX_ITERATIONS = 10_000
TOOLBOX_MAX_ENTRIES = 10_000_000  # pymdptoolbox gets sparse float64 copies: skip the 800M-entry dense MDP
ROOT = Path(__file__).resolve().parent.parent
BENCH_VENV = ROOT / ".bench-venv"
PYMDPTOOLBOX = "pymdptoolbox==4.0b3"

# pymdptoolbox's ValueIteration stops when span(V_k+1 − V_k) < epsilon (1 − γ) / γ; we pass
# epsilon = tol · γ / (1 − γ) so its threshold is our tolerance. It has no terminal states: the
# tables it gets send terminal states to themselves with reward 0, which gives them value 0 too.
PYMDPTOOLBOX_SCRIPT = r"""
import json, sys, time
import numpy as np, scipy.sparse as sp
import mdptoolbox.mdp
data = np.load(sys.argv[1], allow_pickle=False)
next_states, probabilities, rewards = data["next_states"], data["probabilities"], data["rewards"]
num_states, num_actions, k = next_states.shape
rows = np.repeat(np.arange(num_states), k)
shape = (num_states, num_states)
P = [sp.csr_matrix((probabilities[:, a].ravel(), (rows, next_states[:, a].ravel())), shape=shape)
     for a in range(num_actions)]
gamma, tol = float(data["discount_factor"]), float(data["tol"])
times, begin = [], time.perf_counter()
while len(times) < 20 and time.perf_counter() - begin < 1.0:  # best of repeats, as for agentax and NumPy
    vi = mdptoolbox.mdp.ValueIteration(P, rewards, gamma, epsilon=tol * gamma / (1 - gamma), max_iter=100000)
    start = time.perf_counter(); vi.run(); times.append(time.perf_counter() - start)
print(json.dumps({"seconds": min(times), "iterations": int(vi.iter), "V": list(map(float, vi.V))}))
"""


def numpy_tables(mdp) -> dict:
    """The MDP's arrays as NumPy (done before timing, so the loop pays no JAX dispatch)."""
    tables = {"possible": np.asarray(mdp.possible_actions), "terminal": np.asarray(mdp.terminal)}
    if hasattr(mdp, "transition_probabilities"):
        tables["transition_probabilities"] = np.asarray(mdp.transition_probabilities)
        rewards = np.asarray(mdp.rewards)
        if rewards.ndim == 3:
            rewards = (tables["transition_probabilities"] * rewards).sum(-1)
    else:
        tables["next_states"], tables["probabilities"] = (
            np.asarray(mdp.next_states),
            np.asarray(mdp.probabilities),
        )
        rewards = (tables["probabilities"] * np.asarray(mdp.rewards)).sum(-1)
    tables["rewards"] = rewards.astype(np.float32)
    return tables


def numpy_value_iteration(tables: dict, discount_factor: float, tol: float, error_bounds: bool) -> np.ndarray:
    """Value iteration written the obvious way in NumPy (float32 tables, as agentax has them), with
    the same stopping rule as agentax's (the residual, or MacQueen's bounds and their midpoint)."""
    rewards, possible, terminal = tables["rewards"], tables["possible"], tables["terminal"]
    values = np.zeros(len(terminal), np.float32)
    for _ in range(100_000):
        if "transition_probabilities" in tables:
            next_values = tables["transition_probabilities"] @ values
        else:
            next_values = (tables["probabilities"] * values[tables["next_states"]]).sum(-1)
        q_values = np.where(possible, rewards + discount_factor * next_values, -np.inf)
        new_values = np.where(terminal, 0.0, q_values.max(-1)).astype(np.float32)
        delta = new_values - values
        values = new_values
        if not error_bounds and np.abs(delta).max() < tol:
            return values
        scale = discount_factor / (1 - discount_factor)
        if error_bounds and scale * (delta.max() - delta.min()) / 2 < tol:
            return np.where(terminal, 0.0, values + scale * (delta.max() + delta.min()) / 2)
    return values


def bench_venv_python() -> Path | None:
    """The benchmark venv's python with pymdptoolbox installed, or None if it cannot be made."""
    python = BENCH_VENV / "bin" / "python"
    check = [str(python), "-c", "import mdptoolbox.mdp, scipy"]
    try:
        if python.exists() and subprocess.run(check, capture_output=True).returncode == 0:
            return python
        if not python.exists():
            subprocess.run([sys.executable, "-m", "venv", str(BENCH_VENV)], check=True, capture_output=True)
        install = [str(python), "-m", "pip", "install", "-q", PYMDPTOOLBOX, "numpy", "scipy"]
        subprocess.run(install, check=True, capture_output=True, timeout=600)
        return python if subprocess.run(check, capture_output=True).returncode == 0 else None
    except (subprocess.SubprocessError, OSError):
        return None


def run_pymdptoolbox(python: Path, mdp) -> dict | None:
    sparse = mdp if hasattr(mdp, "next_states") else mdp.to_sparse()
    terminal = np.asarray(sparse.terminal)
    next_states = np.asarray(sparse.next_states).copy()
    probabilities = np.asarray(sparse.probabilities, np.float64).copy()
    rewards = np.asarray(sparse.expected_rewards(), np.float64).copy()
    next_states[terminal], probabilities[terminal], rewards[terminal] = (
        np.arange(len(terminal))[terminal, None, None],
        0.0,
        0.0,
    )
    probabilities[terminal, :, 0] = 1.0
    probabilities /= probabilities.sum(-1, keepdims=True)  # float64 rows summing to 1 for its checks
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "mdp.npz"
        np.savez(
            path,
            next_states=next_states,
            probabilities=probabilities,
            rewards=rewards,
            discount_factor=DISCOUNT_FACTOR,
            tol=TOL,
        )
        result = subprocess.run(
            [str(python), "-c", PYMDPTOOLBOX_SCRIPT, str(path)], capture_output=True, text=True
        )
    if result.returncode != 0:
        return None
    return json.loads(result.stdout)


def timed(function, budget: float = 1.0, max_repeats: int = 20):
    """``(output, best seconds)`` over repeated calls until ``budget`` seconds or ``max_repeats``."""
    times = []
    while len(times) < max_repeats and sum(times) < budget:
        start = time.perf_counter()
        output = jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    return output, min(times)


def bench_case(name: str, form: str, mdp, python: Path | None, error_bounds: bool = False) -> list:
    """One table row: agentax against the NumPy loop and (for tables it can hold) pymdptoolbox.

    agentax's jitted program is compiled ahead of time (timed apart), then run once.
    """
    arguments = (mdp, jnp.float32(DISCOUNT_FACTOR), jnp.float32(TOL))
    start = time.perf_counter()
    compiled = _value_iteration.lower(
        *arguments, max_iterations=MAX_ITERATIONS, error_bounds=error_bounds
    ).compile()
    compile_seconds = time.perf_counter() - start
    result, seconds = timed(lambda: compiled(*arguments))
    values = np.asarray(result.values)
    tables = numpy_tables(mdp)
    reference, numpy_seconds = timed(
        lambda: numpy_value_iteration(tables, DISCOUNT_FACTOR, TOL, error_bounds)
    )
    row = [
        name,
        f"{mdp.num_states:,} × {mdp.num_actions}",
        form,
        "MacQueen bounds" if error_bounds else "residual",
        int(result.num_iterations),
        float(f"{compile_seconds:.3g}"),
        float(f"{seconds:.3g}"),
        float(f"{numpy_seconds:.3g}"),
        float(f"{numpy_seconds / seconds:.3g}"),
        float(f"{np.abs(reference - values).max():.2g}"),
    ]
    successors = mdp.next_states.shape[-1] if hasattr(mdp, "next_states") else mdp.num_states
    fits = mdp.num_states * mdp.num_actions * successors <= TOOLBOX_MAX_ENTRIES and not error_bounds
    toolbox = run_pymdptoolbox(python, mdp) if python and fits else None
    if toolbox is None:
        return row + ["-", "-", "-", "-"]
    return row + [
        toolbox["iterations"],
        float(f"{toolbox['seconds']:.3g}"),
        float(f"{toolbox['seconds'] / seconds:.3g}"),
        float(f"{np.abs(np.asarray(toolbox['V']) - values).max():.2g}"),
    ]


def run() -> dict:
    python = bench_venv_python()
    rows = [
        bench_case("lecture 3-state", "dense", lecture_mdp(), python),
        bench_case("FrozenLake 8x8 (slippery)", "sparse", frozenlake("8x8", sparse=True), python),
        bench_case("gridworld 100×100 (slip 0.1)", "sparse", gridworld(100, slip=0.1), python),
    ]
    random_dense = random_mdp(0, 10_000, 8)
    rows.append(bench_case("random 10,000 × 8", "dense", random_dense, python))
    rows.append(bench_case("random 10,000 × 8", "dense", random_dense, python, error_bounds=True))
    del random_dense
    toolbox_note = (
        f"pymdptoolbox ({PYMDPTOOLBOX}, in `.bench-venv`, scipy sparse tables, float64) ran in a subprocess; "
        "its ValueIteration stops on the span of the update (epsilon set so its threshold is our tolerance), "
        "so its iteration count differs. It is skipped for the dense 10,000 × 8 MDP (its tables would be "
        "6.4 GB of float64)."
        if python
        else "pymdptoolbox could not be installed in `.bench-venv` here, so only the NumPy loop is compared."
    )
    return {
        "name": "tabular",
        "title": "Value iteration: agentax vs a NumPy loop and pymdptoolbox",
        "headers": [
            "MDP",
            "S × A",
            "form",
            "stopping rule",
            "iterations",
            "compile s",
            "agentax s",
            "NumPy s",
            "NumPy / agentax",
            "max |V_numpy − V|",
            "pymdptoolbox iterations",
            "pymdptoolbox s",
            "pymdptoolbox / agentax",
            "max |V_toolbox − V|",
        ],
        "rows": rows,
        "notes": (
            f"Value iteration from V = 0 at discount factor {DISCOUNT_FACTOR} until max |V_k+1 − V_k| "
            f"< {TOL}. agentax: `agentax.tabular.value_iteration`, one jitted `lax.while_loop`, "
            "compiled ahead of time (compile s) and then run (agentax s); sparse MDPs store "
            "[S, A, K] next states, never S × A × S. "
            "NumPy: the same loop written the obvious way (`T @ V` for dense tables, "
            "`(P * V[next]).sum(-1)` for sparse ones), float32, in the same process. Times are the "
            "best of repeated runs (up to 20 within ~1 s; a single run where one takes longer). "
            "agentax pins its process to one CPU (the XLA hang cure), so NumPy runs on that one CPU "
            "too. Ratios above 1 mean agentax is faster. The last row stops on MacQueen's error "
            "bounds instead "
            "(`value_iteration(..., error_bounds=True)`: stop when the bounds on V* are within ± tol, "
            "return their midpoint), which a random dense MDP meets in a handful of iterations. "
            + toolbox_note
        ),
    }
