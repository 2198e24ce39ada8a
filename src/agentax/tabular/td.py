"""Temporal-difference learning of state values, TD(0) (lecture eq. 18-4), and its building blocks.

``td_error`` is the one update every tabular learner here shares (TD(0), Q-learning, SARSA,
Expected SARSA, Double Q): ``δ = r_t + discount_t · v_t − v_tm1``, where ``discount_t`` is 0 after
a true termination and ``v_t`` is whatever the algorithm bootstraps from. A learner runs the MDP
as an :class:`~agentax.envs.mdp.MDPEnv` inside one ``lax.scan``, so it jits, and ``jax.vmap`` over
keys runs many seeds at once. A time-limit truncation bootstraps from the state reached.

A learner accepts a discount factor of 1 on any MDP, unlike planning: every episode it samples ends,
by termination or at the cap ``max_steps_in_episode``, so its returns are finite sums of rewards.
(Sutton & Barto's episodic examples, e.g. cliff walking, are undiscounted.) Value iteration has no
such cap, and needs every policy to terminate.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.envs.mdp import MDP, MDPEnv
from agentax.errors import UsageError

Array = jax.Array


def td_error(v_tm1: Array, r_t: Array, discount_t: Array, v_t: Array) -> Array:
    """``δ = r_t + discount_t · v_t − v_tm1`` for one transition (``discount_t = γ``, or 0 if terminated)."""
    return r_t + discount_t * v_t - v_tm1


def learning_rate_at(learning_rate: Array, learning_rate_decay: Array, step: Array) -> Array:
    """The book's decaying learning rate ``α_t = α_0 / (1 + t · decay)``."""
    return learning_rate / (1.0 + step * learning_rate_decay)


def uniform_policy(mdp: MDP) -> Array:
    """The uniformly random exploration policy over each state's possible actions, ``[S, A]``."""
    mask = mdp.possible_actions.astype(jnp.float32)
    return mask / mask.sum(-1, keepdims=True)


