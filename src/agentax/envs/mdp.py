"""Markov chains and Markov decision processes as tables, and any tabular MDP as a steppable env.

Two storage forms of the same MDP, each a ``flax.struct`` pytree so it passes into ``jit``:

- :class:`TabularMDP` (dense): ``T[s, a, s']`` and ``R[s, a, s']`` (or ``R[s, a]``) — the lecture's
  notation, right for small MDPs and for dense random ones.
- :class:`SparseMDP`: for each ``(s, a)`` the ``K`` possible next states with their probabilities and
  rewards, arrays ``[S, A, K]`` — a 100×100 gridworld or FrozenLake 8x8 never builds ``S × A × S``.

Both answer the same questions (``expected_rewards``, ``expected_next_values``, ``sample``), so
the planning and learning code in :mod:`agentax.tabular` takes either.

Conventions. ``possible_actions[s, a]`` masks the actions a state allows (the lecture's
``possible_actions``); the table rows of impossible actions are stored as a self-loop with reward 0,
which is also what :class:`MDPEnv` does when an agent takes one: nothing happens, time passes.
``terminal[s]`` marks absorbing states whose value is 0: reaching one ends the episode. The validated
constructors are :meth:`TabularMDP.create` and :meth:`SparseMDP.create`; they raise
:class:`~agentax.errors.UsageError` naming the offending row or entry.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.envs.core import Discrete, Environment, TimeStep
from agentax.errors import UsageError

Array = jax.Array
PROBABILITY_TOL = 1e-5  # how far a probability row may sum from 1 (float32 tables)


def _as_state_mask(states: Any, num_states: int, what: str) -> np.ndarray:
    """A bool ``[S]`` mask from either a mask or a list of state indices."""
    if states is None:
        return np.zeros(num_states, bool)
    states = np.asarray(states)
    if states.dtype == bool:
        if states.shape != (num_states,):
            raise UsageError(f"{what} mask has shape {states.shape}, expected ({num_states},)")
        return states
    mask = np.zeros(num_states, bool)
    for s in states.reshape(-1):
        if not 0 <= int(s) < num_states:
            raise UsageError(f"{what} lists state {int(s)}, outside 0..{num_states - 1}")
        mask[int(s)] = True
    return mask


def _check_distribution_rows(probabilities: np.ndarray, rows: np.ndarray, what: str) -> None:
    """Raise unless every selected row of ``probabilities [..., N]`` is a probability distribution."""
    if not np.all(np.isfinite(probabilities)):
        index = tuple(int(i) for i in np.argwhere(~np.isfinite(probabilities))[0])
        raise UsageError(f"{what}{list(index)} is not a finite number")
    negative = (probabilities < 0) & rows[..., None]
    if negative.any():
        index = tuple(int(i) for i in np.argwhere(negative)[0])
        raise UsageError(
            f"{what}{list(index)} = {probabilities[index]:.6g} is negative; probabilities must be >= 0"
        )
    sums = probabilities.sum(-1)
    bad = rows & (np.abs(sums - 1.0) > PROBABILITY_TOL)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        raise UsageError(f"{what}{list(index)} sums to {sums[index]:.6g}, not 1")


def _initial_distribution(initial_distribution: Any, terminal: np.ndarray) -> np.ndarray:
    num_states = terminal.shape[0]
    if initial_distribution is None:
        initial_distribution = np.eye(num_states)[0]
    initial_distribution = np.asarray(initial_distribution, np.float64)
    if initial_distribution.shape != (num_states,):
        raise UsageError(
            f"initial_distribution has shape {initial_distribution.shape}, expected ({num_states},)"
        )
    _check_distribution_rows(initial_distribution, np.array(True), "initial_distribution")
    if np.any((initial_distribution > 0) & terminal):
        s = int(np.argmax((initial_distribution > 0) & terminal))
        raise UsageError(f"initial_distribution puts probability on terminal state {s}")
    return initial_distribution


def _possible_actions(possible_actions: Any, num_states: int, num_actions: int) -> np.ndarray:
    """A bool ``[S, A]`` mask from a mask or the lecture's lists of action indices per state."""
    if possible_actions is None:
        return np.ones((num_states, num_actions), bool)
    if isinstance(possible_actions, np.ndarray | jax.Array) and np.asarray(possible_actions).dtype == bool:
        mask = np.asarray(possible_actions)
    else:
        if len(possible_actions) != num_states:
            raise UsageError(
                f"possible_actions has {len(possible_actions)} rows, expected one per state ({num_states})"
            )
        mask = np.zeros((num_states, num_actions), bool)
        for s, actions in enumerate(possible_actions):
            for a in actions:
                if not 0 <= int(a) < num_actions:
                    raise UsageError(f"possible_actions[{s}] lists action {a}, outside 0..{num_actions - 1}")
                mask[s, int(a)] = True
    if mask.shape != (num_states, num_actions):
        raise UsageError(f"possible_actions has shape {mask.shape}, expected ({num_states}, {num_actions})")
    if not mask.any(-1).all():
        s = int(np.argmin(mask.any(-1)))
        raise UsageError(f"state {s} has no possible action; every state needs at least one")
    return mask


