"""Hand-written policies, epsilon-greedy exploration and its schedules.

A policy here is a pure function ``policy(obs, key) -> action`` on *one* observation; callers
batch it with ``jax.vmap``. Parametrised policies close over their parameters.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from agentax.envs.core import Box, Discrete, Policy, RecurrentPolicy


def basic_policy(obs: jax.Array, key: jax.Array | None = None) -> jax.Array:
    """The lecture's CartPole policy: push left (0) when the pole leans left, right (1) otherwise."""
    angle = obs[2]
    return jnp.where(angle < 0, 0, 1).astype(jnp.int32)


def random_policy(action_space: Discrete | Box) -> Policy:
    """Uniformly random actions from ``action_space``."""
    return lambda obs, key: action_space.sample(key)


def epsilon_greedy(
    key: jax.Array, q_values: jax.Array, epsilon: jax.Array, mask: jax.Array | None = None
) -> jax.Array:
    """With probability ``epsilon`` a random (possible) action, else ``argmax Q``.

    q_values: ``[num_actions]``; mask: ``[num_actions]`` bool of possible actions (all if None).
    """
    explore_key, action_key = jax.random.split(key)
    if mask is None:
        mask = jnp.ones(q_values.shape[-1], bool)
    greedy = jnp.argmax(jnp.where(mask, q_values, -jnp.inf))
    random = jax.random.choice(action_key, q_values.shape[-1], p=mask / mask.sum())
    return jnp.where(jax.random.uniform(explore_key) < epsilon, random, greedy).astype(jnp.int32)


def constant_schedule(value: float) -> Callable[[jax.Array], jax.Array]:
    return lambda t: jnp.full((), value, jnp.float32)


def linear_schedule(start: float, end: float, duration: float) -> Callable[[jax.Array], jax.Array]:
    """``start`` moving linearly to ``end`` over ``duration`` steps (or episodes), then ``end``.

    The lecture's ε = max(1 − episode / 500, 0.01) is ``linear_schedule(1.0, 0.01, 495)``.
    """
    return lambda t: (
        jnp.float32(start) + (end - start) * jnp.clip(jnp.asarray(t, jnp.float32) / duration, 0.0, 1.0)
    )


def exponential_schedule(start: float, end: float, decay: float) -> Callable[[jax.Array], jax.Array]:
    """``end + (start − end) · decay^t``: starts at ``start``, tends to ``end``."""
    return lambda t: (
        jnp.float32(end) + (start - end) * jnp.power(jnp.float32(decay), jnp.asarray(t, jnp.float32))
    )


def with_random_actions(
    policy: Policy | RecurrentPolicy, epsilon: float, num_actions: int
) -> Policy | RecurrentPolicy:
    """``policy`` with probability 1 − ε, a uniformly random action with probability ε: how Atari agents
    are evaluated (the Nature DQN with ε 0.05, Dopamine 0.001), so that a greedy policy that never
    presses FIRE cannot stall a game until its frame cap. A policy with memory (:class:`RecurrentPolicy`)
    stays one: its memory takes in every observation, whichever action is played."""

    def act(obs: jax.Array, key: jax.Array) -> jax.Array:
        explore_key, action_key, policy_key = jax.random.split(key, 3)
        random_action = jax.random.randint(action_key, (), 0, num_actions)
        return jnp.where(jax.random.uniform(explore_key) < epsilon, random_action, policy(obs, policy_key))

    if not isinstance(policy, RecurrentPolicy):
        return act

    def step(memory: Any, obs: jax.Array, key: jax.Array) -> tuple[Any, jax.Array]:
        explore_key, action_key, policy_key = jax.random.split(key, 3)
        memory, action = policy.step(memory, obs, policy_key)
        random_action = jax.random.randint(action_key, (), 0, num_actions)
        return memory, jnp.where(jax.random.uniform(explore_key) < epsilon, random_action, action)

    return RecurrentPolicy(policy.initial, step)
