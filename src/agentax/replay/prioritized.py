"""Prioritized replay (Schaul et al., 2016) on an array-backed sum-tree, jittable.

A transition with TD error δ has priority ``p = |δ| + ε`` and is sampled with probability
``P(i) = p_i^ζ / Σ_k p_k^ζ`` (``ζ`` = ``priority_exponent``, 0.6 by default). Its importance weight
``w_i = (n · P(i))^−β`` corrects the bias of non-uniform sampling; weights are divided by the largest
in the batch so they only ever scale the loss down. ``β`` is an argument of ``sample`` so the caller
anneals it towards 1. New transitions get the largest priority seen so far, so each is replayed soon.

The tree is one array of ``2 · L`` floats, ``L`` the capacity rounded up to a power of two: node
``k`` has children ``2k`` and ``2k + 1``, the root is node 1 and leaf ``i`` is node ``L + i``. Every
update rewrites the changed leaves and then, level by level, recomputes their ancestors from their
children (never by adding deltas), so float rounding cannot drift. Sampling is stratified: the
total mass is cut into ``batch`` equal segments and one point drawn in each, then each point walks
down from the root. Both are vectorised over the batch; depth is ``log2 L`` fixed steps.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from agentax.replay import uniform
from agentax.replay.core import ReplaySample, capacity_of


@struct.dataclass
class PrioritizedState:
    buffer: uniform.UniformState  # the transitions, in a ring
    tree: jax.Array  # float32 [2 * num_leaves]: node k = sum of its children; leaves hold p^ζ
    max_priority: jax.Array  # float32 []: the largest p = |δ| + ε so far (given to new transitions)
    priority_exponent: jax.Array  # float32 []: ζ
    priority_epsilon: jax.Array  # float32 []: ε, so no transition's probability is ever zero


def tree_size(capacity: int) -> int:
    """Leaves of the sum-tree: ``capacity`` rounded up to a power of two."""
    return 1 << max(capacity - 1, 0).bit_length()


def init(
    capacity: int, example_transition: Any, priority_exponent: float = 0.6, priority_epsilon: float = 1e-6
) -> PrioritizedState:
    """An empty prioritized buffer of ``capacity`` slots shaped like ``example_transition``."""
    return PrioritizedState(
        buffer=uniform.init(capacity, example_transition),
        tree=jnp.zeros(2 * tree_size(capacity), jnp.float32),
        max_priority=jnp.float32(1.0),
        priority_exponent=jnp.float32(priority_exponent),
        priority_epsilon=jnp.float32(priority_epsilon),
    )


def total(tree: jax.Array) -> jax.Array:
    """The sum of all leaves (the root)."""
    return tree[1]


def leaves(tree: jax.Array) -> jax.Array:
    """The leaves ``[num_leaves]`` (``p^ζ`` of each slot; zero for empty slots)."""
    return tree[tree.shape[0] // 2 :]


def set_leaves(tree: jax.Array, indices: jax.Array, values: jax.Array) -> jax.Array:
    """Set leaves ``indices`` ``[k]`` to ``values`` ``[k]`` and recompute their ancestors."""
    num_leaves = tree.shape[0] // 2
    nodes = indices.astype(jnp.int32) + num_leaves
    tree = tree.at[nodes].set(values.astype(tree.dtype))
    for _ in range(num_leaves.bit_length() - 1):
        nodes = nodes // 2
        tree = tree.at[nodes].set(tree[2 * nodes] + tree[2 * nodes + 1])
    return tree


def find_prefix_sum(tree: jax.Array, mass: jax.Array) -> jax.Array:
    """For each ``mass`` ``[k]`` in ``[0, total)``, the leaf where the running sum of leaves passes it."""
    num_leaves = tree.shape[0] // 2
    nodes = jnp.ones_like(mass, dtype=jnp.int32)
    for _ in range(num_leaves.bit_length() - 1):
        left = tree[2 * nodes]
        go_right = mass >= left
        mass = jnp.where(go_right, mass - left, mass)
        nodes = 2 * nodes + go_right.astype(jnp.int32)
    return nodes - num_leaves


def add(state: PrioritizedState, batch: Any, valid: jax.Array | bool = True) -> PrioritizedState:
    """Append ``batch`` (leaves ``[batch, ...]``) with the maximum priority seen so far
    (``valid`` False: no change, as in ``uniform.add``)."""
    capacity = capacity_of(state.buffer.storage)
    batch_size = jax.tree.leaves(batch)[0].shape[0]
    indices = uniform.write_indices(state.buffer.position, batch_size, capacity)
    value = jnp.where(valid, state.max_priority**state.priority_exponent, leaves(state.tree)[indices])
    return state.replace(
        buffer=uniform.add(state.buffer, batch, valid), tree=set_leaves(state.tree, indices, value)
    )


def probabilities(state: PrioritizedState, indices: jax.Array) -> jax.Array:
    """``P(i)`` ``[k]`` of slots ``indices``."""
    return leaves(state.tree)[indices] / total(state.tree)


def importance_weights(probability: jax.Array, size: jax.Array, beta: jax.Array) -> jax.Array:
    """``w = (n · P)^−β / max w`` over the batch: ``probability`` ``[batch]``, ``size`` = n."""
    weights = (size * probability) ** (-beta)
    return weights / weights.max()


def sample(state: PrioritizedState, key: jax.Array, batch_size: int, beta: jax.Array = 1.0) -> ReplaySample:
    """``batch_size`` transitions drawn with probability ``∝ p^ζ`` (stratified), with their weights."""
    mass_total = total(state.tree)
    segment = mass_total / batch_size
    points = (jnp.arange(batch_size) + jax.random.uniform(key, (batch_size,))) * segment
    indices = find_prefix_sum(state.tree, jnp.minimum(points, mass_total * (1 - 1e-6)))
    indices = jnp.clip(indices, 0, jnp.maximum(state.buffer.size - 1, 0))
    transition = jax.tree.map(lambda s: s[indices], state.buffer.storage)
    weights = importance_weights(probabilities(state, indices), state.buffer.size, beta)
    return ReplaySample(transition=transition, indices=indices, weights=weights)


def update_priorities(state: PrioritizedState, indices: jax.Array, td_error: jax.Array) -> PrioritizedState:
    """After a learning step: slots ``indices`` ``[k]`` get priority ``|td_error| + ε``."""
    priority = jnp.abs(td_error) + state.priority_epsilon
    return state.replace(
        tree=set_leaves(state.tree, indices, priority**state.priority_exponent),
        max_priority=jnp.maximum(state.max_priority, priority.max()),
    )
