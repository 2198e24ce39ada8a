"""What a replay buffer stores and what it hands back."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Transition:
    """One (possibly n-step) transition ``s -a-> r, s'``; batches add leading axes.

    ``terminated`` and ``truncated`` stay apart: a learner bootstraps from ``next_obs`` unless
    ``terminated``. ``next_obs`` is the observation the step really reached (``TimeStep.final_obs``),
    not the first observation of the next episode. For an n-step transition ``reward`` is the
    discounted sum of up to n rewards and ``num_steps`` how many (fewer when the episode ended).
    ``info`` carries what the collect policy returned beside the action (TF-Agents' policy info,
    e.g. PPO's log-probabilities and values); None where there is nothing (replay stores none).
    """

    obs: jax.Array  # [*obs_shape]
    action: jax.Array  # int32 []
    reward: jax.Array  # float32 []
    next_obs: jax.Array  # [*obs_shape]
    terminated: jax.Array  # bool []
    truncated: jax.Array  # bool []
    num_steps: jax.Array  # int32 []: steps between obs and next_obs (1 for one-step transitions)
    info: Any = None  # dict of arrays, or None


@struct.dataclass
class ReplaySample:
    """A sampled batch: ``transition`` fields ``[batch, ...]``, their buffer ``indices`` and
    importance ``weights`` ``[batch]`` (ones for uniform sampling)."""

    transition: Any
    indices: jax.Array  # int32 [batch]
    weights: jax.Array  # float32 [batch]


def example_transition(obs: Any, action: Any) -> Transition:
    """A zero transition shaped like one ``obs`` and one ``action``, for ``init``."""
    obs = jnp.zeros_like(jnp.asarray(obs))
    return Transition(
        obs=obs,
        action=jnp.zeros_like(jnp.asarray(action)),
        reward=jnp.float32(0.0),
        next_obs=obs,
        terminated=jnp.bool_(False),
        truncated=jnp.bool_(False),
        num_steps=jnp.int32(1),
    )


def capacity_of(storage: Any) -> int:
    """The static capacity: the leading axis of every leaf of ``storage``."""
    return jax.tree.leaves(storage)[0].shape[0]
