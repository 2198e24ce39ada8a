"""``agentax search``: policy search for the vacuum robot's (p, r) or a neural CartPole policy.

    agentax search vacuum --method grid|random [--out DIR] [--seed S]
    agentax search cartpole --env CartPole-v0|CartPole-v1 --method ga|cem [--seeds N] [--population N]
                            [--generations N] [--out DIR]

The run folder (default ``runs/search-<method>-<env>-<YYYYmmdd-HHMMSS>``) holds ``config.json``,
``metrics.csv``, ``curve.png``, ``eval.json`` (the best policy on fresh episodes) and the best
parameters (``best_params.msgpack``), plus ``heatmap.png`` and ``path.png`` (one episode of the best
setting) for the vacuum. ``agentax play --policy DIR`` and ``agentax evaluate --policy DIR`` load the best
policy through the module config.json names.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import io
import pathlib
import sys
import time
from dataclasses import dataclass
from functools import partial
from typing import Any

import imageio.v3 as imageio
import jax
import numpy as np
import tyro
from flax import serialization

from agentax.envs.core import episode_returns
from agentax.envs.vacuum import Vacuum, render_path
from agentax.errors import UsageError
from agentax.runs import write_atomic, write_json
from agentax.search import METHODS, NEURAL_METHODS, VACUUM_METHODS, cem, genetic
from agentax.search.grid import GridSearchConfig, grid_search
from agentax.search.population import (
    FlatPolicy,
    NetConfig,
    make_env,
    make_fitness,
    run_generations,
    select_final,
)
from agentax.search.random_search import RandomSearchConfig, random_search
from agentax.search.settings import plot_heatmap, vacuum_policy

TARGETS = ("vacuum", "cartpole")
# Episode streams: the search uses jax.random.key(seed + k) for seed k; the final selection and the fresh
# evaluation fold these numbers into jax.random.key(seed), so no two of them share episodes.
SELECTION_STREAM, EVAL_STREAM = 2, 1


@dataclass(frozen=True)
class VacuumArgs:
    """Grid or random search over the vacuum robot's (p, r)."""

    method: str = "grid"
    """grid (a regular p × r grid) or random (uniform settings)."""
    out: pathlib.Path | None = None
    """Run folder (default runs/search-<method>-Vacuum-v0-<time>)."""
    seed: int = 0
    """Seed of the search and of the fresh evaluation episodes."""
    grid_size: int = 41
    """grid: values of p and of r (grid_size² settings); random: grid_size² settings drawn."""
    episodes: int = 4
    """Episodes per setting in the search."""
    eval_episodes: int = 100
    """Fresh episodes of the best setting for its mean and 95 % confidence interval."""


@dataclass(frozen=True)
class CartPoleArgs:
    """A genetic algorithm or the cross-entropy method over a neural policy's parameters."""

    env: str = "CartPole-v1"
    """CartPole-v0 or CartPole-v1 (any JAX env with vector observations and discrete actions)."""
    method: str = "ga"
    """ga (genetic algorithm) or cem (cross-entropy method)."""
    seeds: int = 1
    """Independent searches, run side by side (vmapped)."""
    seed: int = 0
    """First seed; the searches use seed, seed + 1, ..."""
    population: int = 64
    """Candidates per generation."""
    generations: int = 20
    """Generations (CEM iterations) at most."""
    episodes: int = 5
    """Episodes per fitness evaluation."""
    mutation_scale: float | None = None
    """GA: std of the Gaussian mutation (default 0.3); CEM: std of the extra noise (default 0.3)."""
    elite_fraction: float | None = None
    """Fraction of elites (default GA 0.1, CEM 0.2)."""
    hidden: tuple[int, ...] = (5,)
    """Hidden layer widths of the policy network (the lecture's: one layer of 5)."""
    target: float | None = None
    """Stop early once every seed's best fitness reaches this (default: run all generations)."""
    eval_episodes: int = 100
    """Fresh episodes for the final evaluation of the best policy."""
    out: pathlib.Path | None = None
    """Run folder (default runs/search-<method>-<env>-<time>)."""


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(f"usage: agentax search {{{','.join(TARGETS)}}} [ARGS]  (agentax search TARGET --help)")
        return 0
    target, rest = argv[0], argv[1:]
    if target == "vacuum":
        args = tyro.cli(VacuumArgs, args=rest, prog="agentax search vacuum")
        return search_vacuum(args)
    if target == "cartpole":
        args = tyro.cli(CartPoleArgs, args=rest, prog="agentax search cartpole")
        return search_cartpole(args)
    raise UsageError(f"unknown search target {target!r}; choose from {', '.join(TARGETS)}")


def run_folder(out: pathlib.Path | None, method: str, env_id: str) -> pathlib.Path:
    if out is None:
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        out = pathlib.Path("runs") / f"search-{method}-{env_id}-{stamp}"
    out = pathlib.Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file; give a folder")
    out.mkdir(parents=True, exist_ok=True)
    return out