def _nested_table(transition_probabilities: Any) -> tuple[np.ndarray, np.ndarray]:
    """``T [S, A, S]`` and the mask of rows given, from nested lists with ``None`` for impossible actions."""
    rows = list(transition_probabilities)
    num_states = len(rows)
    num_actions = max((len(r) for r in rows if r is not None), default=0)
    if num_states == 0 or num_actions == 0:
        raise UsageError("an MDP needs at least one state and one action")
    given = np.ones((num_states, num_actions), bool)
    matrix = np.zeros((num_states, num_actions, num_states))
    for s, row in enumerate(rows):
        if row is None or len(row) != num_actions:
            raise UsageError(
                f"transition_probabilities[{s}] has {0 if row is None else len(row)} actions, "
                f"expected {num_actions}"
            )
        for a, probabilities in enumerate(row):
            if probabilities is None:
                given[s, a] = False
                continue
            probabilities = np.asarray(probabilities, np.float64)
            if probabilities.shape != (num_states,):
                raise UsageError(
                    f"transition_probabilities[{s}][{a}] has shape {probabilities.shape}, "
                    f"expected ({num_states},): one probability per next state"
                )
            matrix[s, a] = probabilities
    return matrix, given


@struct.dataclass
class MarkovChain:
    """A Markov chain: ``transition_probabilities[s, s']``, and ``terminal[s]`` states it never leaves."""

    transition_probabilities: Array  # [S, S]
    terminal: Array  # [S] bool

    @classmethod
    def create(cls, transition_probabilities: Any, terminal_states: Any = None) -> MarkovChain:
        """Validated chain; by default the terminal states are those with ``T[s, s] = 1``."""
        matrix = np.asarray(transition_probabilities, np.float64)
        if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1]:
            raise UsageError(
                f"a Markov chain needs a square [S, S] transition matrix, got shape {matrix.shape}"
            )
        _check_distribution_rows(matrix, np.ones(matrix.shape[0], bool), "transition_probabilities")
        if terminal_states is None:
            terminal = np.isclose(np.diag(matrix), 1.0)
        else:
            terminal = _as_state_mask(terminal_states, matrix.shape[0], "terminal_states")
        return cls(jnp.asarray(matrix, jnp.float32), jnp.asarray(terminal))

    @property
    def num_states(self) -> int:
        return self.transition_probabilities.shape[0]

    def simulate(self, key: Array, start: Any, max_steps: int) -> Array:
        """A sampled path ``[max_steps + 1]`` of states from ``start``; it stays put once terminal.

        ``max_steps`` fixes the array length, so it must be a Python int (static under ``jit``).
        """
        logits = jnp.log(self.transition_probabilities)

        def step(state, step_key):
            next_state = jax.random.categorical(step_key, logits[state])
            next_state = jnp.where(self.terminal[state], state, next_state).astype(jnp.int32)
            return next_state, next_state

        start = jnp.asarray(start, jnp.int32)
        _, path = jax.lax.scan(step, start, jax.random.split(key, max_steps))
        return jnp.concatenate([start[None], path])


