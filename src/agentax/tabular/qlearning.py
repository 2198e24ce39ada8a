"""Tabular Q-learning (lecture eq. 18-5) and its siblings: SARSA, Expected SARSA, Double Q-learning.

One learner, four bootstraps. Every step takes ``δ = td_error(Q(s, a), r, discount_t, v_t)`` and moves
``Q(s, a)`` by ``α_t δ`` with the book's ``α_t = α_0 / (1 + t · decay)``; the algorithm only decides
what ``v_t`` is:

- ``q-learning``: ``max_a' Q(s', a')`` (off-policy: the greedy target),
- ``sarsa``: ``Q(s', a')`` for the action ``a'`` the behaviour policy takes next,
- ``expected-sarsa``: ``Σ_a' π(a' | s') Q(s', a')`` under the ε-greedy behaviour policy,
- ``double-q``: two tables; a coin picks the one to update, which chooses ``argmax_a'`` while the
  other evaluates it (van Hasselt 2010), removing the max's overestimation.

Exploration is ε-greedy with a constant, linear or exponential schedule (ε = 1, the default, is
the book's uniformly random exploration), or the book's exploration function (eq. 18-6):
act greedily on ``f(Q, N) = Q + κ / (1 + N)``, ``N`` the visit counts, and bootstrap Q-learning
from ``max_a' f(Q(s', a'), N(s', a'))`` so that optimism about unvisited actions propagates back.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from agentax.envs.mdp import MDP, MDPEnv
from agentax.errors import UsageError
from agentax.policies import constant_schedule, epsilon_greedy, exponential_schedule, linear_schedule
from agentax.tabular.td import (
    check_run_lengths,
    check_sampled_discount_factor,
    learning_rate_at,
    run_with_snapshots,
    td_error,
)

Array = jax.Array
ALGORITHMS = ("q-learning", "sarsa", "expected-sarsa", "double-q")
EXPLORATIONS = ("epsilon-greedy", "exploration-function")
SCHEDULES = ("constant", "linear", "exponential")


@struct.dataclass
class QLearningConfig:
    """Tabular Q-learning and its variants; the defaults are the book's settings."""

    discount_factor: float = 0.9
    """γ, in [0, 1] (1 too: the episode cap ends every episode)."""
    learning_rate: float = 0.05
    """α_0 in α_t = α_0 / (1 + t · learning_rate_decay)."""
    learning_rate_decay: float = 0.005
    """The decay of the learning rate per step (0 keeps it constant)."""
    epsilon_start: float = 1.0
    """ε at step 0 (1 = uniformly random over the possible actions)."""
    epsilon_end: float = 1.0
    """ε that the linear and exponential schedules move toward."""
    epsilon_decay_steps: float = 10_000.0
    """linear schedule: steps to go from epsilon_start to epsilon_end."""
    epsilon_decay_rate: float = 0.999
    """exponential schedule: ε_t = end + (start − end) · rate^t."""
    exploration_bonus: float = 1.0
    """κ, the curiosity of the exploration function f(Q, N) = Q + κ / (1 + N)."""
    algorithm: str = struct.field(pytree_node=False, default="q-learning")
    """q-learning, sarsa, expected-sarsa or double-q."""
    exploration: str = struct.field(pytree_node=False, default="epsilon-greedy")
    """epsilon-greedy, or exploration-function (greedy on f(Q, N); ε unused)."""
    epsilon_schedule: str = struct.field(pytree_node=False, default="constant")
    """constant (epsilon_start), linear or exponential."""
    num_steps: int = struct.field(pytree_node=False, default=10_000)
    """Environment steps in total (a multiple of log_interval)."""
    max_steps_in_episode: int = struct.field(pytree_node=False, default=1000)
    """Episodes are truncated (with bootstrapping) after this many steps, then reset."""
    log_interval: int = struct.field(pytree_node=False, default=100)
    """Steps between the snapshots of the Q table kept for plots."""


