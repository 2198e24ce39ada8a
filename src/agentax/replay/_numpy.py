"""NumPy pieces both host buffers share (:mod:`agentax.replay.host`'s and the frame buffer's): the
sum-tree of prioritized replay and TF-Agents' ``as_dataset``, its batches drawn ahead."""

from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from agentax.replay.core import ReplaySample


def set_leaves(tree: np.ndarray, indices: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Set leaves ``indices`` to ``values`` in place and recompute their ancestors."""
    num_leaves = len(tree) // 2
    nodes = np.asarray(indices) + num_leaves
    tree[nodes] = values
    for _ in range(num_leaves.bit_length() - 1):
        nodes = np.unique(nodes // 2)
        tree[nodes] = tree[2 * nodes] + tree[2 * nodes + 1]
    return tree


def find_prefix_sum(tree: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """For each ``mass``, the leaf where the running sum of leaves passes it."""
    num_leaves = len(tree) // 2
    nodes = np.ones(len(mass), np.int64)
    mass = np.array(mass, np.float64)
    for _ in range(num_leaves.bit_length() - 1):
        left = tree[2 * nodes]
        go_right = mass >= left
        mass = np.where(go_right, mass - left, mass)
        nodes = 2 * nodes + go_right
    return nodes - num_leaves


class Dataset:
    """TF-Agents' ``as_dataset`` for a buffer with ``sample(batch_size)`` and ``prioritized``."""

    def as_dataset(self, sample_batch_size: int, num_batches: int = 1, prefetch: int = 2) -> DrawAhead:
        """Endless uniform batches, each leaf ``[num_batches, sample_batch_size, ...]``, drawn
        ``prefetch + 1`` ahead (uniform replay only: prioritized batches depend on the last update)."""
        if self.prioritized:
            raise ValueError("as_dataset draws ahead, so it serves uniform replay only; sample() instead")
        return DrawAhead(lambda: self._stacked(sample_batch_size, num_batches), prefetch + 1)

    def _stacked(self, batch_size: int, num_batches: int) -> ReplaySample:
        batch = self.sample(batch_size * num_batches)
        return jax.tree.map(lambda x: x.reshape(num_batches, batch_size, *x.shape[1:]), batch)


class DrawAhead:
    """An iterator over ``draw()`` results kept ``depth`` ahead, drawn on the caller's thread at
    fixed points: when it is made, and at each :meth:`refill`. So batch ``k`` holds what the buffer
    held when batch ``k - depth`` was taken, whatever the threads' timing: the same seed gives the
    same batches. A learner calls :meth:`refill` right after dispatching its (asynchronous) update,
    so the drawing overlaps XLA's work on the batch taken; without it, ``next`` draws when empty."""

    def __init__(self, draw: Callable[[], Any], depth: int):
        self.draw, self.depth = draw, max(depth, 1)
        self.ahead: collections.deque = collections.deque()
        self.refill()

    def refill(self) -> None:
        while len(self.ahead) < self.depth:
            self.ahead.append(self.draw())

    def __iter__(self) -> DrawAhead:
        return self

    def __next__(self) -> Any:
        if not self.ahead:
            self.refill()
        return self.ahead.popleft()
