"""``agentax solve``: a tabular MDP solved by planning (value / Q-value iteration) or learned from
samples (TD(0), Q-learning, SARSA); prints V or the Q table and the greedy actions, or one JSON object.

``--plot out.png`` draws the lecture's comparison: the error to Q* of Q-value iteration against
iterations beside that of Q-learning (or SARSA) against environment steps.

The learners accept a discount factor of 1 on any MDP (the episode cap ends every episode); planning
only where every policy terminates. Sutton & Barto's Example 6.6 (cliff walking)::

    agentax solve --mdp cliffwalking --method sarsa --discount-factor 1 --epsilon 0.1 --learning-rate 0.5
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import tyro
from rich.console import Console
from rich.table import Table

from agentax.envs.mdp import (
    MDP,
    chain_mdp,
    check_discount_factor,
    cliffwalking,
    frozenlake,
    lecture_mdp,
    taxi,
)
from agentax.errors import UsageError
from agentax.tabular import (
    QLearningConfig,
    TDConfig,
    episode_returns,
    greedy_policy,
    q_backup,
    q_learning,
    q_value_iterates,
    q_value_iteration,
    td_learning,
    value_iteration,
)

MDPS: dict[str, Callable[[], MDP]] = {
    "lecture": lecture_mdp,
    "frozenlake4x4": lambda: frozenlake("4x4"),
    "frozenlake8x8": lambda: frozenlake("8x8", sparse=True),
    "taxi": lambda: taxi(sparse=True),
    "cliffwalking": lambda: cliffwalking(sparse=True),
    "chain": lambda: chain_mdp(10),
}
METHODS = ("value-iteration", "q-value-iteration", "td", "q-learning", "sarsa")
PLANNING_METHODS = ("value-iteration", "q-value-iteration")
MAX_TABLE_ROWS = 64


@dataclass(frozen=True)
class SolveArgs:
    """Solve a tabular MDP and print V or Q with the greedy actions."""

    mdp: str = "lecture"
    """lecture, frozenlake4x4, frozenlake8x8, taxi, cliffwalking or chain (reward at the far end)"""
    method: str = "q-value-iteration"
    """value-iteration, q-value-iteration, td (V of the random policy), q-learning or sarsa"""
    discount_factor: float = 0.9
    """γ in [0, 1]; 1 for the learners on any MDP (the episode cap ends every episode), for
    planning only where every policy terminates"""
    steps: int = 10_000
    """environment steps for td, q-learning and sarsa"""
    epsilon: float | None = None
    """a constant ε for q-learning and sarsa (default: the book's, 1 for q-learning, 1 → 0.05 for sarsa)"""
    learning_rate: float | None = None
    """a constant α for the learners (default: the book's decaying α_t = 0.05 / (1 + 0.005 t))"""
    seed: int = 0
    """random seed of the sampled transitions"""
    json: bool = False
    """print one JSON object (V or Q with null for −inf, and policy) instead of tables"""
    plot: str | None = None
    """write a PNG: error to Q* of Q-value iteration (per iteration) and of Q-learning (per step)"""


def log_interval(steps: int) -> int:
    """The largest divisor of ``steps`` that still leaves ``min(100, steps)`` snapshots."""
    return next(d for d in range(steps // min(100, steps), 0, -1) if steps % d == 0)


def learning_rate_fields(args: SolveArgs) -> dict:
    if args.learning_rate is None:
        return {}
    return {"learning_rate": args.learning_rate, "learning_rate_decay": 0.0}


def learner_config(method: str, args: SolveArgs) -> QLearningConfig:
    """The book's settings; SARSA learns the Q of the policy it follows, so its ε decays 1 → 0.05.
    ``--epsilon`` and ``--learning-rate`` replace them by constants (Sutton & Barto's)."""
    common = {
        "discount_factor": args.discount_factor,
        "algorithm": method,
        "num_steps": args.steps,
        "log_interval": log_interval(args.steps),
        **learning_rate_fields(args),
    }
    if args.epsilon is not None:
        return QLearningConfig(epsilon_start=args.epsilon, **common)
    if method == "sarsa":
        return QLearningConfig(
            epsilon_schedule="linear", epsilon_end=0.05, epsilon_decay_steps=float(args.steps), **common
        )
    return QLearningConfig(**common)


def to_json_table(values: np.ndarray) -> list:
    """Nested lists with ``None`` where a value is −inf (impossible actions)."""
    return np.where(np.isfinite(values), values, None).tolist()


def q_error(mdp: MDP, q_values: np.ndarray, q_star: np.ndarray) -> np.ndarray:
    """``max_{s, a} |Q − Q*|`` over possible actions, for ``q_values [..., S, A]``."""
    mask = np.asarray(mdp.possible_actions)
    return np.abs(np.where(mask, q_values - np.where(mask, q_star, 0.0), 0.0)).max((-1, -2))


def solve(mdp: MDP, args: SolveArgs) -> dict:
    """Run the method; return the JSON-ready result."""
    result: dict = {"mdp": args.mdp, "method": args.method, "discount_factor": args.discount_factor}
    key = jax.random.key(args.seed)
    if args.method in ("value-iteration", "td"):
        if args.method == "value-iteration":
            planned = value_iteration(mdp, args.discount_factor)
            values, result["iterations"] = planned.values, int(planned.num_iterations)
        else:
            config = TDConfig(
                discount_factor=args.discount_factor,
                num_steps=args.steps,
                log_interval=log_interval(args.steps),
                **learning_rate_fields(args),
            )
            learned = td_learning(key, mdp, config)
            values, result["steps"] = learned.values, args.steps
            result.update(online_returns(learned))
        result["V"] = np.asarray(values).tolist()
        # V alone picks no action: act greedily on the one-step lookahead through the model.
        result["policy"] = np.asarray(greedy_policy(q_backup(mdp, values, args.discount_factor))).tolist()
        return result
    if args.method == "q-value-iteration":
        planned = q_value_iteration(mdp, args.discount_factor)
        q_values, result["iterations"] = planned.values, int(planned.num_iterations)
    else:
        learned = q_learning(key, mdp, learner_config(args.method, args))
        q_values, result["steps"] = learned.q_values, args.steps
        result.update(online_returns(learned))
    result["Q"] = to_json_table(np.asarray(q_values))
    result["policy"] = np.asarray(greedy_policy(q_values)).tolist()
    return result


def online_returns(learned) -> dict:
    """The episodes a learner completed and their mean undiscounted return, over all and the last 100."""
    returns = episode_returns(learned.rewards, learned.episode_ends)
    if len(returns) == 0:
        return {"episodes": 0}
    return {
        "episodes": len(returns),
        "mean_return": float(returns.mean()),
        "mean_return_last_100": float(returns[-100:].mean()),
    }


def print_tables(mdp: MDP, result: dict) -> None:
    console = Console()
    how = f"{result['iterations']} iterations" if "iterations" in result else f"{result['steps']} steps"
    table = Table(
        title=f"{result['method']} on {result['mdp']}",
        caption=f"discount factor {result['discount_factor']}, {how}",
    )
    table.add_column("state", justify="right")
    if "Q" in result:
        for a in range(mdp.num_actions):
            table.add_column(f"Q(s, {a})", justify="right")
    else:
        table.add_column("V(s)", justify="right")
    table.add_column("best action", justify="right")
    rows = result["Q"] if "Q" in result else [[v] for v in result["V"]]
    terminal = np.asarray(mdp.terminal)
    for s, row in enumerate(rows[:MAX_TABLE_ROWS]):
        cells = ["-inf" if v is None else f"{v:.2f}" for v in row]
        best = "terminal" if terminal[s] else str(result["policy"][s])
        table.add_row(str(s), *cells, best)
    console.print(table)
    if len(rows) > MAX_TABLE_ROWS:
        console.print(f"({len(rows) - MAX_TABLE_ROWS} more states; --json prints them all)")
    console.print(f"optimal actions: {result['policy'] if len(rows) <= MAX_TABLE_ROWS else '(see --json)'}")
    if result.get("episodes"):
        console.print(
            f"online return: {result['mean_return_last_100']:.2f} per episode over the last "
            f"{min(100, result['episodes'])} of {result['episodes']} episodes "
            f"({result['mean_return']:.2f} over all)"
        )


def plot(mdp: MDP, args: SolveArgs, path: str) -> None:
    """Error to Q* of Q-value iteration (per iteration) beside the learner's (per step)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    planned = q_value_iteration(mdp, args.discount_factor)
    q_star = np.asarray(planned.values)
    num_iterations = max(int(planned.num_iterations), 2)
    iterates = np.asarray(q_value_iterates(mdp, jnp.float32(args.discount_factor), num_iterations))
    method = args.method if args.method == "sarsa" else "q-learning"
    learned = q_learning(jax.random.key(args.seed), mdp, learner_config(method, args))
    steps = np.arange(1, learned.q_history.shape[0] + 1) * log_interval(args.steps)
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.plot(np.arange(1, num_iterations + 1), q_error(mdp, iterates, q_star), marker=".")
    left.set(
        title="Q-value iteration (model known)", xlabel="iterations", ylabel="max |Q − Q*|", yscale="log"
    )
    right.plot(steps, q_error(mdp, np.asarray(learned.q_history), q_star))
    right.set(
        title=f"{method} (model unknown)", xlabel="environment steps", ylabel="max |Q − Q*|", yscale="log"
    )
    figure.suptitle(f"{args.mdp}, discount factor {args.discount_factor}")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def main(argv: list[str]) -> int:
    args = tyro.cli(SolveArgs, args=argv, prog="agentax solve")
    if args.mdp not in MDPS:
        raise UsageError(f"unknown MDP {args.mdp!r}; choose from {', '.join(MDPS)}")
    if args.method not in METHODS:
        raise UsageError(f"unknown method {args.method!r}; choose from {', '.join(METHODS)}")
    if not math.isfinite(args.discount_factor):
        raise UsageError(f"discount factor {args.discount_factor} is not a number in [0, 1]")
    if args.steps < 1:
        raise UsageError(f"--steps must be at least 1, not {args.steps}")
    if args.epsilon is not None and not 0.0 <= args.epsilon <= 1.0:
        raise UsageError(f"--epsilon must be in [0, 1], not {args.epsilon}")
    if args.learning_rate is not None and not args.learning_rate > 0.0:
        raise UsageError(f"--learning-rate must be positive, not {args.learning_rate}")
    mdp = MDPS[args.mdp]()
    if args.method in PLANNING_METHODS or args.plot:  # --plot plans too, for Q*
        try:
            check_discount_factor(mdp, args.discount_factor)
        except UsageError as error:
            if args.discount_factor != 1.0 or args.method in PLANNING_METHODS:
                raise
            raise UsageError(
                f"{error} (--plot plans Q* by Q-value iteration; without it {args.method} "
                "learns at discount factor 1)"
            ) from None
    elif not 0.0 <= args.discount_factor <= 1.0:
        raise UsageError(f"discount factor {args.discount_factor} is outside [0, 1]")
    result = solve(mdp, args)
    if args.plot:
        plot(mdp, args, args.plot)
        result["plot"] = args.plot
    if args.json:
        print(json.dumps(result))
    else:
        print_tables(mdp, result)
        if args.plot:
            Console().print(f"wrote {args.plot}")
    return 0