@struct.dataclass
class QLearningResult:
    q_values: Array  # [S, A] learned Q, −inf for impossible actions
    q_history: Array  # [num_steps // log_interval, S, A] Q after every log_interval steps
    visit_counts: Array  # [S, A] int32 N(s, a)
    next_states: Array  # [num_steps] int32, the state each step reached
    rewards: Array  # [num_steps]
    episode_ends: Array  # [num_steps] bool, the step ended an episode (terminated or truncated)


@struct.dataclass
class _Carry:
    q_values: Array  # [S, A], 0 at impossible actions
    q_values_b: Array  # [S, A], Double Q-learning's second table (unused otherwise)
    visit_counts: Array  # [S, A] int32
    env_state: Any
    obs: Array  # int32 []: s_tm1
    action: Array  # int32 []: a_tm1, already chosen
    step: Array  # int32 []
    key: Array


def exploration_values(q_values: Array, visit_counts: Array, exploration_bonus: Array) -> Array:
    """The book's exploration function ``f(Q, N) = Q + κ / (1 + N)`` (any shape)."""
    return q_values + exploration_bonus / (1.0 + visit_counts)


def epsilon_greedy_probabilities(q_values: Array, mask: Array, epsilon: Array) -> Array:
    """``π(a | s)`` of ε-greedy on one row ``q_values [A]``: ε over the possible actions, 1 − ε on argmax."""
    uniform = mask / mask.sum()
    greedy = jax.nn.one_hot(jnp.argmax(jnp.where(mask, q_values, -jnp.inf)), q_values.shape[-1])
    return epsilon * uniform + (1.0 - epsilon) * greedy


def epsilon_schedule(config: QLearningConfig):
    """ε as a function of the step, from ``agentax.policies``' schedules."""
    if config.epsilon_schedule == "linear":
        return linear_schedule(config.epsilon_start, config.epsilon_end, config.epsilon_decay_steps)
    if config.epsilon_schedule == "exponential":
        return exponential_schedule(config.epsilon_start, config.epsilon_end, config.epsilon_decay_rate)
    return constant_schedule(config.epsilon_start)


def _masked_max(values: Array, mask: Array) -> Array:
    return jnp.max(jnp.where(mask, values, -jnp.inf))