def write_csv(path: pathlib.Path, rows: list[dict]) -> None:
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    write_atomic(path, text.getvalue().encode())


def search_vacuum(args: VacuumArgs) -> int:
    if args.method not in VACUUM_METHODS:
        raise UsageError(
            f"unknown method {args.method!r} for the vacuum; choose from {', '.join(VACUUM_METHODS)}"
        )
    if args.grid_size < 1:
        raise UsageError(f"grid size must be >= 1, got {args.grid_size}")
    if args.method == "grid":
        config = GridSearchConfig(args.grid_size, args.grid_size, num_episodes=args.episodes,
                                  final_episodes=args.eval_episodes)  # fmt: skip
    else:
        config = RandomSearchConfig(
            args.grid_size**2, num_episodes=args.episodes, final_episodes=args.eval_episodes
        )
    out = run_folder(args.out, args.method, "Vacuum-v0")
    write_json(
        out / "config.json",
        {"algo": args.method, "module": METHODS[args.method], "env": "Vacuum-v0", "seed": args.seed,
         **dataclasses.asdict(config)},
    )  # fmt: skip
    num_settings = args.grid_size**2
    print(f"evaluating {num_settings} (p, r) settings × {args.episodes} episodes of 30 simulated minutes ...")
    start = time.perf_counter()
    search = grid_search if args.method == "grid" else random_search
    result = search(config, seed=args.seed)
    seconds = time.perf_counter() - start

    means, stds = result.mean_returns, result.returns.std(axis=1)
    best_so_far = np.maximum.accumulate(means)
    write_csv(
        out / "metrics.csv",
        [
            {"setting": i, "p": float(result.p[i]), "r": float(result.r[i]), "mean_return": float(means[i]),
             "std_return": float(stds[i]), "best_mean_so_far": float(best_so_far[i])}
            for i in range(means.size)
        ],
    )  # fmt: skip
    plot_heatmap(result, out / "heatmap.png")
    # One episode of the best setting drawn over the room, like the lecture's illustration.
    path_key = jax.random.fold_in(jax.random.key(args.seed), EVAL_STREAM)
    states, _ = Vacuum().trajectory(vacuum_policy(result.best_p, result.best_r), path_key)
    imageio.imwrite(out / "path.png", render_path(states))
    _plot_curve(
        out / "curve.png",
        np.arange(1, means.size + 1),
        {"best mean dust so far": best_so_far[None]},
        "settings evaluated",
        "mean dust collected",
        f"{args.method} search over (p, r)",
    )
    summary = result.summary() | {"seconds": seconds}
    best = {"p": np.float32(result.best_p), "r": np.float32(result.best_r)}
    write_atomic(out / "best_params.msgpack", serialization.to_bytes(best))
    write_json(out / "eval.json", summary)
    lo, hi = result.ci95
    print(
        f"best p = {result.best_p:.3f}, r = {result.best_r:.3f}: {summary['mean_return']:.1f} dust on "
        f"{summary['episodes']} fresh episodes (95 % CI {lo:.1f} to {hi:.1f}); "
        f"search and evaluation took {seconds:.1f} s, compilation included"
    )
    print(f"run folder: {out}")
    return 0


def _population_search(args: CartPoleArgs, net: NetConfig) -> tuple[Any, Any]:
    """``(module, config)``: the genetic algorithm or the cross-entropy method as the flags set it."""
    common = dict(
        population_size=args.population, generations=args.generations, num_episodes=args.episodes, net=net
    )
    if args.elite_fraction is not None:
        common["elite_fraction"] = args.elite_fraction
    if args.method == "ga":
        scale = {} if args.mutation_scale is None else {"mutation_scale": args.mutation_scale}
        return genetic, genetic.GAConfig(**common, **scale)
    scale = {} if args.mutation_scale is None else {"extra_noise": args.mutation_scale}
    return cem, cem.CEMConfig(**common, **scale)


