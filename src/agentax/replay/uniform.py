"""A uniform replay buffer in JAX arrays: a ring that overwrites its oldest transitions.

Pure and jittable: the capacity is the static leading axis of the storage, the write position
and fill level are scalars in the state, so the buffer lives inside a compiled training loop and
``vmap``s over seeds like any pytree.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from agentax.replay.core import ReplaySample, capacity_of


@struct.dataclass
class UniformState:
    storage: Any  # pytree of [capacity, ...] arrays
    position: jax.Array  # int32 []: where the next transition goes
    size: jax.Array  # int32 []: how many slots hold transitions


def init(capacity: int, example_transition: Any) -> UniformState:
    """An empty buffer of ``capacity`` slots shaped like ``example_transition`` (one transition)."""
    if capacity < 1:
        raise ValueError(f"replay capacity must be at least 1, got {capacity}")
    storage = jax.tree.map(
        lambda x: jnp.zeros((capacity, *jnp.shape(x)), jnp.asarray(x).dtype), example_transition
    )
    return UniformState(storage=storage, position=jnp.int32(0), size=jnp.int32(0))


def write_indices(position: jax.Array, batch_size: int, capacity: int) -> jax.Array:
    """Slots ``[batch_size]`` for the next ``batch_size`` transitions, wrapping around the ring."""
    return (position + jnp.arange(batch_size, dtype=jnp.int32)) % capacity


def add(state: UniformState, batch: Any, valid: jax.Array | bool = True) -> UniformState:
    """Append ``batch`` (leaves ``[batch, ...]``, batch <= capacity), overwriting the oldest slots.

    ``valid`` (a scalar) False leaves the buffer as it was, without a branch: the n-step
    accumulator emits nothing real until its window has filled.
    """
    capacity = capacity_of(state.storage)
    batch_size = jax.tree.leaves(batch)[0].shape[0]
    indices = write_indices(state.position, batch_size, capacity)
    storage = jax.tree.map(
        lambda s, x: s.at[indices].set(jnp.where(valid, x.astype(s.dtype), s[indices])), state.storage, batch
    )
    advance = jnp.where(valid, batch_size, 0).astype(jnp.int32)
    return UniformState(
        storage=storage,
        position=(state.position + advance) % capacity,
        size=jnp.minimum(state.size + advance, capacity),
    )


def sample(state: UniformState, key: jax.Array, batch_size: int) -> ReplaySample:
    """``batch_size`` transitions drawn uniformly with replacement from the filled slots."""
    indices = jax.random.randint(key, (batch_size,), 0, jnp.maximum(state.size, 1))
    transition = jax.tree.map(lambda s: s[indices], state.storage)
    return ReplaySample(transition=transition, indices=indices, weights=jnp.ones(batch_size, jnp.float32))