def lecture_markov_chain() -> MarkovChain:
    """The lecture's 4-state Markov chain; s3 is terminal."""
    return MarkovChain.create(
        [
            [0.7, 0.2, 0.0, 0.1],
            [0.0, 0.0, 0.9, 0.1],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


@struct.dataclass
class TabularMDP:
    """A dense MDP: ``T[s, a, s']``, ``R[s, a, s']`` (or ``R[s, a]``), masks and start distribution.

    Build one with :meth:`create` (validated); the plain constructor trusts its arrays.
    """

    transition_probabilities: Array  # [S, A, S] float32
    rewards: Array  # [S, A, S] float32, or [S, A] when the reward does not depend on s'
    possible_actions: Array  # [S, A] bool
    initial_distribution: Array  # [S] float32
    terminal: Array  # [S] bool

    @classmethod
    def create(
        cls,
        transition_probabilities: Any,
        rewards: Any,
        possible_actions: Any = None,
        initial_distribution: Any = None,
        terminal_states: Any = None,
    ) -> TabularMDP:
        """Validate and build. ``transition_probabilities`` may hold ``None`` for impossible actions
        (the lecture's format); ``possible_actions`` is a bool ``[S, A]`` mask or a list of action
        indices per state (default: all actions, or those whose row is not ``None``);
        ``initial_distribution`` defaults to starting in state 0; ``terminal_states`` is a mask or a
        list of state indices (default: none).
        """
        if isinstance(transition_probabilities, np.ndarray | jax.Array):
            matrix = np.asarray(transition_probabilities, np.float64)
            if matrix.ndim != 3 or matrix.shape[0] != matrix.shape[2]:
                raise UsageError(f"transition_probabilities has shape {matrix.shape}, expected [S, A, S]")
            inferred = np.ones(matrix.shape[:2], bool)
        else:
            matrix, inferred = _nested_table(transition_probabilities)
        num_states, num_actions = inferred.shape
        mask = _possible_actions(
            inferred if possible_actions is None else possible_actions, num_states, num_actions
        )
        if np.any(mask & ~inferred):
            s, a = (int(i) for i in np.argwhere(mask & ~inferred)[0])
            raise UsageError(f"action {a} is possible in state {s} but its transition row is None")
        _check_distribution_rows(matrix, mask, "transition_probabilities")
        rewards = np.asarray(rewards, np.float64)
        if rewards.shape not in ((num_states, num_actions, num_states), (num_states, num_actions)):
            raise UsageError(
                f"rewards has shape {rewards.shape}, expected ({num_states}, {num_actions}, {num_states}) "
                f"or ({num_states}, {num_actions}) to match the transition table"
            )
        if not np.all(np.isfinite(rewards)):
            raise UsageError(
                f"rewards{[int(i) for i in np.argwhere(~np.isfinite(rewards))[0]]} is not finite"
            )
        terminal = _as_state_mask(terminal_states, num_states, "terminal_states")
        start = _initial_distribution(initial_distribution, terminal)
        self_loop = np.broadcast_to(np.eye(num_states)[:, None, :], matrix.shape)
        matrix = np.where(mask[..., None], matrix, self_loop)
        rewards = np.where(mask[..., None] if rewards.ndim == 3 else mask, rewards, 0.0)
        return cls(
            jnp.asarray(matrix, jnp.float32),
            jnp.asarray(rewards, jnp.float32),
            jnp.asarray(mask),
            jnp.asarray(start, jnp.float32),
            jnp.asarray(terminal),
        )

    @property
    def num_states(self) -> int:
        return self.transition_probabilities.shape[0]

    @property
    def num_actions(self) -> int:
        return self.transition_probabilities.shape[1]

    def expected_rewards(self) -> Array:
        """``Σ_s' T(s, a, s') R(s, a, s')``: ``[S, A]``."""
        if self.rewards.ndim == 2:
            return self.rewards
        return jnp.einsum("sat,sat->sa", self.transition_probabilities, self.rewards)

    def expected_next_values(self, values: Array) -> Array:
        """``Σ_s' T(s, a, s') V(s')`` for ``values: [S]``: ``[S, A]``."""
        return jnp.einsum("sat,t->sa", self.transition_probabilities, values)

    def sample(self, key: Array, state: Array, action: Array) -> tuple[Array, Array]:
        """One transition from ``(state, action)``: ``(next_state, reward)``."""
        next_state = jax.random.categorical(key, jnp.log(self.transition_probabilities[state, action]))
        reward = (
            self.rewards[state, action] if self.rewards.ndim == 2 else self.rewards[state, action, next_state]
        )
        return next_state.astype(jnp.int32), reward

    def successors_within(self, states: np.ndarray) -> np.ndarray:
        """Host-side: ``[S, A]`` bool, whether every possible next state of ``(s, a)`` is in ``states``."""
        transition_probabilities = np.asarray(self.transition_probabilities)
        return ~np.any((transition_probabilities > 0) & ~states, axis=-1)

    def to_sparse(self) -> SparseMDP:
        """The same MDP as a :class:`SparseMDP`, with ``K`` the most next states any ``(s, a)`` has."""
        transition_probabilities = np.asarray(self.transition_probabilities)
        k = max(int((transition_probabilities > 0).sum(-1).max()), 1)
        next_states = np.argsort(-transition_probabilities, axis=-1, kind="stable")[..., :k]
        probabilities = np.take_along_axis(transition_probabilities, next_states, -1)
        rewards = np.asarray(self.rewards)
        if rewards.ndim == 3:
            rewards = np.take_along_axis(rewards, next_states, -1)
        else:
            rewards = np.broadcast_to(rewards[..., None], next_states.shape)
        return SparseMDP(
            jnp.asarray(next_states, jnp.int32),
            jnp.asarray(probabilities, jnp.float32),
            jnp.asarray(rewards, jnp.float32),
            self.possible_actions,
            self.initial_distribution,
            self.terminal,
        )


@struct.dataclass
class SparseMDP:
    """An MDP as, for each ``(s, a)``, ``K`` next states with their probabilities and rewards.

    Entries with probability 0 pad rows that have fewer than ``K`` successors; a next state may
    appear twice in a row (Gymnasium's slippery FrozenLake lists one outcome per direction).
    """

    next_states: Array  # [S, A, K] int32
    probabilities: Array  # [S, A, K] float32
    rewards: Array  # [S, A, K] float32
    possible_actions: Array  # [S, A] bool
    initial_distribution: Array  # [S] float32
    terminal: Array  # [S] bool

    @classmethod
    def create(
        cls,
        next_states: Any,
        probabilities: Any,
        rewards: Any,
        possible_actions: Any = None,
        initial_distribution: Any = None,
        terminal_states: Any = None,
    ) -> SparseMDP:
        """Validate and build from ``[S, A, K]`` arrays (see :meth:`TabularMDP.create` for the rest)."""
        next_states = np.asarray(next_states)
        probabilities = np.asarray(probabilities, np.float64)
        rewards = np.asarray(rewards, np.float64)
        if (
            next_states.ndim != 3
            or probabilities.shape != next_states.shape
            or rewards.shape != next_states.shape
        ):
            raise UsageError(
                f"next_states, probabilities and rewards must share one [S, A, K] shape, got "
                f"{next_states.shape}, {probabilities.shape} and {rewards.shape}"
            )
        num_states, num_actions, _ = next_states.shape
        if not np.issubdtype(next_states.dtype, np.integer):
            raise UsageError(f"next_states must hold integer state indices, got dtype {next_states.dtype}")
        outside = (next_states < 0) | (next_states >= num_states)
        if outside.any():
            index = [int(i) for i in np.argwhere(outside)[0]]
            raise UsageError(
                f"next_states{index} = {next_states[tuple(index)]} is outside 0..{num_states - 1}"
            )
        mask = _possible_actions(possible_actions, num_states, num_actions)
        _check_distribution_rows(probabilities, mask, "probabilities")
        if not np.all(np.isfinite(rewards)):
            raise UsageError(
                f"rewards{[int(i) for i in np.argwhere(~np.isfinite(rewards))[0]]} is not finite"
            )
        terminal = _as_state_mask(terminal_states, num_states, "terminal_states")
        start = _initial_distribution(initial_distribution, terminal)
        self_loop = np.zeros_like(probabilities)
        self_loop[..., 0] = 1.0
        own_state = np.broadcast_to(np.arange(num_states)[:, None, None], next_states.shape)
        impossible = ~mask[..., None]
        return cls(
            jnp.asarray(np.where(impossible, own_state, next_states), jnp.int32),
            jnp.asarray(np.where(impossible, self_loop, probabilities), jnp.float32),
            jnp.asarray(np.where(impossible, 0.0, rewards), jnp.float32),
            jnp.asarray(mask),
            jnp.asarray(start, jnp.float32),
            jnp.asarray(terminal),
        )

    @property
    def num_states(self) -> int:
        return self.next_states.shape[0]

    @property
    def num_actions(self) -> int:
        return self.next_states.shape[1]

    def expected_rewards(self) -> Array:
        return jnp.sum(self.probabilities * self.rewards, -1)

    def expected_next_values(self, values: Array) -> Array:
        return jnp.sum(self.probabilities * values[self.next_states], -1)

    def sample(self, key: Array, state: Array, action: Array) -> tuple[Array, Array]:
        k = jax.random.categorical(key, jnp.log(self.probabilities[state, action]))
        return self.next_states[state, action, k], self.rewards[state, action, k]

    def successors_within(self, states: np.ndarray) -> np.ndarray:
        inside = states[np.asarray(self.next_states)] | (np.asarray(self.probabilities) == 0)
        return inside.all(-1)

    def to_dense(self) -> TabularMDP:
        """The same MDP as a :class:`TabularMDP` (duplicate next states merged: probabilities add,
        rewards average weighted by probability, so expected rewards are unchanged)."""
        num_states, num_actions, _ = self.next_states.shape
        next_states = np.asarray(self.next_states)
        probabilities = np.asarray(self.probabilities, np.float64)
        s, a = np.indices(next_states.shape[:2])
        matrix = np.zeros((num_states, num_actions, num_states))
        weighted_rewards = np.zeros_like(matrix)
        for k in range(next_states.shape[-1]):
            np.add.at(matrix, (s, a, next_states[..., k]), probabilities[..., k])
            np.add.at(
                weighted_rewards,
                (s, a, next_states[..., k]),
                probabilities[..., k] * np.asarray(self.rewards)[..., k],
            )
        rewards = np.divide(weighted_rewards, matrix, out=np.zeros_like(matrix), where=matrix > 0)
        return TabularMDP(
            jnp.asarray(matrix, jnp.float32),
            jnp.asarray(rewards, jnp.float32),
            self.possible_actions,
            self.initial_distribution,
            self.terminal,
        )


MDP = TabularMDP | SparseMDP


def improper_states(mdp: MDP) -> np.ndarray:
    """Host-side: bool ``[S]``, the states from which some policy can avoid every terminal state forever.

    The largest set ``C`` of non-terminal states in which every state has a possible action whose
    successors all stay in ``C``: a policy choosing those actions never terminates from ``C``, and
    outside ``C`` every policy terminates with probability 1. With a discount factor of 1 values are
    only finite when ``C`` is empty (every policy terminates).
    """
    trapped = ~np.asarray(mdp.terminal)
    possible = np.asarray(mdp.possible_actions)
    if trapped.all():
        return trapped
    while True:
        keep = trapped & (mdp.successors_within(trapped) & possible).any(-1)
        if np.array_equal(keep, trapped):
            return trapped
        trapped = keep


def check_discount_factor(mdp: MDP, discount_factor: float) -> None:
    """Raise :class:`UsageError` unless ``0 <= discount_factor <= 1`` (1 only if every policy terminates)."""
    if not 0.0 <= float(discount_factor) <= 1.0:
        raise UsageError(f"discount factor {discount_factor} is outside [0, 1]")
    if float(discount_factor) == 1.0:
        trapped = improper_states(mdp)
        if trapped.any():
            raise UsageError(
                "discount factor 1 needs every policy to terminate, but from state "
                f"{int(np.argmax(trapped))} a policy can run forever; use a discount factor below 1"
            )


def lecture_mdp() -> TabularMDP:
    """The lecture's 3-state MDP (Hands-On ML, chapter 18); it never terminates."""
    transition_probabilities = [
        [[0.7, 0.3, 0.0], [1.0, 0.0, 0.0], [0.8, 0.2, 0.0]],
        [[0.0, 1.0, 0.0], None, [0.0, 0.0, 1.0]],
        [None, [0.8, 0.1, 0.1], None],
    ]
    rewards = [
        [[+10, 0, 0], [0, 0, 0], [0, 0, 0]],
        [[0, 0, 0], [0, 0, 0], [0, 0, -50]],
        [[0, 0, 0], [+40, 0, 0], [0, 0, 0]],
    ]
    return TabularMDP.create(transition_probabilities, rewards, possible_actions=[[0, 1, 2], [0, 2], [1]])


def chain_mdp(num_states: int = 10, reward: float = 1.0, slip: float = 0.0) -> TabularMDP:
    """A corridor: start at state 0, action 0 moves left, 1 moves right; reaching the far end
    (state ``num_states - 1``, terminal) pays ``reward``, every other step pays 0. With ``slip`` the
    move goes the other way. Hard for random exploration: it needs ~``num_states²`` steps to get there.
    """
    if num_states < 2:
        raise UsageError(f"a chain needs at least 2 states, got {num_states}")
    matrix = np.zeros((num_states, 2, num_states))
    rewards = np.zeros_like(matrix)
    for s in range(num_states):
        left, right = max(s - 1, 0), min(s + 1, num_states - 1)
        for a, (intended, other) in enumerate([(left, right), (right, left)]):
            matrix[s, a, intended] += 1.0 - slip
            matrix[s, a, other] += slip
    rewards[:, :, num_states - 1] = reward
    return TabularMDP.create(matrix, rewards, terminal_states=[num_states - 1])


def gridworld(size: int = 100, slip: float = 0.1, step_reward: float = -1.0) -> SparseMDP:
    """A ``size × size`` grid, sparse: start top-left, the bottom-right cell is terminal. Actions
    0-3 = up, right, down, left; with probability ``slip`` the move goes in a uniformly random
    direction instead (walls keep the agent in place). Every step pays ``step_reward``.
    """
    rows, cols = np.divmod(np.arange(size * size), size)
    moves = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]])
    targets = np.stack(
        [np.clip(rows + dr, 0, size - 1) * size + np.clip(cols + dc, 0, size - 1) for dr, dc in moves], -1
    )  # [S, 4]
    next_states = np.concatenate(
        [targets[:, :, None], np.broadcast_to(targets[:, None, :], (size * size, 4, 4))], -1
    )  # [S, A, 5]: the intended move, then each direction under slip
    probabilities = np.broadcast_to(np.array([1.0 - slip] + [slip / 4] * 4), next_states.shape)
    return SparseMDP.create(
        next_states,
        probabilities,
        np.full(next_states.shape, step_reward),
        terminal_states=[size * size - 1],
    )