def run_with_snapshots(step: Callable, carry: Any, num_steps: int, log_interval: int, snapshot: Callable):
    """``lax.scan`` ``step`` for ``num_steps``, taking ``snapshot(carry)`` after every ``log_interval``.

    Returns ``(carry, snapshots [num_steps // log_interval, ...], per-step outputs [num_steps, ...])``.
    """

    def chunk(carry, _):
        carry, outputs = jax.lax.scan(step, carry, length=log_interval)
        return carry, (snapshot(carry), outputs)

    carry, (snapshots, outputs) = jax.lax.scan(chunk, carry, length=num_steps // log_interval)
    outputs = jax.tree.map(lambda x: x.reshape(num_steps, *x.shape[2:]), outputs)
    return carry, snapshots, outputs


def check_sampled_discount_factor(discount_factor: float) -> None:
    """Raise :class:`UsageError` unless ``0 <= discount_factor <= 1``: 1 included, for learning
    from sampled episodes, which the episode cap ends (planning checks more, see
    :func:`agentax.envs.mdp.check_discount_factor`)."""
    if isinstance(discount_factor, jax.core.Tracer):
        return
    if not 0.0 <= float(discount_factor) <= 1.0:
        raise UsageError(f"discount factor {discount_factor} is outside [0, 1]")


def episode_returns(rewards: Any, episode_ends: Any) -> list[np.ndarray]:
    """Host-side: the undiscounted return of every episode completed in a learner's step stream.

    ``rewards`` and ``episode_ends`` are ``[..., num_steps]`` (a vmapped run gives one row per
    seed); returns a list (one entry per row, or a single array for one stream) of the returns
    ``[num_episodes]`` in order. The unfinished episode at the end is left out.
    """
    rewards, episode_ends = np.asarray(rewards, np.float64), np.asarray(episode_ends, bool)
    if rewards.ndim == 1:
        return episode_returns(rewards[None], episode_ends[None])[0]
    out = []
    num_steps = rewards.shape[-1]
    for r, ends in zip(rewards.reshape(-1, num_steps), episode_ends.reshape(-1, num_steps), strict=True):
        cumulative = np.concatenate([[0.0], np.cumsum(r)])
        boundaries = np.concatenate([[0], np.flatnonzero(ends) + 1])
        out.append(np.diff(cumulative[boundaries]))
    return out


def check_run_lengths(num_steps: int, log_interval: int, max_steps_in_episode: int) -> None:
    if num_steps < 1 or log_interval < 1 or num_steps % log_interval:
        raise UsageError(
            f"num_steps ({num_steps}) must be a positive multiple of log_interval ({log_interval})"
        )
    if max_steps_in_episode < 1:
        raise UsageError(f"max_steps_in_episode must be at least 1, got {max_steps_in_episode}")


@struct.dataclass
class TDConfig:
    """TD(0) of state values under a fixed exploration policy."""

    discount_factor: float = 0.9
    """γ, in [0, 1] (1 too: the episode cap ends every episode)."""
    learning_rate: float = 0.05
    """α_0 in α_t = α_0 / (1 + t · learning_rate_decay)."""
    learning_rate_decay: float = 0.005
    """The decay of the learning rate per step (0 keeps it constant)."""
    num_steps: int = struct.field(pytree_node=False, default=10_000)
    """Environment steps in total (a multiple of log_interval)."""
    max_steps_in_episode: int = struct.field(pytree_node=False, default=1000)
    """Episodes are truncated (with bootstrapping) after this many steps, then reset."""
    log_interval: int = struct.field(pytree_node=False, default=100)
    """Steps between the snapshots of the value table kept for plots."""


@struct.dataclass
class TDResult:
    values: Array  # [S] learned V
    value_history: Array  # [num_steps // log_interval, S] V after every log_interval steps
    next_states: Array  # [num_steps] int32, the state each step reached
    rewards: Array  # [num_steps]
    episode_ends: Array  # [num_steps] bool, the step ended an episode (terminated or truncated)


@struct.dataclass
class _TDCarry:
    values: Array  # [S]
    env_state: Any
    obs: Array  # int32 []
    step: Array  # int32 []
    key: Array


@jax.jit
def _td_learning(key: Array, mdp: MDP, config: TDConfig, policy: Array) -> TDResult:
    env = MDPEnv(mdp, config.max_steps_in_episode)
    params = env.default_params()
    key, reset_key = jax.random.split(key)
    obs, env_state = env.reset(reset_key, params)

    def step(carry: _TDCarry, _):
        key, action_key, step_key = jax.random.split(carry.key, 3)
        action = jax.random.categorical(action_key, jnp.log(policy[carry.obs]))
        ts, env_state = env.step(step_key, carry.env_state, action, params)
        discount_t = config.discount_factor * (1.0 - ts.terminated)
        delta = td_error(carry.values[carry.obs], ts.reward, discount_t, carry.values[ts.final_obs])
        alpha = learning_rate_at(config.learning_rate, config.learning_rate_decay, carry.step)
        values = carry.values.at[carry.obs].add(alpha * delta)
        carry = _TDCarry(values, env_state, ts.obs, carry.step + 1, key)
        return carry, (ts.final_obs, ts.reward, ts.done)

    carry = _TDCarry(jnp.zeros(mdp.num_states, jnp.float32), env_state, obs, jnp.int32(0), key)
    carry, history, (next_states, rewards, ends) = run_with_snapshots(
        step, carry, config.num_steps, config.log_interval, lambda c: c.values
    )
    return TDResult(carry.values, history, next_states, rewards, ends)


def td_learning(
    key: Array, mdp: MDP, config: TDConfig | None = None, policy: Array | None = None
) -> TDResult:
    """TD(0): ``V(s) ← V(s) + α_t δ`` along one stream of transitions sampled from ``mdp``.

    ``policy`` ``[S, A]`` gives the exploration policy's action probabilities (default: uniform over
    the possible actions); V converges to that policy's values. Vmap over ``key`` for many seeds.
    """
    config = TDConfig() if config is None else config
    check_sampled_discount_factor(config.discount_factor)
    check_run_lengths(config.num_steps, config.log_interval, config.max_steps_in_episode)
    policy = uniform_policy(mdp) if policy is None else jnp.asarray(policy, jnp.float32)
    if policy.shape != (mdp.num_states, mdp.num_actions):
        raise UsageError(f"policy has shape {policy.shape}, expected ({mdp.num_states}, {mdp.num_actions})")
    if not isinstance(policy, jax.core.Tracer) and np.any(
        np.asarray(policy)[~np.asarray(mdp.possible_actions)] > 0
    ):
        raise UsageError("policy gives probability to an impossible action")
    return _td_learning(key, mdp, config, policy)
