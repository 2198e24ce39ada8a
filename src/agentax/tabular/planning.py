"""Planning with a known model: value iteration and Q-value iteration (Bellman, lecture eqs. 18.2-18.3).

Both start from zero and apply the Bellman optimality backup inside one ``lax.while_loop`` until the
Bellman residual ``max |X_{k+1} − X_k|`` drops below ``tol`` (a fixed iteration count is not
converged for discount factors near 1). They take a dense :class:`~agentax.envs.mdp.TabularMDP` or
a :class:`~agentax.envs.mdp.SparseMDP` alike: the backup only asks the MDP for its expected rewards
and expected next-state values. Terminal states are worth 0; impossible actions get Q = −inf.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.envs.mdp import MDP, check_discount_factor
from agentax.errors import UsageError

Array = jax.Array


@struct.dataclass
class PlanningResult:
    """What value iteration and Q-value iteration return."""

    values: Array  # V* [S], or Q* [S, A] with −inf for impossible actions
    residuals: Array  # [max_iterations]: the Bellman residual of each iteration, NaN after the last
    num_iterations: Array  # int32 []: iterations run
    converged: Array  # bool []: the last residual is below tol

    def residual_history(self) -> np.ndarray:
        """The residuals of the iterations that ran, ``[num_iterations]``."""
        return np.asarray(self.residuals)[: int(self.num_iterations)]


def q_backup(mdp: MDP, values: Array, discount_factor: Array, expected_rewards: Array | None = None) -> Array:
    """``Q(s, a) = Σ_s' T(s, a, s') [R(s, a, s') + γ V(s')]`` with ``V = 0`` at terminal states:
    ``[S, A]``, 0 in terminal states, −inf for impossible actions. Loops pass ``expected_rewards``
    (``mdp.expected_rewards()``, ``[S, A]``) computed once, so an iteration reads the table once."""
    expected_rewards = mdp.expected_rewards() if expected_rewards is None else expected_rewards
    next_values = jnp.where(mdp.terminal, 0.0, values)
    q_values = expected_rewards + discount_factor * mdp.expected_next_values(next_values)
    q_values = jnp.where(mdp.terminal[:, None], 0.0, q_values)
    return jnp.where(mdp.possible_actions, q_values, -jnp.inf)


def state_values(mdp: MDP, q_values: Array) -> Array:
    """``V(s) = max_a Q(s, a)`` over possible actions, 0 at terminal states: ``[S]``."""
    return jnp.where(mdp.terminal, 0.0, jnp.max(q_values, -1))


def greedy_policy(q_values: Array) -> Array:
    """The action with the highest Q-value in each state, ``[S]`` int32 (impossible actions are −inf)."""
    return jnp.argmax(q_values, -1).astype(jnp.int32)


def _iterate(backup, initial: Array, tol: Array, max_iterations: int, gap=None) -> PlanningResult:
    """Apply ``backup`` from ``initial`` until ``gap`` is below ``tol`` or ``max_iterations``.

    The residual ``max |X_{k+1} − X_k|`` (over finite entries) is recorded every iteration; ``gap``
    maps ``(X_k, X_{k+1}, residual)`` to the stopping quantity (default: the residual itself).
    """
    gap = (lambda values, new_values, residual: residual) if gap is None else gap

    def cond(carry):
        _, _, _, iteration, last_gap = carry
        return (iteration < max_iterations) & (last_gap >= tol)

    def body(carry):
        values, _, residuals, iteration, _ = carry
        new_values = backup(values)
        finite = jnp.isfinite(new_values)
        residual = jnp.max(jnp.where(finite, jnp.abs(new_values - jnp.where(finite, values, 0.0)), 0.0))
        residuals = residuals.at[iteration].set(residual)
        return new_values, values, residuals, iteration + 1, gap(values, new_values, residual)

    residuals = jnp.full((max_iterations,), jnp.nan, jnp.float32)
    carry = (initial, initial, residuals, jnp.int32(0), jnp.float32(jnp.inf))
    values, previous, residuals, iterations, last_gap = jax.lax.while_loop(cond, body, carry)
    return PlanningResult(values, residuals, iterations, last_gap < tol), previous


@partial(jax.jit, static_argnames=("max_iterations", "error_bounds"))
def _value_iteration(
    mdp: MDP, discount_factor: Array, tol: Array, max_iterations: int, error_bounds: bool = False
) -> PlanningResult:
    rewards = mdp.expected_rewards()
    backup = lambda values: state_values(mdp, q_backup(mdp, values, discount_factor, rewards))
    initial = jnp.zeros(mdp.num_states, jnp.float32)
    if not error_bounds:
        return _iterate(backup, initial, tol, max_iterations)[0]
    # MacQueen's bounds: V_{k+1} + c·min ΔV <= V* <= V_{k+1} + c·max ΔV with c = γ / (1 − γ) and
    # ΔV = V_{k+1} − V_k. Terminal states keep ΔV = 0 in the min and max, which keeps the bounds
    # valid when some probability mass leaves through them.
    scale = discount_factor / (1.0 - discount_factor)
    width = lambda values, new_values, residual: (
        scale * (jnp.max(new_values - values) - jnp.min(new_values - values)) / 2
    )
    result, previous = _iterate(backup, initial, tol, max_iterations, width)
    delta = result.values - previous
    midpoint = result.values + scale * (jnp.max(delta) + jnp.min(delta)) / 2
    return result.replace(values=jnp.where(mdp.terminal, 0.0, midpoint))


@partial(jax.jit, static_argnames="max_iterations")
def _q_value_iteration(mdp: MDP, discount_factor: Array, tol: Array, max_iterations: int) -> PlanningResult:
    rewards = mdp.expected_rewards()
    backup = lambda q_values: q_backup(mdp, state_values(mdp, q_values), discount_factor, rewards)
    initial = jnp.where(mdp.possible_actions, 0.0, -jnp.inf).astype(jnp.float32)
    return _iterate(backup, initial, tol, max_iterations)[0]


def _check(mdp: MDP, discount_factor: float, tol: float, max_iterations: int) -> None:
    if not isinstance(discount_factor, jax.core.Tracer):
        check_discount_factor(mdp, discount_factor)
    if max_iterations < 1:
        raise UsageError(f"max_iterations must be at least 1, got {max_iterations}")
    if not tol > 0:
        raise UsageError(f"tol must be positive, got {tol}")


def value_iteration(
    mdp: MDP,
    discount_factor: float = 0.9,
    tol: float = 1e-6,
    max_iterations: int = 10_000,
    error_bounds: bool = False,
) -> PlanningResult:
    """V* by value iteration, ``V_{k+1}(s) = max_a Σ_s' T [R + γ V_k(s')]`` from ``V_0 = 0``.

    Stops when the residual ``max_s |V_{k+1}(s) − V_k(s)| < tol`` (then ``|V_{k+1} − V*| <=
    tol · γ / (1 − γ)``). With ``error_bounds`` (γ < 1) it stops instead when MacQueen's bounds on
    V* are within ``± tol`` and returns their midpoint, so ``|V − V*| <= tol``: far fewer
    iterations where all states' values move together (dense random MDPs converge in a handful).
    Jittable in ``mdp`` and ``discount_factor``; ``max_iterations`` and ``error_bounds`` are static.
    """
    _check(mdp, discount_factor, tol, max_iterations)
    if error_bounds and not isinstance(discount_factor, jax.core.Tracer) and float(discount_factor) >= 1.0:
        raise UsageError("error_bounds need a discount factor below 1 (the bounds scale with γ / (1 − γ))")
    return _value_iteration(mdp, jnp.float32(discount_factor), jnp.float32(tol), max_iterations, error_bounds)


def q_value_iteration(
    mdp: MDP, discount_factor: float = 0.9, tol: float = 1e-6, max_iterations: int = 10_000
) -> PlanningResult:
    """Q* by Q-value iteration, ``Q_{k+1}(s, a) = Σ_s' T [R + γ max_a' Q_k(s', a')]`` from 0
    (−inf for impossible actions, which stay −inf); the residual is over possible actions."""
    _check(mdp, discount_factor, tol, max_iterations)
    return _q_value_iteration(mdp, jnp.float32(discount_factor), jnp.float32(tol), max_iterations)


@partial(jax.jit, static_argnames="num_iterations")
def q_value_iterates(mdp: MDP, discount_factor: Array, num_iterations: int) -> Array:
    """The first ``num_iterations`` Q-value-iteration tables ``Q_1 .. Q_n``, ``[n, S, A]`` (for plots)."""

    rewards = mdp.expected_rewards()

    def step(q_values, _):
        q_values = q_backup(mdp, state_values(mdp, q_values), discount_factor, rewards)
        return q_values, q_values

    initial = jnp.where(mdp.possible_actions, 0.0, -jnp.inf).astype(jnp.float32)
    return jax.lax.scan(step, initial, length=num_iterations)[1]