def random_mdp(seed: int, num_states: int, num_actions: int) -> TabularMDP:
    """A dense random MDP: each row ``T[s, a]`` is a normalised uniform(0, 1) vector over all next
    states, rewards ``R[s, a]`` uniform(0, 1), start uniform, no terminal state. Drawn with NumPy's
    generator in float32 (a 10,000 × 8 table is 3.2 GB; JAX's counter-based keys take minutes)."""
    rng = np.random.default_rng(seed)
    matrix = np.empty((num_states, num_actions, num_states), np.float32)
    block = max(1, 2**24 // (num_actions * num_states))  # rows per draw: no float64 temporaries
    for start in range(0, num_states, block):
        rows = rng.random((min(block, num_states - start), num_actions, num_states), dtype=np.float32)
        matrix[start : start + block] = rows / rows.sum(-1, keepdims=True)
    rewards = rng.random((num_states, num_actions), dtype=np.float32)
    return TabularMDP(
        jax.device_put(matrix),  # one copy (jnp.asarray would make two of a 3.2 GB table)
        jnp.asarray(rewards),
        jnp.ones((num_states, num_actions), bool),
        jnp.full((num_states,), 1.0 / num_states, jnp.float32),
        jnp.zeros((num_states,), bool),
    )


def from_gymnasium(env: Any, sparse: bool = False) -> MDP:
    """An MDP from a Gymnasium toy-text env (anything with ``unwrapped.P``) or its id.

    ``P[s][a]`` lists ``(probability, next_state, reward, done)``; a state that a ``done``
    transition reaches becomes terminal (absorbing, value 0), and its own rows are kept but never
    used. Every state reachable from the start must then reach terminal states only by ``done``
    transitions (Taxi's states with the passenger already delivered are unreachable and left as
    they are). Dense by default; ``sparse=True`` keeps Gymnasium's per-outcome lists as ``[S, A, K]``.
    """
    import gymnasium

    if isinstance(env, str):
        env = gymnasium.make(env)
    unwrapped = env.unwrapped
    if not hasattr(unwrapped, "P"):
        raise UsageError(f"{unwrapped} has no transition table P; only toy-text style envs convert to an MDP")
    num_states, num_actions = int(unwrapped.observation_space.n), int(unwrapped.action_space.n)
    k = max(len(unwrapped.P[s][a]) for s in range(num_states) for a in range(num_actions))
    next_states = np.tile(np.arange(num_states)[:, None, None], (1, num_actions, k))
    probabilities = np.zeros((num_states, num_actions, k))
    rewards = np.zeros((num_states, num_actions, k))
    done = np.zeros((num_states, num_actions, k), bool)
    for s in range(num_states):
        for a in range(num_actions):
            for i, (probability, next_state, reward, is_done) in enumerate(unwrapped.P[s][a]):
                next_states[s, a, i], probabilities[s, a, i], rewards[s, a, i] = (
                    next_state,
                    probability,
                    reward,
                )
                done[s, a, i] = is_done
    terminal = np.zeros(num_states, bool)
    terminal[next_states[done & (probabilities > 0)]] = True
    start = getattr(unwrapped, "initial_state_distrib", None)
    reachable = np.ones(num_states, bool) if start is None else np.asarray(start) > 0
    while True:
        sources = reachable & ~terminal
        grown = reachable.copy()
        grown[next_states[sources][probabilities[sources] > 0]] = True
        if np.array_equal(grown, reachable):
            break
        reachable = grown
    slipped = (reachable & ~terminal)[:, None, None] & ~done & (probabilities > 0) & terminal[next_states]
    if slipped.any():
        s, a, i = (int(x) for x in np.argwhere(slipped)[0])
        raise UsageError(
            f"P[{s}][{a}] reaches state {next_states[s, a, i]} without done, though other transitions "
            "end the episode there; such an env has no tabular form with terminal states"
        )
    mdp = SparseMDP.create(next_states, probabilities, rewards, None, start, terminal)
    return mdp if sparse else mdp.to_dense()


def frozenlake(map_name: str = "4x4", is_slippery: bool = True, sparse: bool = False) -> MDP:
    """Gymnasium's ``FrozenLake-v1`` (``map_name`` "4x4" or "8x8")."""
    return from_gymnasium(_make("FrozenLake-v1", map_name=map_name, is_slippery=is_slippery), sparse)


def taxi(sparse: bool = False) -> MDP:
    """Gymnasium's ``Taxi-v4`` (500 states, 6 actions)."""
    return from_gymnasium(_make("Taxi-v4"), sparse)


def cliffwalking(sparse: bool = False) -> MDP:
    """Gymnasium's ``CliffWalking-v1`` (48 states, 4 actions; the cliff sends the agent back to the start)."""
    return from_gymnasium(_make("CliffWalking-v1"), sparse)


def _make(env_id: str, **kwargs: Any) -> Any:
    import gymnasium

    return gymnasium.make(env_id, **kwargs)


@struct.dataclass
class MDPEnvParams:
    mdp: TabularMDP | SparseMDP
    max_steps_in_episode: int = 1000


@struct.dataclass
class MDPEnvState:
    state: Array  # int32 []: the MDP state
    time: Array  # int32 []: steps taken in this episode


class MDPEnv(Environment):
    """Any tabular MDP as a steppable env: ``Discrete(S)`` observations, ``Discrete(A)`` actions.

    An episode starts from ``mdp.initial_distribution``, is terminated on reaching a terminal state
    and truncated after ``max_steps_in_episode`` steps. An impossible action (``possible_actions``
    false) is a no-op: the agent stays where it is, gets reward 0, and the step counts toward the
    time limit.
    """

    def __init__(self, mdp: MDP, max_steps_in_episode: int = 1000, id: str = "MDP-v0"):
        self.mdp = mdp
        self.max_steps_in_episode = max_steps_in_episode
        self.id = id

    def default_params(self) -> MDPEnvParams:
        return MDPEnvParams(self.mdp, self.max_steps_in_episode)

    def reset_env(self, key: Array, params: MDPEnvParams) -> tuple[Array, MDPEnvState]:
        state = jax.random.categorical(key, jnp.log(params.mdp.initial_distribution)).astype(jnp.int32)
        return state, MDPEnvState(state, jnp.int32(0))

    def step_env(
        self, key: Array, state: MDPEnvState, action: Array, params: MDPEnvParams
    ) -> tuple[TimeStep, MDPEnvState]:
        next_state, reward = params.mdp.sample(key, state.state, action)
        possible = params.mdp.possible_actions[state.state, action]
        next_state = jnp.where(possible, next_state, state.state).astype(jnp.int32)
        reward = jnp.where(possible, reward, 0.0).astype(jnp.float32)
        time = state.time + 1
        terminated = params.mdp.terminal[next_state]
        truncated = (time >= params.max_steps_in_episode) & ~terminated
        return TimeStep(next_state, reward, terminated, truncated, next_state), MDPEnvState(next_state, time)

    def observation_space(self, params: MDPEnvParams | None = None) -> Discrete:
        return Discrete(self.mdp.num_states)

    def action_space(self, params: MDPEnvParams | None = None) -> Discrete:
        return Discrete(self.mdp.num_actions)


def lecture_mdp_env() -> MDPEnv:
    """``LectureMDP-v0``: the lecture's 3-state MDP from state 0, truncated after 100 steps."""
    return MDPEnv(lecture_mdp(), max_steps_in_episode=100, id="LectureMDP-v0")


__all__ = [
    "MDP",
    "MDPEnv",
    "MDPEnvParams",
    "MDPEnvState",
    "MarkovChain",
    "SparseMDP",
    "TabularMDP",
    "chain_mdp",
    "check_discount_factor",
    "cliffwalking",
    "from_gymnasium",
    "frozenlake",
    "gridworld",
    "improper_states",
    "lecture_markov_chain",
    "lecture_mdp",
    "lecture_mdp_env",
    "random_mdp",
    "taxi",
]
