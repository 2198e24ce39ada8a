"""NumPy twins of the uniform and prioritized buffers, for runners that step host environments.

Same functions as ``agentax.replay.uniform`` and ``agentax.replay.prioritized`` (``init``, ``add``,
``sample``, ``update_priorities``), same sum-tree layout, but the arrays are NumPy, ``add`` writes
in place (and returns the state, so call sites read the same), and ``key`` is a
``numpy.random.Generator``. A host loop that adds one transition per env step then never copies a
buffer-sized array, which a functional JAX update outside ``jit`` would.
"""

from __future__ import annotations

import collections
import json
import threading
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from agentax.errors import UsageError
from agentax.replay._numpy import Dataset, find_prefix_sum, set_leaves
from agentax.replay.core import ReplaySample, capacity_of
from agentax.replay.frames import available_memory
from agentax.replay.prioritized import tree_size


@dataclass
class HostUniformState:
    storage: Any  # pytree of NumPy [capacity, ...] arrays
    position: int = 0
    size: int = 0


@dataclass
class HostPrioritizedState:
    buffer: HostUniformState
    tree: np.ndarray  # float64 [2 * num_leaves], the layout of prioritized.PrioritizedState.tree
    max_priority: float = 1.0
    priority_exponent: float = 0.6
    priority_epsilon: float = 1e-6


def init(capacity: int, example_transition: Any) -> HostUniformState:
    """An empty buffer of ``capacity`` slots shaped like ``example_transition``."""
    if capacity < 1:
        raise ValueError(f"replay capacity must be at least 1, got {capacity}")
    need = capacity * sum(np.asarray(x).nbytes for x in jax.tree.leaves(example_transition))
    have = available_memory()
    if have is not None and need > have:
        raise UsageError(
            f"a replay of {capacity:,} transitions needs {need / 1e9:.2f} GB ({need:,} bytes), but only "
            f"{have / 1e9:.2f} GB of memory is available; lower --buffer-size"
        )
    storage = jax.tree.map(
        lambda x: np.zeros((capacity, *np.shape(x)), np.asarray(x).dtype), example_transition
    )
    return HostUniformState(storage=storage)


def _write_indices(state: HostUniformState, batch_size: int) -> np.ndarray:
    return (state.position + np.arange(batch_size)) % capacity_of(state.storage)


def add(state: HostUniformState, batch: Any) -> HostUniformState:
    """Append ``batch`` (leaves ``[batch, ...]``) in place, overwriting the oldest slots."""
    capacity = capacity_of(state.storage)
    batch_size = len(jax.tree.leaves(batch)[0])
    indices = _write_indices(state, batch_size)
    for store, values in zip(jax.tree.leaves(state.storage), jax.tree.leaves(batch), strict=True):
        store[indices] = np.asarray(values)
    state.position = (state.position + batch_size) % capacity
    state.size = min(state.size + batch_size, capacity)
    return state


def sample(state: HostUniformState, key: np.random.Generator, batch_size: int) -> ReplaySample:
    """``batch_size`` transitions drawn uniformly with replacement."""
    indices = key.integers(0, max(state.size, 1), batch_size)
    transition = jax.tree.map(lambda s: s[indices], state.storage)
    return ReplaySample(transition=transition, indices=indices, weights=np.ones(batch_size, np.float32))


def init_prioritized(
    capacity: int, example_transition: Any, priority_exponent: float = 0.6, priority_epsilon: float = 1e-6
) -> HostPrioritizedState:
    """An empty prioritized buffer (see ``agentax.replay.prioritized``)."""
    return HostPrioritizedState(
        buffer=init(capacity, example_transition),
        tree=np.zeros(2 * tree_size(capacity)),
        priority_exponent=priority_exponent,
        priority_epsilon=priority_epsilon,
    )


def add_prioritized(state: HostPrioritizedState, batch: Any) -> HostPrioritizedState:
    """Append ``batch`` with the maximum priority seen so far."""
    batch_size = len(jax.tree.leaves(batch)[0])
    indices = _write_indices(state.buffer, batch_size)
    set_leaves(state.tree, indices, np.full(batch_size, state.max_priority**state.priority_exponent))
    add(state.buffer, batch)
    return state


