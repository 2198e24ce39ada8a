"""Every figure on the README and the docs pages, written from the result file it comes from.

A figure on a page is its printed value between two HTML comments, which GitHub and the docs site
do not show::

    SB3 DQN 48.2 s  ->  SB3 DQN <!-- fig:dqn.sb3.seconds -->48.2<!-- /fig --> s

Its name is a key of ``FIGURES`` below, which says the source (a committed result file:
``benchmarks/results/NAME.json``, written by ``make bench``, or a trained score's evidence folder
``evidence/NAME/``), how the value is read from it and how it is printed. ``python scripts/figures.py
--write`` rewrites every marked figure from its source; ``--check`` (the default) prints each marked
figure that differs from its source, each unknown name and each figure no page shows, and exits 1 if
there is any; ``--list`` prints every figure with its value and source. ``tests/test_figures.py``
runs the check.

An evidence folder holds what a trained score stands on (``--evidence RUN_DIR --name NAME`` makes
one from a finished run folder, on the machine that trained it)::

    evidence/NAME/
      config.json   the run's config (algorithm, env, preset, runner, every hyperparameter)
      metrics.csv   its training rows
      eval.json     its final evaluation (mean, std, min, max return, episodes)
      run.json      {"command", "wall_seconds", "date", "cpu": lscpu's model and flags,
                     "commit": the checkout when the folder was made, "-dirty" with uncommitted changes}
      curve.png     its learning curve, where the run drew one
"""

from __future__ import annotations

import argparse
import csv
import datetime
import functools
import importlib.util
import json
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(r"<!-- fig:([\w.\-]+) -->(.*?)<!-- /fig -->")
OPENING = re.compile(r"<!-- fig:")
CLOSING = re.compile(r"<!-- /fig -->")
EVIDENCE_FILES = ("config.json", "metrics.csv", "eval.json", "curve.png")