def search_cartpole(args: CartPoleArgs) -> int:
    if args.method not in NEURAL_METHODS:
        raise UsageError(f"unknown method {args.method!r}; choose from {', '.join(NEURAL_METHODS)}")
    for name in ("seeds", "eval_episodes"):
        if getattr(args, name) < 1:
            raise UsageError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    net = NetConfig(hidden=tuple(args.hidden))
    env = make_env(args.env, net)
    algorithm, config = _population_search(args, net)
    out = run_folder(args.out, args.method, env.id)
    write_json(
        out / "config.json",
        {"algo": args.method, "module": METHODS[args.method], "env": env.id, "seed": args.seed,
         "seeds": args.seeds, "eval_episodes": args.eval_episodes, **dataclasses.asdict(config)},
    )  # fmt: skip

    flat = FlatPolicy.create(env, net)
    fitness = make_fitness(env, flat, config.num_episodes, greedy=not config.sample_actions)
    keys = jax.vmap(jax.random.key)(np.arange(args.seed, args.seed + args.seeds))
    rows: list[dict] = []
    start = time.perf_counter()
    with _progress() as progress:
        task = progress.add_task("compiling", total=config.generations)

        def on_generation(generation: int, metrics: dict) -> bool:
            env_steps = (rows[-1]["env_steps"] if rows else 0) + float(metrics["env_steps"].mean())
            best, mean = metrics["best_fitness"], metrics["mean_fitness"]
            row = dict(
                generation=generation + 1,
                env_steps=int(env_steps),
                best_fitness=float(best.mean()),
                mean_fitness=float(mean.mean()),
                best_fitness_min=float(best.min()),
                best_fitness_max=float(best.max()),
                seconds=round(time.perf_counter() - start, 3),
            )
            row |= {f"return_seed{k}": float(value) for k, value in enumerate(best)}  # for agentax plot
            rows.append(row)
            description = f"generation {row['generation']}  best {row['best_fitness']:7.1f}"
            progress.update(task, advance=1, description=f"{description}  mean {row['mean_fitness']:7.1f}")
            return args.target is not None and bool(np.all(best >= args.target))

        state = run_generations(
            partial(algorithm.init, num_params=flat.num_params, config=config),
            partial(algorithm.step, fitness_fn=fitness, config=config),
            keys,
            config.generations,
            on_generation,
        )
    seconds = time.perf_counter() - start
    write_csv(out / "metrics.csv", rows)
    generations = np.array([row["generation"] for row in rows])
    _plot_curve(
        out / "curve.png",
        generations,
        {"best fitness": np.array([[row["best_fitness"] for row in rows]]),
         "mean fitness": np.array([[row["mean_fitness"] for row in rows]])},
        "generation",
        f"mean return over {config.num_episodes} episodes",
        f"{args.method.upper()} on {env.id} ({args.seeds} seed{'s' * (args.seeds > 1)}, mean over seeds)",
        threshold=getattr(env, "reward_threshold", None),
        spread={"best fitness": (np.array([row["best_fitness_min"] for row in rows]),
                                 np.array([row["best_fitness_max"] for row in rows]))},
    )  # fmt: skip
    selection_key = jax.random.fold_in(jax.random.key(args.seed), SELECTION_STREAM)
    selection_fitness = make_fitness(env, flat, config.selection_episodes, greedy=not config.sample_actions)
    best_params, selection_scores = select_final(
        algorithm.candidates, state, selection_fitness, selection_key
    )
    summary = _evaluate_best(env, flat, best_params, selection_scores, args, seconds, int(generations[-1]))
    write_json(out / "eval.json", summary)
    best = np.asarray(best_params[summary["seed"] - args.seed], np.float32)
    write_atomic(out / "best_params.msgpack", serialization.to_bytes(best))
    print(
        "best policy (seed {seed}): return {mean_return:.1f} ± {std_return:.1f}, {episodes} fresh episodes "
        "(min {min_return:.0f}, max {max_return:.0f}); {generations} generations in {seconds:.1f} s".format(
            **summary
        )
    )
    print(f"run folder: {out}")
    return 0


def _evaluate_best(
    env, flat, best_params, selection_scores, args: CartPoleArgs, seconds, generations
) -> dict:
    """Every seed's selected policy on ``eval_episodes`` fresh episodes; the summary of the best seed
    (chosen by its selection score, not by the fresh episodes), and every seed's under ``per_seed``.
    """
    key = jax.random.fold_in(jax.random.key(args.seed), EVAL_STREAM)
    returns = jax.jit(
        jax.vmap(lambda theta: episode_returns(env, flat.policy(theta), key, args.eval_episodes)[0])
    )(best_params)
    returns = np.asarray(returns, np.float64)  # [seeds, eval_episodes]
    best = int(np.argmax(np.asarray(selection_scores)))
    stats = [
        {"seed": args.seed + i, "mean_return": float(r.mean()), "std_return": float(r.std()),
         "min_return": float(r.min()), "max_return": float(r.max()), "episodes": int(r.size)}
        for i, r in enumerate(returns)
    ]  # fmt: skip
    return stats[best] | {
        "generations": generations,
        "seconds": round(seconds, 3),
        "mean_return_over_seeds": float(returns.mean()),
        "per_seed": stats,
    }


def _progress():
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        transient=not sys.stderr.isatty(),
    )  # fmt: skip


def _plot_curve(path, x, series, xlabel, ylabel, title, threshold=None, spread=None) -> None:
    """Lines of ``series`` (name -> ``[1, len(x)]``) against ``x``, optional min-max bands and a threshold."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6.4, 4.0))
    for name, values in series.items():
        (line,) = axes.plot(x, values[0], label=name)
        if spread and name in spread:
            axes.fill_between(x, *spread[name], color=line.get_color(), alpha=0.2, linewidth=0)
    if threshold is not None:
        axes.axhline(threshold, color="grey", linestyle="--", linewidth=1, label=f"solved ({threshold:g})")
    axes.set_xlabel(xlabel)
    axes.set_ylabel(ylabel)
    axes.set_title(title, fontsize=10)
    axes.legend(loc="lower right")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