@jax.jit
def _q_learning(key: Array, mdp: MDP, config: QLearningConfig) -> QLearningResult:
    env = MDPEnv(mdp, config.max_steps_in_episode)
    params = env.default_params()
    mask = mdp.possible_actions
    schedule = epsilon_schedule(config)
    curious = config.exploration == "exploration-function"

    def acting_values(carry: _Carry) -> Array:
        if config.algorithm == "double-q":
            return (carry.q_values + carry.q_values_b) / 2
        return carry.q_values

    def act(key: Array, q_row: Array, counts_row: Array, mask_row: Array, epsilon: Array) -> Array:
        if curious:
            scores = exploration_values(q_row, counts_row, config.exploration_bonus)
            return jnp.argmax(jnp.where(mask_row, scores, -jnp.inf)).astype(jnp.int32)
        return epsilon_greedy(key, q_row, epsilon, mask_row)

    def step(carry: _Carry, _):
        key, step_key, action_key, bootstrap_key, coin_key = jax.random.split(carry.key, 5)
        s_tm1, a_tm1 = carry.obs, carry.action
        ts, env_state = env.step(step_key, carry.env_state, a_tm1, params)
        s_t = ts.final_obs
        visit_counts = carry.visit_counts.at[s_tm1, a_tm1].add(1)
        epsilon = schedule(carry.step + 1)
        q_act = acting_values(carry)
        next_action = act(action_key, q_act[ts.obs], visit_counts[ts.obs], mask[ts.obs], epsilon)
        # SARSA bootstraps from the action taken in s_t; after an episode ends it samples one there.
        bootstrap_action = act(bootstrap_key, q_act[s_t], visit_counts[s_t], mask[s_t], epsilon)
        a_t = jnp.where(ts.done, bootstrap_action, next_action)

        online, target = carry.q_values, carry.q_values
        coin = jnp.bool_(True)
        if config.algorithm == "double-q":
            coin = jax.random.bernoulli(coin_key)
            online = jnp.where(coin, carry.q_values, carry.q_values_b)
            target = jnp.where(coin, carry.q_values_b, carry.q_values)
        q_t, mask_t = target[s_t], mask[s_t]
        if config.algorithm == "q-learning":
            scores = exploration_values(q_t, visit_counts[s_t], config.exploration_bonus) if curious else q_t
            v_t = _masked_max(scores, mask_t)
        elif config.algorithm == "sarsa":
            v_t = q_t[a_t]
        elif config.algorithm == "expected-sarsa":
            probabilities = epsilon_greedy_probabilities(q_act[s_t], mask_t, jnp.where(curious, 0.0, epsilon))
            v_t = jnp.sum(probabilities * q_t)
        else:
            v_t = q_t[jnp.argmax(jnp.where(mask_t, online[s_t], -jnp.inf))]
        discount_t = config.discount_factor * (1.0 - ts.terminated)
        delta = td_error(online[s_tm1, a_tm1], ts.reward, discount_t, v_t)
        alpha = learning_rate_at(config.learning_rate, config.learning_rate_decay, carry.step)
        online = online.at[s_tm1, a_tm1].add(alpha * delta)
        q_values = jnp.where(coin, online, carry.q_values)
        q_values_b = jnp.where(coin, carry.q_values_b, online)
        carry = _Carry(
            q_values, q_values_b, visit_counts, env_state, ts.obs, next_action, carry.step + 1, key
        )
        return carry, (s_t, ts.reward, ts.done)

    def final_q(carry: _Carry) -> Array:
        return jnp.where(mask, acting_values(carry), -jnp.inf)

    key, reset_key, action_key = jax.random.split(key, 3)
    obs, env_state = env.reset(reset_key, params)
    zeros = jnp.zeros((mdp.num_states, mdp.num_actions), jnp.float32)
    counts = jnp.zeros((mdp.num_states, mdp.num_actions), jnp.int32)
    action = act(action_key, zeros[obs], counts[obs], mask[obs], schedule(0))
    carry = _Carry(zeros, zeros, counts, env_state, obs, action, jnp.int32(0), key)
    carry, history, (next_states, rewards, ends) = run_with_snapshots(
        step, carry, config.num_steps, config.log_interval, final_q
    )
    return QLearningResult(final_q(carry), history, carry.visit_counts, next_states, rewards, ends)


def check_config(mdp: MDP, config: QLearningConfig) -> None:
    """Raise :class:`UsageError` for an unknown algorithm, exploration or schedule, or bad numbers."""
    for value, choices, what in [
        (config.algorithm, ALGORITHMS, "algorithm"),
        (config.exploration, EXPLORATIONS, "exploration"),
        (config.epsilon_schedule, SCHEDULES, "epsilon schedule"),
    ]:
        if value not in choices:
            raise UsageError(f"unknown {what} {value!r}; choose from {', '.join(choices)}")
    check_sampled_discount_factor(config.discount_factor)
    for name in ("epsilon_start", "epsilon_end"):
        value = getattr(config, name)
        if not isinstance(value, jax.core.Tracer) and not 0.0 <= float(value) <= 1.0:
            raise UsageError(f"{name} is {value}, outside [0, 1]")
    for name in ("learning_rate", "learning_rate_decay", "exploration_bonus"):
        value = getattr(config, name)
        if not isinstance(value, jax.core.Tracer) and float(value) < 0.0:
            raise UsageError(f"{name} is {value}; it must be >= 0")
    check_run_lengths(config.num_steps, config.log_interval, config.max_steps_in_episode)


def q_learning(key: Array, mdp: MDP, config: QLearningConfig | None = None) -> QLearningResult:
    """Learn Q from ``config.num_steps`` transitions sampled from ``mdp`` (algorithm and exploration
    as ``config`` says). Pure and jitted; ``jax.vmap`` over ``key`` runs many seeds at once."""
    config = QLearningConfig() if config is None else config
    check_config(mdp, config)
    return _q_learning(key, mdp, config)