def _bench_harness():
    """``benchmarks/run.py`` as a module: its number format and its CPU record, shared."""
    spec = importlib.util.spec_from_file_location("agentax_bench_run", ROOT / "benchmarks" / "run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


HARNESS = _bench_harness()


@dataclass(frozen=True)
class Figure:
    """One figure: ``read(source JSON) -> value``, printed by ``fmt`` (a format string or a function)."""

    source: str  # a path from the repository root
    read: Callable[[dict], object]
    fmt: str | Callable[[object], str] = "{}"

    def show(self, root: Path) -> str:
        text = (root / self.source).read_text()
        record = list(csv.DictReader(text.splitlines())) if self.source.endswith(".csv") else json.loads(text)
        value = self.read(record)
        return self.fmt(value) if callable(self.fmt) else self.fmt.format(value)


def number(value):
    """A table cell as a number where it is one: ``1.90×`` -> 1.9, ``-1.4%`` -> -1.4, ``8/8`` stays."""
    if isinstance(value, int | float):
        return value
    try:
        return float(str(value).rstrip("×%x").replace(",", ""))
    except ValueError:
        return value


def cell(result: dict, *labels, col: str):
    """The cell in column ``col`` of the one row whose first cells are ``labels``."""
    rows = [row for row in result["rows"] if tuple(row[: len(labels)]) == labels]
    if len(rows) != 1:
        raise LookupError(f"{result['name']}.json has {len(rows)} rows starting {labels!r}, expected 1")
    return rows[0][result["headers"].index(col)]


def bench(name: str, *labels, col: str, fmt: str | Callable = "{}", scale: float = 1.0) -> Figure:
    """A cell of ``benchmarks/results/NAME.json`` (times ``scale``: seconds shown as ms)."""
    return Figure(
        f"benchmarks/results/{name}.json", lambda r: _scaled(number(cell(r, *labels, col=col)), scale), fmt
    )


def _scaled(value, scale: float):
    return value * scale if scale != 1.0 else value


def derived(name: str, read: Callable[[dict], float], fmt: str | Callable = "{}") -> Figure:
    """A value computed from ``benchmarks/results/NAME.json``: a ratio of two of its cells, say."""
    return Figure(f"benchmarks/results/{name}.json", read, fmt)


def sb3_row(result: dict, agent: str) -> list:
    """The Stable-Baselines3 row of ``agent`` in a bench result (its label names torch's threads)."""
    return next(row for row in result["rows"] if row[0] == agent and row[1].startswith("Stable-Baselines3"))


def cpu(name: str) -> Figure:
    """The CPU ``benchmarks/results/NAME.json`` was measured on, as ``run.cpu_label`` names it."""
    return Figure(f"benchmarks/results/{name}.json", lambda r: HARNESS.cpu_label(r["machine"]))


def evidence(name: str, file: str, key: str, fmt: str | Callable = "{}") -> Figure:
    """A field of ``evidence/NAME/FILE`` (``key``: dotted, ``cpu`` is ``run.json``'s CPU label)."""

    def read(record: dict):
        if key == "cpu":
            return HARNESS.cpu_label({"cpu": record["cpu"]})
        for part in key.split("."):
            record = record[part]
        return record

    return Figure(f"evidence/{name}/{file}", read, fmt)


def passed(name: str, score: float, column: str, fmt: str | Callable = "{}", rows: int = 10) -> Figure:
    """``column`` (``wall_seconds``, ``env_steps``) of the first row of ``evidence/NAME/metrics.csv``
    where the mean of the last ``rows`` scores (the training games' true score; a row in which no
    game finished has none) is at least ``score``."""

    def read(metrics: list[dict]):
        scores: list[float] = []
        for row in metrics:
            if row["mean_return"]:
                scores.append(float(row["mean_return"]))
                if len(scores) >= rows and sum(scores[-rows:]) / rows >= score:
                    return float(row[column])
        raise LookupError(f"evidence/{name}/metrics.csv never reaches a mean of {score} over {rows} rows")

    return Figure(f"evidence/{name}/metrics.csv", read, fmt)


def si(value) -> str:
    """The benchmark tables' format: 51.2M, 179k, 3,919, 65.1."""
    return HARNESS.format_cell(float(value))


def thousands(value) -> str:
    return f"{value:,.0f}"


def minus(fmt: str) -> Callable[[float], str]:
    """``fmt`` with a typographic minus sign (−1.4), as the pages print negative figures."""
    return lambda value: fmt.format(value).replace("-", "−")


def of(value) -> str:
    """``8/8`` -> ``8 of 8``."""
    return str(value).replace("/", " of ")


def seconds_short(value) -> str:
    """Seconds, whole from 10 on, else one decimal: 195, 4.6."""
    return f"{value:.0f}" if value >= 10 else f"{value:.1f}"


def minutes(value) -> str:
    """Seconds as ``2 min 16 s``."""
    whole = round(value)
    return f"{whole // 60} min {whole % 60} s"


def ratio(name: str, top: tuple, bottom: tuple, col: str, fmt: str = "{:.2f}") -> Figure:
    """``top`` row's ``col`` over ``bottom`` row's, both of ``benchmarks/results/NAME.json``."""
    return derived(name, lambda r: number(cell(r, *top, col=col)) / number(cell(r, *bottom, col=col)), fmt)


AGENTAX_ENVS = "agentax (jit + vmap + scan)"
NUMPY_ENVS = "Gymnasium NumPy-vectorized"
PPO_PROCESS = "agentax train ppo (whole process, {} cache)"
DQN_PROCESS = "`agentax train dqn` process, {} compile cache"
PQN_PROCESS = "`agentax train pqn` process, {} compile cache"
DQN_COMPILED = "compiled (JAX CartPole)"
SB3_DQN = "SB3 DQN, RL-Zoo settings, whole process"
SB3_PPO = "Stable-Baselines3 PPO, RL-Zoo settings, 1e5 steps"
GRIDWORLD = ("gridworld 100×100 (slip 0.1)", "10,000 × 4")
FROZENLAKE = ("FrozenLake 8x8 (slippery)", "64 × 4")
LECTURE_MDP = ("lecture 3-state", "3 × 3")
RANDOM_MDP = ("random 10,000 × 8", "10,000 × 8", "dense")
PAR_DQN = "DQN, RL-Zoo schedule, net 256-256"
PAR_PPO = "PPO cartpole-fast"
PAR_COMPILED = "PPO default, compiled (JAX CartPole)"
PAR_HOST = "PPO default, host (Gymnasium CartPole)"
ATARI_ENVS = "8 Breakout envs, random actions"
ATARI_STEP = "Nature-CNN DQN learning step, batch 32"
ATARI_DQN = "DQN on Breakout, 8,192 agent steps"
ATARI_PPO = "PPO atari preset on Breakout"
ATARI_PQN = "PQN breakout-hour preset on Breakout"
ATARI_PQN15 = "PQN breakout-15min preset on Breakout"
RUNNERS = {
    "host": "host runner",
    "parallel": "parallel runner (1 actor, policy lag 1)",
    "compiled": "compiled Atari runner (EnvPool inside the program)",
    "ray": "Ray runner (1 actor process, policy lag 1)",
}
RUNNERS_NOW = {  # the runner rows since the compiled runner has a policy lag (bench_atari.RUNNERS)
    **RUNNERS,
    "compiled": "compiled Atari runner (EnvPool inside the program, policy lag 0)",
    "compiled-lag1": "compiled Atari runner (policy lag 1: collection beside learning)",
}
LEARNER = "DQN update, batch 32"
PQN_ITERATION = "PQN breakout-hour iteration"
SAC_PROCESS = "`agentax train sac --env Pendulum-v1` process (compiled runner)"
SAC_SB3 = "SB3 SAC, RL Zoo settings, whole process"
WORKERS = {
    "one": "1 process (--workers 1)",
    "taskset": "2 workers, confined to one core (taskset -c 0)",
    "two": "2 workers, both cores",
}
TRAINED = (
    "ppo-halfcheetah-1m",
    "ppo-halfcheetah-1m-seed1",
    "ppo-halfcheetah-1m-seed2",
    "sac-halfcheetah-1m",
    "pqn-breakout-hour-lag1",
    "pqn-breakout-15min",
    "pqn-breakout-15min-auto",
    "pqn-breakout-15min-f32",
    "pqn-breakout-100",
)  # the folders of evidence/ whose scores the pages show


LUNAR = {
    "ppo": ("ppo", "RL Zoo"),
    "dqn": ("dqn", "RL Zoo"),
    "dqn_preset": ("dqn", "Zoo + Double, 3-step, lr → 0, 150k steps (preset lunar)"),
}


def _figures() -> dict[str, Figure]:
    figures: dict[str, Figure] = {}
    for name in ("envs", "evaluate", "tabular", "search", "ppo", "dqn", "parallel", "ray", "atari"):
        figures[f"{name}.cpu"] = cpu(name)
    for name in ("learner", "sweep", "workers", "sac", "mujoco", "export", "lunar"):
        figures[f"{name}.cpu"] = cpu(name)

    # CartPole env steps/s (envs.json)
    for envs in (1, 64, 1024, 8192):
        figures[f"envs.agentax.{envs}"] = bench("envs", AGENTAX_ENVS, envs, col="steps/s", fmt=si)
        figures[f"envs.numpy.{envs}"] = bench("envs", NUMPY_ENVS, envs, col="steps/s", fmt=si)
        figures[f"envs.agentax_over_numpy.{envs}"] = bench(
            "envs", AGENTAX_ENVS, envs, col="÷ NumPy-vectorized", fmt="{:.2g}" if envs < 64 else "{:.1f}"
        )
    figures["envs.agentax_over_loop.8192"] = bench(
        "envs", AGENTAX_ENVS, 8192, col="÷ Python loop", fmt="{:.0f}"
    )
    figures["envs.loop"] = bench("envs", "Gymnasium, Python loop", 1, col="steps/s", fmt=si)
    figures["envs.sync_vector.64"] = bench("envs", "Gymnasium SyncVectorEnv", 64, col="steps/s", fmt=si)

    # evaluation (evaluate.json)
    figures["evaluate.basic.ms"] = bench("evaluate", "basic", col="agentax compiled, ms", fmt="{:.1f}")
    figures["evaluate.basic.first_call"] = bench(
        "evaluate", "basic", col="agentax first call, s (compile + run)", fmt="{:.2f}"
    )
    figures["evaluate.basic.loop_ms"] = bench(
        "evaluate", "basic", col="Gymnasium Python loop, ms (scaled to the same steps)", fmt="{:.0f}"
    )
    figures["evaluate.basic.ratio"] = bench(
        "evaluate", "basic", col="ratio: loop / agentax compiled", fmt="{:.0f}"
    )

    # value iteration (tabular.json)
    figures["tabular.gridworld.ms"] = bench("tabular", *GRIDWORLD, col="agentax s", fmt="{:.0f}", scale=1e3)
    figures["tabular.gridworld.iterations"] = bench("tabular", *GRIDWORLD, col="iterations")
    figures["tabular.gridworld.numpy"] = bench("tabular", *GRIDWORLD, col="NumPy / agentax", fmt="{:.1f}")
    figures["tabular.gridworld.toolbox"] = bench(
        "tabular", *GRIDWORLD, col="pymdptoolbox / agentax", fmt="{:.1f}"
    )
    for key, labels in (("frozenlake", FROZENLAKE), ("lecture", LECTURE_MDP)):
        figures[f"tabular.{key}.ms"] = bench("tabular", *labels, col="agentax s", fmt="{:.2f}", scale=1e3)
        figures[f"tabular.{key}.numpy"] = bench("tabular", *labels, col="NumPy / agentax", fmt="{:.0f}")
        figures[f"tabular.{key}.toolbox"] = bench(
            "tabular", *labels, col="pymdptoolbox / agentax", fmt="{:.0f}"
        )
    figures["tabular.random.seconds"] = bench(
        "tabular", *RANDOM_MDP, "residual", col="agentax s", fmt="{:.1f}"
    )
    figures["tabular.random.iterations"] = bench("tabular", *RANDOM_MDP, "residual", col="iterations")
    figures["tabular.random.numpy"] = bench(
        "tabular", *RANDOM_MDP, "residual", col="NumPy / agentax", fmt="{:.2f}"
    )
    figures["tabular.bounds.seconds"] = bench(
        "tabular", *RANDOM_MDP, "MacQueen bounds", col="agentax s", fmt="{:.2f}"
    )
    figures["tabular.bounds.iterations"] = bench("tabular", *RANDOM_MDP, "MacQueen bounds", col="iterations")

    # policy search (search.json)
    for method in ("GA", "CEM"):
        for version, bar in (("v0", "195"), ("v1", "475")):
            task = f"{method} CartPole-{version} (≥ {bar})"
            key = f"search.{method.lower()}.{version}"
            figures[f"{key}.seconds"] = bench(
                "search", task, "agentax (JAX)", col="seconds (vacuum: settings/s)", fmt="{:.2f}"
            )
    for method in ("ga", "cem"):
        task = f"{method.upper()} CartPole-v1 (≥ 475)"
        figures[f"search.{method}.v1.speedup"] = bench(
            "search", task, "agentax (JAX)", col="speed-up", fmt="{:.1f}"
        )
    speedups = lambda r: [row[-1] for row in r["rows"] if "CartPole" in row[0] and row[1] == "agentax (JAX)"]  # noqa: E731
    figures["search.speedup.least"] = derived("search", lambda r: min(speedups(r)), "{:.1f}")
    figures["search.speedup.most"] = derived("search", lambda r: max(speedups(r)), "{:.1f}")
    vacuum = ("vacuum (1024 settings × 4 episodes)", "agentax (JAX)")
    figures["search.vacuum.settings"] = bench(
        "search", *vacuum, col="seconds (vacuum: settings/s)", fmt=thousands
    )
    figures["search.vacuum.steps"] = bench("search", *vacuum, col="env steps/s", fmt=si)
    figures["search.vacuum.speedup"] = bench("search", *vacuum, col="speed-up", fmt="{:.1f}")
    figures["search.vacuum.dust"] = bench("search", *vacuum, col="fresh mean return", fmt="{:.0f}")
    figures["search.vacuum.numpy_dust"] = bench(
        "search", "", "NumPy, vectorized", col="fresh mean return", fmt="{:.0f}"
    )

    # PPO on CartPole (ppo.json)
    for cache, key in (("empty", "cold"), ("warm", "warm")):
        for seeds in (1, 8):
            row = (PPO_PROCESS.format(cache), seeds)
            figures[f"ppo.{key}.{seeds}.seconds"] = bench("ppo", *row, col="whole process s", fmt="{:.1f}")
            figures[f"ppo.{key}.{seeds}.sb3_ratio"] = bench("ppo", *row, col="SB3 s ÷ this", fmt="{:.1f}")
    figures["ppo.cold.1.compile"] = bench(
        "ppo", PPO_PROCESS.format("empty"), 1, col="compile s", fmt="{:.1f}"
    )
    figures["ppo.solved_at.1"] = bench(
        "ppo", PPO_PROCESS.format("empty"), 1, col="solved at env steps (per seed)", fmt=thousands
    )
    figures["ppo.solved_at.8"] = bench(
        "ppo", PPO_PROCESS.format("empty"), 8, col="solved at env steps (per seed)", fmt=si
    )
    figures["ppo.sb3.seconds"] = bench("ppo", SB3_PPO, col="whole process s", fmt="{:.1f}")
    figures["ppo.sb3.steps"] = bench("ppo", SB3_PPO, col="env steps/s", fmt=si)
    for seeds in (1, 8):
        figures[f"ppo.compiled.{seeds}.steps"] = bench(
            "ppo", "compiled runner, 51,200 steps/seed", seeds, col="env steps/s", fmt=si
        )

    # DQN and PQN on CartPole (dqn.json)
    for cache, key in (("cold", "cold"), ("warm", "warm")):
        figures[f"dqn.{key}.seconds"] = bench(
            "dqn", DQN_PROCESS.format(cache), col="wall-clock to solve s", fmt="{:.2f}"
        )
        figures[f"dqn.{key}.sb3_ratio"] = bench(
            "dqn", DQN_PROCESS.format(cache), col="SB3 DQN ÷ this", fmt="{:.1f}"
        )
        figures[f"pqn.{key}.seconds"] = bench(
            "dqn", PQN_PROCESS.format(cache), col="wall-clock to solve s", fmt="{:g}"
        )
        figures[f"pqn.{key}.sb3_ratio"] = bench(
            "dqn", PQN_PROCESS.format(cache), col="SB3 DQN ÷ this", fmt="{:.1f}"
        )
        figures[f"dqn.{key}.over_45"] = derived(
            "dqn",
            lambda r, c=cache: 45 / cell(r, DQN_PROCESS.format(c), col="wall-clock to solve s"),
            "{:.1f}",
        )
    figures["dqn.sb3.seconds"] = bench("dqn", SB3_DQN, col="wall-clock to solve s", fmt="{:.1f}")
    for seeds in (1, 8):
        row = (DQN_COMPILED, seeds)
        figures[f"dqn.compiled.{seeds}.seconds"] = bench(
            "dqn", *row, col="wall-clock to solve s", fmt="{:.2f}"
        )
        figures[f"dqn.compiled.{seeds}.compile"] = bench("dqn", *row, col="compile s", fmt="{:.2f}")
        figures[f"dqn.compiled.{seeds}.updates"] = bench("dqn", *row, col="learner updates/s", fmt=si)
        figures[f"dqn.compiled.{seeds}.solved"] = bench("dqn", *row, col="solved (final eval ≥ 475)", fmt=of)
    host = "host runner (Gymnasium CartPole)"
    figures["dqn.host.seconds"] = bench("dqn", host, col="wall-clock to solve s", fmt="{:.1f}")
    figures["dqn.host.steps"] = bench("dqn", host, col="env steps to solve", fmt=si)
    figures["dqn.host.updates"] = bench("dqn", host, col="learner updates/s", fmt=thousands)

    # the parallel runner and the runners' overhead (parallel.json)
    seconds, over = "seconds", "over the bare run (target ≤ +5 %)"
    for key, workload in (("dqn", PAR_DQN), ("ppo", PAR_PPO)):
        figures[f"parallel.{key}.collect"] = bench(
            "parallel", workload, "collect alone", col=seconds, fmt="{:.2f}"
        )
        figures[f"parallel.{key}.sequential"] = bench(
            "parallel", workload, "sequential (host.train)", col=seconds, fmt="{:.2f}"
        )
    figures["parallel.dqn.learn"] = bench(
        "parallel", PAR_DQN, "learn alone (57 phases)", col=seconds, fmt="{:.2f}"
    )
    figures["parallel.ppo.learn"] = bench(
        "parallel", PAR_PPO, "learn alone (80 learn calls)", col=seconds, fmt="{:.2f}"
    )
    one_actor = (PAR_DQN, "parallel, 1 actor")
    figures["parallel.dqn.one_actor"] = bench("parallel", *one_actor, col=seconds, fmt="{:.2f}")
    figures["parallel.dqn.speedup"] = bench(
        "parallel", *one_actor, col="sequential ÷ this (target ≥ 1.6)", fmt="{:.2f}"
    )
    figures["parallel.dqn.slower_part"] = bench(
        "parallel", *one_actor, col="÷ max(collect, learn) (target ≤ 1.1)", fmt="{:.2f}"
    )
    figures["parallel.dqn.cpu_wall"] = bench("parallel", *one_actor, col="CPU / wall", fmt="{:.2f}")
    figures["parallel.dqn.two_actors"] = bench(
        "parallel", PAR_DQN, "parallel, 2 actors", col="sequential ÷ this (target ≥ 1.6)", fmt="{:.2f}"
    )
    figures["parallel.ppo.speedup"] = bench(
        "parallel",
        PAR_PPO,
        "parallel, 1 actor, policy lag 1",
        col="sequential ÷ this (target ≥ 1.6)",
        fmt="{:.2f}",
    )
    compiled_runner = (PAR_COMPILED, "compiled runner, defaults + run folder")
    host_runner = (PAR_HOST, "host runner, defaults + run folder")
    figures["parallel.overhead.compiled"] = bench(
        "parallel", *compiled_runner, col=over, fmt=minus("{:+.1f}")
    )
    figures["parallel.overhead.host"] = bench("parallel", *host_runner, col=over, fmt=minus("{:+.1f}"))
    figures["parallel.compiled.seconds"] = bench("parallel", *compiled_runner, col=seconds, fmt="{:.2f}")
    figures["parallel.compiled.bare"] = bench(
        "parallel",
        PAR_COMPILED,
        "bare program: the same updates and 10 evaluations",
        col=seconds,
        fmt="{:.2f}",
    )
    figures["parallel.host.seconds"] = bench("parallel", *host_runner, col=seconds, fmt="{:.2f}")
    figures["parallel.host.bare"] = bench(
        "parallel", PAR_HOST, "bare loop: the same rollouts and learn calls", col=seconds, fmt="{:.2f}"
    )

    # Ray actors (ray.json)
    for key, workload in (("dqn", "DQN (bench_parallel workload)"), ("ppo", "PPO cartpole-fast")):
        for runner in ("threads", "ray"):
            figures[f"ray.{key}.{runner}"] = bench("ray", workload, runner, col="training s", fmt="{:.2f}")
        figures[f"ray.{key}.ratio"] = bench("ray", workload, "ray", col="ray / threads", fmt="{:.2f}")
    ray_ms, queue_ms = "Ray ms (round trip or put)", "thread queue ms or actor fetch ms"
    batches = {
        "cartpole": "batch: CartPole rollout [32, 4]",
        "atari": "batch: Atari rollout [128, 4]",
        "packed": "batch: Atari rollout [128, 4], frames once",
    }
    for key, what in batches.items():
        figures[f"ray.batch.{key}.ray_ms"] = bench("ray", what, col=ray_ms, fmt="{:.1f}")
        figures[f"ray.batch.{key}.thread_ms"] = bench("ray", what, col=queue_ms, fmt="{:.2f}")
    figures["ray.batch.atari.mib"] = derived(
        "ray", lambda r: r["figures"]["batches"]["Atari rollout [128, 4]"]["bytes"] / 2**20, "{:.1f}"
    )
    figures["ray.batch.packed.mib"] = derived(
        "ray",
        lambda r: r["figures"]["batches"]["Atari rollout [128, 4], frames once"]["bytes"] / 2**20,
        "{:.2f}",
    )
    figures["ray.batch.cartpole.kib"] = derived(
        "ray", lambda r: r["figures"]["batches"]["CartPole rollout [32, 4]"]["bytes"] / 2**10, "{:.0f}"
    )
    figures["ray.publish.cnn.put_ms"] = bench(
        "ray", "publish: PPO Nature CNN (Atari)", col=ray_ms, fmt="{:.1f}"
    )
    figures["ray.publish.cnn.fetch_ms"] = bench(
        "ray", "publish: PPO Nature CNN (Atari)", col=queue_ms, fmt="{:.1f}"
    )
    figures["ray.publish.cnn.mib"] = derived(
        "ray", lambda r: r["figures"]["publishes"]["PPO Nature CNN (Atari)"]["bytes"] / 2**20, "{:.1f}"
    )
    figures["ray.actor.steps"] = derived(
        "ray", lambda r: r["figures"]["atari_actor"]["steps_per_second"], thousands
    )
    figures["ray.actor.batch_mib"] = derived(
        "ray", lambda r: r["figures"]["atari_actor"]["batch_bytes"] / 2**20, "{:.1f}"
    )
    figures["ray.actor.kib_per_step"] = derived(
        "ray", lambda r: r["figures"]["atari_actor"]["batch_bytes"] / 512 / 2**10, "{:.1f}"
    )

    # Atari (atari.json)
    envs = {
        "envpool": "EnvPool host API (`envpool.make`, 8 envs)",
        "xla": "EnvPool XLA (`XlaAtari.step` in a jitted 128-step `lax.scan`)",
        "agentax_envpool": "agentax `AtariEnv`, backend envpool",
        "agentax_ale": "agentax `AtariEnv`, backend ale",
    }
    for key, what in envs.items():
        figures[f"atari.envs.{key}"] = bench("atari", ATARI_ENVS, what, col="rate", fmt=si)
        figures[f"atari.envs.{key}.ratio"] = bench("atari", ATARI_ENVS, what, col="÷ reference", fmt="{:.3g}")
    agentax_step = (ATARI_STEP, "agentax `dqn.make_learn` (nature), jitted")
    figures["atari.step.agentax"] = bench("atari", *agentax_step, col="rate", fmt=si)
    figures["atari.step.ratio"] = bench("atari", *agentax_step, col="÷ reference", fmt="{:.2f}")
    figures["atari.step.bare"] = bench(
        "atari", ATARI_STEP, "bare JAX (flax + optax, jitted)", col="rate", fmt=si
    )
    uniform, prioritized = "`FrameReplayBuffer` 100k, uniform", "`FrameReplayBuffer` 100k, prioritized"
    figures["atari.replay.add"] = bench("atari", uniform, "add (8-env batches)", col="rate", fmt=si)
    figures["atari.replay.sample"] = bench("atari", uniform, "sample (batch 32)", col="rate", fmt=si)
    figures["atari.replay.prioritized"] = bench(
        "atari", prioritized, "sample + update_priorities", col="rate", fmt=si
    )
    figures["atari.replay.bytes"] = bench(
        "atari", uniform, "add (8-env batches)", col="bytes / transition", fmt=thousands
    )
    dqn_runners = {
        "sb3": "Stable-Baselines3 DQN (torch, 2 threads)",
        "host": "`agentax train dqn --runner host`",
        "parallel": "`agentax train dqn --runner parallel --actors 1`",
    }
    for key, what in dqn_runners.items():
        figures[f"atari.dqn.{key}"] = bench("atari", ATARI_DQN, what, col="rate", fmt=si)
        if key != "sb3":  # the reference
            figures[f"atari.dqn.{key}.ratio"] = bench(
                "atari", ATARI_DQN, what, col="÷ reference", fmt="{:.2f}"
            )
    for key, what in RUNNERS.items():
        for agent, group in (("ppo", ATARI_PPO), ("pqn", ATARI_PQN)):
            figures[f"atari.{agent}.{key}"] = bench("atari", group, what, col="rate", fmt=si)
            if (agent, key) != ("ppo", "host"):  # PPO's host runner is the reference
                figures[f"atari.{agent}.{key}.ratio"] = bench(
                    "atari", group, what, col="÷ reference", fmt="{:.2f}"
                )
            if key != "host":
                over_host = ratio("atari", (group, what), (group, RUNNERS["host"]), col="rate")
                figures[f"atari.{agent}.{key}.over_host"] = over_host

    # the same Atari rows on the AMD EPYC (atari@amd-epyc.json, beside the Xeon's atari.json)
    amd = "atari@amd-epyc"
    figures["atari.amd.cpu"] = cpu(amd)
    for key, what in dqn_runners.items():
        figures[f"atari.amd.dqn.{key}"] = bench(amd, ATARI_DQN, what, col="rate", fmt=si)
        if key != "sb3":
            figures[f"atari.amd.dqn.{key}.ratio"] = bench(
                amd, ATARI_DQN, what, col="÷ reference", fmt="{:.2f}"
            )
    measured_now = (("ppo", ATARI_PPO), ("pqn", ATARI_PQN), ("pqn15", ATARI_PQN15))
    for key, what in RUNNERS_NOW.items():
        for agent, group in measured_now:
            figures[f"atari.amd.{agent}.{key}"] = bench(amd, group, what, col="rate", fmt=si)
    for agent, group in measured_now:
        lag1, lag0 = (group, RUNNERS_NOW["compiled-lag1"]), (group, RUNNERS_NOW["compiled"])
        figures[f"atari.amd.{agent}.lag1_over_lag0"] = ratio(amd, lag1, lag0, col="rate")

    # the Atari learner (learner.json)
    ms = "ms per update"
    for conv in ("XLA f32", "oneDNN f32", "oneDNN bf16"):
        key = conv.lower().replace(" ", "_")
        figures[f"learner.{key}.every_cpu"] = bench(
            "learner", LEARNER, f"agentax, {conv}, XLA on every CPU (host, parallel)", col=ms, fmt="{:.1f}"
        )
        figures[f"learner.{key}.one_cpu"] = bench(
            "learner", LEARNER, f"agentax, {conv}, XLA on one CPU (compiled)", col=ms, fmt="{:.1f}"
        )
    amd = "learner@amd-epyc"  # the same update on the AMD EPYC, beside the Xeon's learner.json
    figures["learner.amd.cpu"] = cpu(amd)
    for conv in ("XLA f32", "oneDNN f32", "oneDNN bf16"):
        key = conv.lower().replace(" ", "_")
        figures[f"learner.amd.{key}.every_cpu"] = bench(
            amd, LEARNER, f"agentax, {conv}, XLA on every CPU (host, parallel)", col=ms, fmt="{:.1f}"
        )
    for key, what in (("torch_f32", "torch f32"), ("torch_bf16", "torch bf16 autocast")):
        figures[f"learner.amd.{key}"] = bench(amd, LEARNER, what, col=ms, fmt="{:.1f}")
    auto = "AGENTAX_CONV=auto's choice: agentax, oneDNN bf16, its own measure (one-cpu)"
    figures["learner.amd.auto"] = bench(amd, LEARNER, auto, col=ms, fmt="{:.1f}")
    figures["learner.torch_f32"] = bench("learner", LEARNER, "torch f32", col=ms, fmt="{:.1f}")
    figures["learner.torch_bf16"] = bench("learner", LEARNER, "torch bf16 autocast", col=ms, fmt="{:.1f}")
    figures["learner.xla_over_bf16"] = ratio(
        "learner",
        (LEARNER, "agentax, XLA f32, XLA on every CPU (host, parallel)"),
        (LEARNER, "agentax, oneDNN bf16, XLA on every CPU (host, parallel)"),
        col=ms,
        fmt="{:.1f}",
    )
    for key, what in (
        ("xla", "XLA f32, written out"),
        ("bf16", "oneDNN bf16, written out"),
        ("scan", "oneDNN bf16, lax.scan"),
    ):
        figures[f"learner.pqn.{key}.ms"] = bench(
            "learner", PQN_ITERATION, f"agentax, {what}", col=ms, fmt=thousands
        )
        figures[f"learner.pqn.{key}.compile"] = bench(
            "learner", PQN_ITERATION, f"agentax, {what}", col="compile s", fmt="{:.1f}"
        )

    # a trained policy exported and played from the file (export.json)
    for key in ("onnx", "stablehlo"):
        figures[f"export.{key}.bytes"] = bench("export", key, col="file bytes", fmt=thousands)
        figures[f"export.{key}.seconds"] = bench("export", key, col="export s", fmt="{:.2g}")
        mean = "file's mean return (100 episodes)"
        figures[f"export.{key}.mean"] = bench("export", key, col=mean, fmt="{:.1f}")
        figures[f"export.{key}.equal"] = bench("export", key, col="equal statistics")

    # memory: recurrent PPO on CartPoleNoVel (memory.json), beside SB3-Contrib and at PureJaxRL's settings
    figures["memory.cpu"] = cpu("memory")
    figures["memory_chain.cpu"] = cpu("memory_chain")
    chain_lstm = ("memory_chain", "PPO + LSTM 64")
    figures["memory_chain.steps"] = bench(*chain_lstm, col="env steps per seed", fmt=thousands)
    for key, agent in (("lstm", "PPO + LSTM 64"), ("ff", "PPO feed-forward")):
        figures[f"memory_chain.{key}.mean"] = bench("memory_chain", agent, col="eval mean", fmt="{:g}")
    figures["memory_chain.lstm.worst"] = bench(*chain_lstm, col="worst seed", fmt="{:g}")
    for key, agent in (("lstm", "PPO + LSTM 64"), ("gru", "PPO + GRU 64"), ("ff", "PPO feed-forward")):
        figures[f"memory.{key}.mean"] = bench("memory", agent, col="eval mean", fmt="{:.1f}")
        figures[f"memory.{key}.solved"] = bench("memory", agent, col="seeds ≥ 475")
        figures[f"memory.{key}.train"] = bench("memory", agent, col="train s", fmt=seconds_short)
    for key, index in (("agentax", 0), ("sb3", 1)):
        table = lambda r, i=index: r["beside_sb3"]["rows"][i]  # noqa: E731
        figures[f"memory.zoo.{key}.steps"] = derived("memory", lambda r, t=table: t(r)[1], thousands)
        figures[f"memory.zoo.{key}.seconds"] = derived("memory", lambda r, t=table: t(r)[2], "{:.0f}")
        figures[f"memory.zoo.{key}.mean"] = derived("memory", lambda r, t=table: t(r)[4], "{:.1f}")
    figures["memory.zoo.ratio"] = derived("memory", lambda r: r["beside_sb3"]["rows"][0][5], "{:.3f}")
    for index, seeds in enumerate((8, 64)):
        figures[f"memory.purejaxrl.{seeds}"] = derived(
            "memory", lambda r, i=index: r["purejaxrl_settings"]["rows"][i][1], thousands
        )

    # sweeps (sweep.json), workers (workers.json)
    for key, workload in (
        ("ppo", "PPO default, 100,352 env steps per agent"),
        ("dqn", "DQN default, 20,480 env steps per agent"),
    ):
        figures[f"sweep.{key}.one"] = bench("sweep", workload, col="1 agent (s)", fmt="{:.2f}")
        figures[f"sweep.{key}.all"] = bench("sweep", workload, col="64 agents, one program (s)", fmt="{:.1f}")
        figures[f"sweep.{key}.ratio"] = bench("sweep", workload, col="ratio", fmt="{:.1f}")
    for key, command in WORKERS.items():
        figures[f"workers.{key}.seconds"] = bench("workers", command, col="whole command (s)", fmt="{:.1f}")
    figures["workers.two.speedup"] = bench(
        "workers", WORKERS["two"], col="speed-up over one core", fmt="{:.2f}"
    )
    equal = "seeds whose final evaluation equals one process's"
    for key in ("one", "two"):
        figures[f"workers.{key}.equal"] = Figure(
            "benchmarks/results/workers.json", lambda r, c=WORKERS[key]: cell(r, c, col=equal)
        )

    # continuous control (sac.json, mujoco.json)
    vmapped = ("agentax compiled, 8 seeds vmapped (Pendulum-v1)", 8)  # sac.json: the AMD EPYC's rows
    figures["sac.vmapped.solved"] = bench("sac", *vmapped, col="final eval ≥ -200", fmt=of)
    figures["sac.process.seconds"] = bench("sac", SAC_PROCESS, 1, col="wall-clock s", fmt="{:.0f}")
    figures["sac.process.ratio"] = bench("sac", SAC_PROCESS, 1, col="wall-clock ÷ SB3's", fmt="{:.3g}")
    figures["sac.sb3.seconds"] = bench("sac", SAC_SB3, 1, col="wall-clock s", fmt="{:.0f}")
    for agent in ("SAC", "TD3"):
        key = agent.lower()
        figures[f"mujoco.{key}.host"] = bench(
            "mujoco", agent, "agentax, host runner", col="agent steps/s", fmt="{:.0f}"
        )
        figures[f"mujoco.{key}.host.ratio"] = bench(
            "mujoco", agent, "agentax, host runner", col="÷ SB3's", fmt="{:.2f}"
        )
        figures[f"mujoco.{key}.sb3"] = bench(
            "mujoco", agent, "Stable-Baselines3 (torch, 1 thread(s))", col="agent steps/s", fmt="{:.1f}"
        )

    # the same on the Xeon, with SBX, --precision auto and the compiled EnvPool runner (mujoco@intel-xeon)
    xeon = "mujoco@intel-xeon"
    figures["mujoco-xeon.cpu"] = cpu(xeon)
    figures["mujoco-xeon.sac.precision"] = bench(
        xeon, "SAC", "agentax, host runner, --precision auto", col="precision"
    )
    for agent in ("SAC", "TD3"):
        key = agent.lower()
        for runner in ("host", "parallel", "compiled"):
            row = (agent, f"agentax, {runner} runner, --precision auto")
            figures[f"mujoco-xeon.{key}.{runner}"] = bench(xeon, *row, col="agent steps/s", fmt="{:.0f}")
            figures[f"mujoco-xeon.{key}.{runner}.sbx"] = bench(xeon, *row, col="÷ SBX's", fmt="{:.2f}")
            learning = f"mujoco-xeon.{key}.{runner}.learning"  # steps 2,048-4,000, compilation outside
            figures[learning] = bench(xeon, *row, col="learning steps/s", fmt="{:.0f}")
            figures[f"{learning}.sbx"] = bench(xeon, *row, col="learning ÷ SBX's", fmt="{:.2f}")
            figures[f"{learning}.sb3"] = bench(xeon, *row, col="learning ÷ SB3's", fmt="{:.2f}")
        peers = {"f32": "agentax, host runner, --precision f32", "sbx": "SBX 0.28 (jax 0.10.2)"}
        for peer, label in peers.items():
            for column, name in (("agent steps/s", peer), ("learning steps/s", f"{peer}.learning")):
                figures[f"mujoco-xeon.{key}.{name}"] = bench(xeon, agent, label, col=column, fmt="{:.0f}")
        for column, name in (("agent steps/s", "sb3"), ("learning steps/s", "sb3.learning")):
            figures[f"mujoco-xeon.{key}.{name}"] = derived(  # its label names torch's thread count
                xeon, lambda r, a=agent, c=column: sb3_row(r, a)[r["headers"].index(c)], "{:.0f}"
            )
    figures["mujoco-xeon.sb3.threads"] = derived(xeon, lambda r: sb3_row(r, "SAC")[1].split(", ")[1][:-1])
    xeon = "sac@intel-xeon"  # the whole 8-seed command against SB3's one seed, on the Xeon
    seeds = ("`agentax train sac --env Pendulum-v1 --seeds 8 --precision auto` process", 8)
    figures["sac-xeon.cpu"] = cpu(xeon)
    figures["sac-xeon.seeds.solved"] = bench(xeon, *seeds, col="final eval ≥ -200", fmt=of)
    figures["sac-xeon.seeds.seconds"] = bench(xeon, *seeds, col="wall-clock s", fmt="{:.0f}")
    figures["sac-xeon.seeds.ratio"] = bench(xeon, *seeds, col="wall-clock ÷ SB3's", fmt="{:.2f}")
    figures["sac-xeon.seeds.how"] = bench(xeon, *seeds, col="precision, processes")
    figures["sac-xeon.sb3.seconds"] = bench(xeon, SAC_SB3, 1, col="wall-clock s", fmt="{:.0f}")

    # LunarLander-v3 (lunar.json): the RL Zoo's settings, and DQN's preset lunar
    for key, labels in LUNAR.items():
        figures[f"lunar.{key}.steps"] = bench("lunar", *labels, col="env steps", fmt=thousands)
        figures[f"lunar.{key}.mean"] = bench("lunar", *labels, col="eval mean", fmt=minus("{:.1f}"))
        figures[f"lunar.{key}.std"] = bench("lunar", *labels, col="eval std", fmt="{:.1f}")
    figures["lunar.sb3_full.cpu"] = evidence("lunar-sb3-rlzoo", "run.json", "cpu")
    for key in ("ppo", "dqn"):
        figures[f"lunar.{key}.train"] = bench("lunar", *LUNAR[key], col="train s", fmt="{:.0f}")
        full = functools.partial(evidence, "lunar-sb3-rlzoo", "sb3.json")
        figures[f"lunar.sb3_full.{key}.steps"] = full(f"{key}.steps", thousands)
        figures[f"lunar.sb3_full.{key}.seconds"] = full(f"{key}.seconds", "{:.0f}")
        figures[f"lunar.sb3_full.{key}.mean"] = full(f"{key}.mean", "{:.1f}")
        figures[f"lunar.sb3_full.{key}.std"] = full(f"{key}.std", "{:.1f}")
    for key in ("ppo", "dqn"):
        figures[f"lunar.{key}.ratio"] = bench("lunar", *LUNAR[key], col="agentax / SB3 steps/s", fmt="{:.2f}")
        figures[f"lunar.{key}.sb3_steps"] = bench("lunar", *LUNAR[key], col="SB3 env steps", fmt=thousands)

    # every core by default: where two workers start to pay (break_even.json)
    figures["break_even.cpu"] = cpu("break_even")
    for seeds, steps in ((64, 4_000), (64, 16_000), (64, 64_000), (8, 125_000)):
        run, key = f"--seeds {seeds} --total-steps {steps:,}", f"break_even.{seeds}x{steps // 1000}k"
        figures[f"{key}.one"] = bench("break_even", run, col="one process (s)", fmt="{:.1f}")
        figures[f"{key}.two"] = bench("break_even", run, col="2 workers (s)", fmt="{:.1f}")
        figures[f"{key}.speedup"] = bench("break_even", run, col="speed-up", fmt="{:.2f}")
    xeon = "break_even@intel-xeon"  # the same rows on the Xeon, with SAC's beside them
    figures["break_even.sac.cpu"] = cpu(xeon)
    for steps in (500, 2_000):
        run, key = f"sac Pendulum-v1 --seeds 8 --total-steps {steps:,}", f"break_even.sac.8x{steps}"
        figures[f"{key}.one"] = bench(xeon, run, col="one process (s)", fmt="{:.1f}")
        figures[f"{key}.two"] = bench(xeon, run, col="2 workers (s)", fmt="{:.1f}")
        figures[f"{key}.speedup"] = bench(xeon, run, col="speed-up", fmt="{:.2f}")

    # the Xeon's (rejax.json) and the Zen 3's
    for name, prefix in (("rejax", "rejax"), ("rejax@amd-epyc-no-avx512", "rejax.zen3")):
        figures[f"{prefix}.cpu"] = cpu(name)
        for i, key in enumerate(("agentax", "yaml", "min")):  # its rows: agentax, Rejax's yaml, its ends only
            figures[f"{prefix}.{key}.seconds"] = derived(name, lambda r, i=i: r["rows"][i][2], "{:.1f}")
            if key != "yaml":  # the same training as "min"
                figures[f"{prefix}.{key}.final"] = derived(name, lambda r, i=i: r["rows"][i][3], "{:.1f}")
            if key != "agentax":
                figures[f"{prefix}.{key}.ratio"] = derived(name, lambda r, i=i: r["rows"][i][4], "{:.2f}")

    figures["regress.cpu"] = cpu("regress")  # this checkout against an earlier commit, --precision f32
    figures["regress.against"] = derived("regress", lambda r: r["headers"][1].split()[0])
    for i, key in enumerate(("ppo", "dqn", "pqn")):  # its rows: PPO, DQN CartPole; PQN Breakout
        figures[f"regress.{key}.ratio"] = derived("regress", lambda r, i=i: r["rows"][i][3], "{:.3f}")

    # trained scores, each from its evidence folder: NAME.mean, .std, .episodes, .steps, .wall, .cpu
    for name in TRAINED:
        figures[f"{name}.mean"] = evidence(name, "eval.json", "mean_return", "{:,.1f}")
        figures[f"{name}.std"] = evidence(name, "eval.json", "std_return", "{:.1f}")
        figures[f"{name}.episodes"] = evidence(name, "eval.json", "episodes")
        figures[f"{name}.steps"] = evidence(name, "eval.json", "env_steps", thousands)
        figures[f"{name}.wall"] = evidence(name, "run.json", "wall_seconds", minutes)
        figures[f"{name}.cpu"] = evidence(name, "run.json", "cpu")
    # the Breakout runs: when the training games' true score passed 30 (or 100), the CPU share
    for breakout in (name for name in TRAINED if name.startswith("pqn-breakout")):
        for score in (30, 100) if breakout.endswith("100") else (30,):
            figures[f"{breakout}.passed{score}.time"] = passed(breakout, score, "wall_seconds", minutes)
            figures[f"{breakout}.passed{score}.steps"] = passed(breakout, score, "env_steps", thousands)
        figures[f"{breakout}.cpu_percent"] = evidence(breakout, "run.json", "cpu_percent")
    return figures


FIGURES = _figures()


def pages(root: Path) -> list[Path]:
    """The pages whose figures are bound: the README and every docs page."""
    return [root / "README.md", *sorted((root / "docs").rglob("*.md"))]


def values(root: Path, figures: dict[str, Figure] = FIGURES) -> dict[str, str]:
    """Every figure as its page prints it, read from its source under ``root`` (a source that cannot
    be read gives a value that says why, which no page shows)."""
    shown = {}
    for name, figure in figures.items():
        try:
            shown[name] = figure.show(root)
        except (OSError, LookupError, ValueError, TypeError) as error:
            shown[name] = f"<{figure.source} unreadable: {error}>"
    return shown


def problems(text: str, shown: dict[str, str], where: str = "") -> list[str]:
    """Each marked figure of ``text`` other than ``shown[name]``, each unknown name, each open marker."""
    found, line, counted = [], 1, 0
    for match in MARKER.finditer(text):
        name, printed = match.groups()
        line, counted = line + text.count("\n", counted, match.start()), match.start()  # since the last
        if name not in shown:
            found.append(f"{where}:{line}: fig:{name} is not a figure of scripts/figures.py")
        elif printed != shown[name]:
            found.append(f"{where}:{line}: fig:{name} shows {printed!r}, its source gives {shown[name]!r}")
    if len(OPENING.findall(text)) != len(CLOSING.findall(text)) or len(CLOSING.findall(text)) != len(
        MARKER.findall(text)
    ):
        found.append(
            f"{where}: a <!-- fig:NAME --> without its <!-- /fig --> on the same line, or one too many"
        )
    return found


def rewrite(text: str, shown: dict[str, str]) -> str:
    """``text`` with every marked figure of a known name printed from its source."""

    def figure(match: re.Match) -> str:
        name, printed = match.groups()
        return f"<!-- fig:{name} -->{shown.get(name, printed)}<!-- /fig -->"

    return MARKER.sub(figure, text)


def check(root: Path = ROOT, figures: dict[str, Figure] = FIGURES) -> list[str]:
    """Every problem of the pages under ``root``: figures off their sources, unknown, or shown nowhere."""
    shown = values(root, figures)
    found, used = [], set()
    for page in pages(root):
        text = page.read_text()
        found += problems(text, shown, str(page.relative_to(root)))
        used |= {match.group(1) for match in MARKER.finditer(text)}
    found += [f"fig:{name} is on no page (drop it from FIGURES)" for name in sorted(set(figures) - used)]
    return found


def write(root: Path = ROOT, figures: dict[str, Figure] = FIGURES) -> list[Path]:
    """Print every marked figure from its source; returns the pages that changed."""
    shown, changed = values(root, figures), []
    for page in pages(root):
        text = page.read_text()
        if (new := rewrite(text, shown)) != text:
            page.write_text(new)
            changed.append(page)
    return changed


def time_log(path: Path) -> dict:
    """The command (its program without the folder), wall-clock and (where it says) CPU share of a
    GNU ``/usr/bin/time -v`` log."""
    text = path.read_text()
    command = re.search(r'Command being timed: "(.*)"', text)
    clock = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", text)
    if not (command and clock):
        raise ValueError(f"{path} holds no /usr/bin/time -v report (Command being timed, Elapsed)")
    seconds = 0.0
    for part in clock.group(1).split(":"):
        seconds = seconds * 60 + float(part)
    program, _, rest = command.group(1).partition(" ")  # .venv/bin/agentax train ... -> agentax train ...
    timed = {"command": f"{Path(program).name} {rest}".strip(), "wall_seconds": round(seconds, 1)}
    share = re.search(r"Percent of CPU this job got: (\d+)%", text)
    return {**timed, "cpu_percent": int(share.group(1))} if share else timed


def make_evidence(
    run_dir: Path, name: str, command: str, wall_seconds: float, root: Path = ROOT, **timed: float
) -> Path:
    """``evidence/NAME/`` from a finished run folder, with the command, its wall-clock (and what
    else ``timed`` says: ``cpu_percent``) and this CPU."""
    missing = [file for file in ("config.json", "metrics.csv", "eval.json") if not (run_dir / file).is_file()]
    if missing:
        raise FileNotFoundError(f"{run_dir} lacks {', '.join(missing)}: not a finished run folder")
    out = root / "evidence" / name
    out.mkdir(parents=True, exist_ok=True)
    for file in EVIDENCE_FILES:
        if (run_dir / file).is_file():
            shutil.copy2(run_dir / file, out / file)
    describe = ["git", "describe", "--always", "--dirty", "--abbrev=12"]
    commit = subprocess.run(describe, cwd=root, capture_output=True, text=True).stdout.strip()
    record = {
        "command": command,
        "wall_seconds": wall_seconds,
        **timed,
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": commit,
        "cpu": HARNESS.cpu_info(),
    }
    (out / "run.json").write_text(json.dumps(record, indent=1) + "\n")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/figures.py", description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument(
        "--check", action="store_true", help="exit 1 if a figure differs from its source (default)"
    )
    mode.add_argument("--write", action="store_true", help="print every marked figure from its source")
    mode.add_argument("--list", action="store_true", help="every figure, its value and its source")
    mode.add_argument(
        "--evidence", type=Path, metavar="RUN_DIR", help="make evidence/NAME/ from a run folder"
    )
    parser.add_argument("--name", help="--evidence: the folder's name under evidence/")
    parser.add_argument("--time-log", type=Path, help="--evidence: the /usr/bin/time -v log of the command")
    parser.add_argument("--root", type=Path, default=ROOT, help="the repository (default: this one)")
    args = parser.parse_args(argv)
    if args.evidence:
        if not (args.name and args.time_log):
            parser.error("--evidence needs --name and --time-log")
        timed = time_log(args.time_log)
        folder = make_evidence(args.evidence, args.name, root=args.root, **timed)
        print(f"wrote {folder}")
        return 0
    if args.list:
        for name, shown in values(args.root).items():
            print(f"{name}\t{shown}\t{FIGURES[name].source}")
        return 0
    if args.write:
        for page in write(args.root):
            print(f"wrote {page.relative_to(args.root)}")
    found = check(args.root)
    print("\n".join(found) if found else f"{len(FIGURES)} figures, every one as its source gives it")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
