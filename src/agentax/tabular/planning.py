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


def q_backup(mdp: MDP, values: Array, discount_factor: Array) -> Array:
    """``Q(s, a) = Σ_s' T(s, a, s') [R(s, a, s') + γ V(s')]`` with ``V = 0`` at terminal states:
    ``[S, A]``, 0 in terminal states, −inf for impossible actions."""
    next_values = jnp.where(mdp.terminal, 0.0, values)
    q_values = mdp.expected_rewards() + discount_factor * mdp.expected_next_values(next_values)
    q_values = jnp.where(mdp.terminal[:, None], 0.0, q_values)
    return jnp.where(mdp.possible_actions, q_values, -jnp.inf)


def state_values(mdp: MDP, q_values: Array) -> Array:
    """``V(s) = max_a Q(s, a)`` over possible actions, 0 at terminal states: ``[S]``."""
    return jnp.where(mdp.terminal, 0.0, jnp.max(q_values, -1))


def greedy_policy(q_values: Array) -> Array:
    """The action with the highest Q-value in each state, ``[S]`` int32 (impossible actions are −inf)."""
    return jnp.argmax(q_values, -1).astype(jnp.int32)


def _iterate(backup, initial: Array, tol: Array, max_iterations: int) -> PlanningResult:
    """Apply ``backup`` from ``initial`` until the residual is below ``tol`` or ``max_iterations``."""

    def cond(carry):
        _, _, iteration, residual = carry
        return (iteration < max_iterations) & (residual >= tol)

    def body(carry):
        values, residuals, iteration, _ = carry
        new_values = backup(values)
        finite = jnp.isfinite(new_values)
        residual = jnp.max(jnp.where(finite, jnp.abs(new_values - jnp.where(finite, values, 0.0)), 0.0))
        return new_values, residuals.at[iteration].set(residual), iteration + 1, residual

    residuals = jnp.full((max_iterations,), jnp.nan, jnp.float32)
    carry = (initial, residuals, jnp.int32(0), jnp.float32(jnp.inf))
    values, residuals, iterations, residual = jax.lax.while_loop(cond, body, carry)
    return PlanningResult(values, residuals, iterations, residual < tol)


@partial(jax.jit, static_argnames="max_iterations")
def _value_iteration(mdp: MDP, discount_factor: Array, tol: Array, max_iterations: int) -> PlanningResult:
    backup = lambda values: state_values(mdp, q_backup(mdp, values, discount_factor))
    return _iterate(backup, jnp.zeros(mdp.num_states, jnp.float32), tol, max_iterations)


@partial(jax.jit, static_argnames="max_iterations")
def _q_value_iteration(mdp: MDP, discount_factor: Array, tol: Array, max_iterations: int) -> PlanningResult:
    backup = lambda q_values: q_backup(mdp, state_values(mdp, q_values), discount_factor)
    initial = jnp.where(mdp.possible_actions, 0.0, -jnp.inf).astype(jnp.float32)
    return _iterate(backup, initial, tol, max_iterations)


def _check(mdp: MDP, discount_factor: float, tol: float, max_iterations: int) -> None:
    if not isinstance(discount_factor, jax.core.Tracer):
        check_discount_factor(mdp, discount_factor)
    if max_iterations < 1:
        raise UsageError(f"max_iterations must be at least 1, got {max_iterations}")
    if not tol > 0:
        raise UsageError(f"tol must be positive, got {tol}")


def value_iteration(
    mdp: MDP, discount_factor: float = 0.9, tol: float = 1e-6, max_iterations: int = 10_000
) -> PlanningResult:
    """V* by value iteration, ``V_{k+1}(s) = max_a Σ_s' T [R + γ V_k(s')]`` from ``V_0 = 0``.

    Stops when ``max_s |V_{k+1}(s) − V_k(s)| < tol`` (then ``|V_k − V*| < tol · γ / (1 − γ)``).
    Jittable in ``mdp`` and ``discount_factor``; ``max_iterations`` is static.
    """
    _check(mdp, discount_factor, tol, max_iterations)
    return _value_iteration(mdp, jnp.float32(discount_factor), jnp.float32(tol), max_iterations)


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

    def step(q_values, _):
        q_values = q_backup(mdp, state_values(mdp, q_values), discount_factor)
        return q_values, q_values

    initial = jnp.where(mdp.possible_actions, 0.0, -jnp.inf).astype(jnp.float32)
    return jax.lax.scan(step, initial, length=num_iterations)[1]