def sample_prioritized(
    state: HostPrioritizedState, key: np.random.Generator, batch_size: int, beta: float = 1.0
) -> ReplaySample:
    """``batch_size`` transitions drawn with probability ``∝ p^ζ`` (stratified), with their weights."""
    mass_total = state.tree[1]
    points = (np.arange(batch_size) + key.uniform(size=batch_size)) * (mass_total / batch_size)
    indices = find_prefix_sum(state.tree, np.minimum(points, mass_total * (1 - 1e-9)))
    indices = np.clip(indices, 0, max(state.buffer.size - 1, 0))
    probability = state.tree[len(state.tree) // 2 + indices] / mass_total
    weights = (state.buffer.size * probability) ** (-beta)
    transition = jax.tree.map(lambda s: s[indices], state.buffer.storage)
    return ReplaySample(
        transition=transition, indices=indices, weights=(weights / weights.max()).astype(np.float32)
    )


def update_priorities(
    state: HostPrioritizedState, indices: np.ndarray, td_error: np.ndarray
) -> HostPrioritizedState:
    """Slots ``indices`` get priority ``|td_error| + ε``."""
    priority = np.abs(np.asarray(td_error, np.float64)) + state.priority_epsilon
    set_leaves(state.tree, np.asarray(indices), priority**state.priority_exponent)
    state.max_priority = max(state.max_priority, float(priority.max()))
    return state


class ReplayBuffer(Dataset):
    """A host replay buffer (uniform or prioritized) that actor and learner threads can share.

    TF-Agents' vocabulary: ``add_batch`` (an observer of the Driver adds through it), ``sample``,
    ``update_priorities``, and ``as_dataset(sample_batch_size)``, an iterator of sampled batches
    drawn ahead. Every access holds one lock, so a sample never sees half a write.
    """

    def __init__(
        self,
        capacity: int,
        example_transition: Any,
        *,
        prioritized: bool = False,
        priority_exponent: float = 0.6,
        seed: int = 0,
    ):
        self.prioritized = prioritized
        if prioritized:
            self.state: Any = init_prioritized(capacity, example_transition, priority_exponent)
        else:
            self.state = init(capacity, example_transition)
        self.rng = np.random.default_rng(seed)
        self.lock = threading.RLock()

    @property
    def size(self) -> int:
        return self.state.buffer.size if self.prioritized else self.state.size

    @property
    def nbytes(self) -> int:
        """Bytes the buffer's arrays hold."""
        uniform = self.state.buffer if self.prioritized else self.state
        tree = self.state.tree.nbytes if self.prioritized else 0
        return tree + sum(leaf.nbytes for leaf in jax.tree.leaves(uniform.storage))

    def state_dict(self) -> dict[str, np.ndarray]:
        """Every array (not copies) and counter as NumPy arrays, for a checkpoint."""
        with self.lock:
            uniform = self.state.buffer if self.prioritized else self.state
            names = [
                jax.tree_util.keystr(path) for path, _ in jax.tree_util.tree_leaves_with_path(uniform.storage)
            ]
            state = {
                f"storage{name}": leaf
                for name, leaf in zip(names, jax.tree.leaves(uniform.storage), strict=True)
            }
            state["counters"] = np.array([uniform.position, uniform.size])
            if self.prioritized:
                state["tree"], state["max_priority"] = self.state.tree, np.float64(self.state.max_priority)
            state["rng"] = np.array(json.dumps(self.rng.bit_generator.state))
            return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned, into a buffer made with the same settings."""
        with self.lock:
            uniform = self.state.buffer if self.prioritized else self.state
            paths = jax.tree_util.tree_leaves_with_path(uniform.storage)
            for path, leaf in paths:
                got = np.asarray(state[f"storage{jax.tree_util.keystr(path)}"])
                if got.shape != leaf.shape or got.dtype != leaf.dtype:
                    raise ValueError(
                        f"replay array {jax.tree_util.keystr(path)} is {got.dtype}{list(got.shape)}"
                    )
                leaf[...] = got
            uniform.position, uniform.size = (int(x) for x in state["counters"])
            if self.prioritized:
                self.state.tree[...] = state["tree"]
                self.state.max_priority = float(state["max_priority"])
            self.rng.bit_generator.state = json.loads(str(state["rng"]))

    def add_batch(self, batch: Any, envs: Any = None) -> None:
        """Add transitions ``[batch, ...]``. ``envs`` (which env streams they come from) is ignored:
        this buffer keeps whole transitions, not streams (``FrameReplayBuffer`` needs it)."""
        with self.lock:
            (add_prioritized if self.prioritized else add)(self.state, batch)

    def sample(self, batch_size: int, beta: float = 1.0) -> ReplaySample:
        """``batch_size`` transitions: uniformly, or ∝ priority with importance weights (exponent β)."""
        with self.lock:
            if self.prioritized:
                return sample_prioritized(self.state, self.rng, batch_size, beta)
            return sample(self.state, self.rng, batch_size)

    def update_priorities(self, indices: np.ndarray, td_error: np.ndarray) -> None:
        if self.prioritized:
            with self.lock:
                update_priorities(self.state, indices, td_error)


class NStepAccumulator:
    """The NumPy twin of :mod:`agentax.replay.nstep` for host loops: the same n-step transitions,
    without a device round trip per env step. ``push`` returns them ``[num_envs]`` once the window of
    the last ``n`` one-step batches is full, else None."""

    def __init__(self, n: int, discount_factor: float):
        if n < 1:
            raise ValueError(f"n-step returns need n >= 1, got {n}")
        self.window: collections.deque = collections.deque(maxlen=n)
        self.discounts = (np.float32(discount_factor) ** np.arange(n, dtype=np.float32))[:, None]

    def push(self, batch: Any) -> Any:
        self.window.append(batch)
        if len(self.window) < self.window.maxlen:
            return None
        window = self.window
        reward = np.stack([t.reward for t in window])  # [n, num_envs]
        terminated = np.stack([t.terminated for t in window])
        truncated = np.stack([t.truncated for t in window])
        done = terminated | truncated
        alive = (np.cumsum(done, axis=0) - done) == 0  # no episode ended strictly before step i
        last = alive.sum(axis=0) - 1  # [num_envs]: the window's last step inside the episode
        envs = np.arange(reward.shape[1])
        return window[0].replace(
            reward=np.sum(alive * self.discounts * reward, axis=0, dtype=np.float32),
            next_obs=np.stack([t.next_obs for t in window])[last, envs],
            terminated=terminated[last, envs],
            truncated=truncated[last, envs],
            num_steps=(last + 1).astype(np.int32),
        )
