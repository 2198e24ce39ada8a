"""Replay buffers: ring wrap-around, sum-tree invariants and sampling, importance weights, n-step."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agentax.replay import (
    ReplaySample,
    Transition,
    _numpy,
    example_transition,
    host,
    nstep,
    prioritized,
    uniform,
)


def batch_of(rewards, obs_dim=2):
    """Transitions whose reward (and obs, filled with it) identify them: [len(rewards)]."""
    rewards = jnp.asarray(rewards, jnp.float32)
    n = rewards.shape[0]
    return Transition(
        obs=jnp.repeat(rewards[:, None], obs_dim, axis=1),
        action=jnp.arange(n, dtype=jnp.int32) % 2,
        reward=rewards,
        next_obs=jnp.repeat(rewards[:, None], obs_dim, axis=1) + 0.5,
        terminated=jnp.zeros(n, bool),
        truncated=jnp.zeros(n, bool),
        num_steps=jnp.ones(n, jnp.int32),
    )


EXAMPLE = example_transition(jnp.zeros(2), jnp.int32(0))


def test_ring_buffer_wraps_around():
    # Capacity 5: add 10, 11, 12 (slots 0-2), then 13, 14, 15, 16 -> slots 3, 4, 0, 1.
    state = uniform.init(5, EXAMPLE)
    state = jax.jit(uniform.add)(state, batch_of([10, 11, 12]))
    assert int(state.position) == 3 and int(state.size) == 3
    state = jax.jit(uniform.add)(state, batch_of([13, 14, 15, 16]))
    np.testing.assert_array_equal(state.storage.reward, [15, 16, 12, 13, 14])
    np.testing.assert_array_equal(state.storage.obs[:, 0], [15, 16, 12, 13, 14])
    assert int(state.position) == 2 and int(state.size) == 5


def test_invalid_add_changes_nothing():
    state = uniform.add(uniform.init(4, EXAMPLE), batch_of([1, 2, 3]))
    same = uniform.add(state, batch_of([7, 8]), valid=False)
    np.testing.assert_array_equal(same.storage.reward, [1, 2, 3, 0])
    assert int(same.position) == 3 and int(same.size) == 3


def test_uniform_sample_draws_only_filled_slots():
    state = uniform.add(uniform.init(100, EXAMPLE), batch_of([1, 2, 3]))
    sample = jax.jit(uniform.sample, static_argnums=2)(state, jax.random.key(0), 1000)
    assert set(np.unique(sample.transition.reward).tolist()) == {1.0, 2.0, 3.0}
    np.testing.assert_array_equal(sample.weights, np.ones(1000))


@pytest.mark.slow
def test_host_ring_buffer_matches_jax():
    jax_state, host_state = uniform.init(5, EXAMPLE), host.init(5, jax.device_get(EXAMPLE))
    for rewards in ([1, 2, 3], [4, 5], [6, 7, 8, 9]):
        jax_state = uniform.add(jax_state, batch_of(rewards))
        host_state = host.add(host_state, jax.device_get(batch_of(rewards)))
    np.testing.assert_array_equal(host_state.storage.reward, jax_state.storage.reward)
    assert host_state.position == int(jax_state.position) and host_state.size == int(jax_state.size)


def check_sum_tree(tree):
    tree = np.asarray(tree, np.float64)
    num_leaves = len(tree) // 2
    for node in range(1, num_leaves):
        assert tree[node] == pytest.approx(tree[2 * node] + tree[2 * node + 1], rel=1e-5, abs=1e-5)
    assert tree[1] == pytest.approx(tree[num_leaves:].sum(), rel=1e-4)


updates = st.lists(
    st.tuples(
        st.lists(st.integers(0, 12), min_size=1, max_size=6), st.integers(0, 10_000).map(lambda k: k / 100)
    ),
    min_size=1,
    max_size=6,
)


set_leaves_jit = jax.jit(prioritized.set_leaves)


@settings(max_examples=25, deadline=None)
@given(capacity=st.sampled_from([1, 2, 5, 8, 13]), updates=updates)
def test_sum_tree_invariants(capacity, updates):
    """Every internal node is the sum of its children, the root the sum of the leaves (JAX and NumPy)."""
    size = prioritized.tree_size(capacity)
    assert size >= capacity and size & (size - 1) == 0 and (size == 1 or size // 2 < capacity)
    jax_tree, host_tree = jnp.zeros(2 * size), np.zeros(2 * size)
    for indices, value in updates:
        indices = np.resize(np.asarray(indices) % capacity, 6)  # one shape: compile once per tree size
        values = value + indices  # a duplicate index gets the same value: the result is well defined
        jax_tree = set_leaves_jit(jax_tree, jnp.asarray(indices), jnp.asarray(values, jnp.float32))
        host_tree = _numpy.set_leaves(host_tree, indices, values)
        check_sum_tree(jax_tree)
        check_sum_tree(host_tree)
    np.testing.assert_allclose(prioritized.leaves(jax_tree), host_tree[size:], rtol=1e-6)


def test_prefix_sum_search():
    # Leaves [1, 2, 3, 4]: cumulative sums 1, 3, 6, 10.
    tree = prioritized.set_leaves(jnp.zeros(8), jnp.arange(4), jnp.array([1.0, 2.0, 3.0, 4.0]))
    masses = jnp.array([0.0, 0.99, 1.0, 2.9, 3.0, 5.99, 6.0, 9.99])
    expected = [0, 0, 1, 1, 2, 2, 3, 3]
    np.testing.assert_array_equal(prioritized.find_prefix_sum(tree, masses), expected)
    np.testing.assert_array_equal(
        _numpy.find_prefix_sum(np.asarray(tree, np.float64), np.asarray(masses)), expected
    )


def filled_prioritized(td_errors, capacity=8, exponent=0.6):
    state = prioritized.init(capacity, EXAMPLE, priority_exponent=exponent, priority_epsilon=0.0)
    state = prioritized.add(state, batch_of(np.arange(len(td_errors), dtype=np.float32)))
    return prioritized.update_priorities(state, jnp.arange(len(td_errors)), jnp.asarray(td_errors))


@pytest.mark.slow
def test_sampling_frequencies_match_priorities():
    # p = |δ| = [1, 2, 3, 4, 0.5]; P ∝ p^0.6.
    td_errors = np.array([1.0, -2.0, 3.0, 4.0, -0.5])
    state = filled_prioritized(td_errors)
    draw = jax.jit(jax.vmap(lambda key: prioritized.sample(state, key, 64).indices))
    indices = np.asarray(draw(jax.random.split(jax.random.key(0), 500))).ravel()  # 32,000 draws
    frequencies = np.bincount(indices, minlength=8) / indices.size
    expected = np.abs(td_errors) ** 0.6 / np.sum(
        np.abs(td_errors) ** 0.6
    )  # [0.146, 0.222, 0.283, 0.336, 0.096]
    np.testing.assert_allclose(frequencies[:5], expected, atol=0.01)
    assert frequencies[5:].sum() == 0  # empty slots are never drawn


def test_host_prioritized_sampling_frequencies():
    td_errors = np.array([1.0, -2.0, 3.0, 4.0, -0.5])
    state = host.init_prioritized(8, jax.device_get(EXAMPLE), priority_exponent=0.6, priority_epsilon=0.0)
    host.add_prioritized(state, jax.device_get(batch_of(np.arange(5, dtype=np.float32))))
    host.update_priorities(state, np.arange(5), td_errors)
    rng = np.random.default_rng(0)
    indices = np.concatenate([host.sample_prioritized(state, rng, 64).indices for _ in range(500)])
    expected = np.abs(td_errors) ** 0.6 / np.sum(np.abs(td_errors) ** 0.6)
    np.testing.assert_allclose(np.bincount(indices, minlength=8)[:5] / indices.size, expected, atol=0.01)


def test_importance_weights_follow_the_formula():
    # Priorities [1, 4] with ζ = 0.5: p^ζ = [1, 2], P = [1/3, 2/3], n = 2.
    # w = (n P)^-β with β = 1: [(2/3)^-1, (4/3)^-1] = [1.5, 0.75]; / max -> [1, 0.5].
    state = filled_prioritized([1.0, 4.0], capacity=2, exponent=0.5)
    np.testing.assert_allclose(prioritized.probabilities(state, jnp.arange(2)), [1 / 3, 2 / 3], rtol=1e-6)
    sample = prioritized.sample(state, jax.random.key(3), 2, beta=1.0)  # stratified: one from each half
    np.testing.assert_array_equal(sample.indices, [0, 1])
    np.testing.assert_allclose(sample.weights, [1.0, 0.5], rtol=1e-5)
    # β = 0.5: w ∝ [(2/3)^-0.5, (4/3)^-0.5] = [1.2247, 0.8660] -> [1, 0.7071].
    np.testing.assert_allclose(
        prioritized.sample(state, jax.random.key(3), 2, beta=0.5).weights, [1, 0.70711], rtol=1e-4
    )
    host_state = host.init_prioritized(
        2, jax.device_get(EXAMPLE), priority_exponent=0.5, priority_epsilon=0.0
    )
    host.add_prioritized(host_state, jax.device_get(batch_of([0.0, 1.0])))
    host.update_priorities(host_state, np.arange(2), np.array([1.0, 4.0]))
    host_sample = host.sample_prioritized(host_state, np.random.default_rng(0), 2, beta=1.0)
    np.testing.assert_allclose(host_sample.weights, [1.0, 0.5], rtol=1e-5)


@pytest.mark.slow
def test_new_transitions_get_the_max_priority():
    state = filled_prioritized([5.0, 1.0], exponent=0.6)
    assert float(state.max_priority) == pytest.approx(5.0)
    state = prioritized.add(state, batch_of([9.0]))  # slot 2
    assert float(prioritized.leaves(state.tree)[2]) == pytest.approx(5.0**0.6, rel=1e-5)


def one_step(rewards, terminated, truncated):
    """A stream of one-step transitions of ONE env: [T] -> list of [1]-batches; obs = step index."""
    return [
        Transition(
            obs=jnp.full((1, 1), t, jnp.float32),
            action=jnp.zeros(1, jnp.int32),
            reward=jnp.full(1, r, jnp.float32),
            next_obs=jnp.full((1, 1), t + 0.5, jnp.float32),
            terminated=jnp.full(1, te),
            truncated=jnp.full(1, tr),
            num_steps=jnp.ones(1, jnp.int32),
        )
        for t, (r, te, tr) in enumerate(zip(rewards, terminated, truncated, strict=True))
    ]


def run_accumulator(stream, n, discount_factor):
    state = nstep.init(n, stream[0])
    emitted = []
    for transition in stream:
        state, out, full = jax.jit(nstep.push)(state, transition, discount_factor)
        if full:
            emitted.append(jax.tree.map(lambda x: np.asarray(x[0]), out))
    return emitted


def test_n_step_transitions_by_hand():
    # γ = 0.5, n = 3, rewards 1, 2, 3, 4, 5; step 3 (reward 4) terminates.
    stream = one_step([1, 2, 3, 4, 5], [False, False, False, True, False], [False] * 5)
    first, second, third = run_accumulator(stream, 3, 0.5)
    assert float(first.reward) == pytest.approx(1 + 0.5 * 2 + 0.25 * 3)  # 2.75
    assert int(first.num_steps) == 3 and float(first.next_obs[0]) == 2.5 and not first.terminated
    assert float(second.reward) == pytest.approx(2 + 0.5 * 3 + 0.25 * 4)  # 4.5, ends on the terminal step
    assert int(second.num_steps) == 3 and bool(second.terminated)
    assert float(third.reward) == pytest.approx(3 + 0.5 * 4)  # 5.0: the episode ended after 2 steps
    assert int(third.num_steps) == 2 and float(third.next_obs[0]) == 3.5 and bool(third.terminated)


def test_n_step_truncation_keeps_its_flag():
    stream = one_step([1, 1, 1], [False] * 3, [False, True, False])
    (first,) = run_accumulator(stream, 3, 0.9)
    assert float(first.reward) == pytest.approx(1.9) and int(first.num_steps) == 2
    assert bool(first.truncated) and not bool(first.terminated)


def test_one_step_accumulator_is_the_identity():
    stream = one_step([1, 2, 3], [False, True, False], [False] * 3)
    emitted = run_accumulator(stream, 1, 0.5)
    assert [float(t.reward) for t in emitted] == [1, 2, 3]
    assert [bool(t.terminated) for t in emitted] == [False, True, False]


def test_replay_sample_is_a_pytree():
    sample = ReplaySample(transition=batch_of([1.0]), indices=jnp.zeros(1, jnp.int32), weights=jnp.ones(1))
    assert len(jax.tree.leaves(sample)) == 9


def test_n_step_return_function():
    from agentax.returns import n_step_return

    no, yes = jnp.array([False, False, False]), jnp.array([False, True, False])
    # 2 + 0.5 · 4 + 0.25 · 8 = 6 over all 3 steps; cut after step 1 when it ends: 2 + 2 = 4 over 2.
    ret, k = n_step_return(jnp.array([2.0, 4.0, 8.0]), no, no, 0.5)
    assert (float(ret), int(k)) == (6.0, 3)
    assert tuple(map(float, n_step_return(jnp.array([2.0, 4.0, 8.0]), yes, no, 0.5))) == (4.0, 2.0)
    assert tuple(map(float, n_step_return(jnp.array([2.0, 4.0, 8.0]), no, yes, 0.5))) == (4.0, 2.0)


def test_a_full_disk_while_saving_the_replay_leaves_nothing_and_names_the_bytes(tmp_path, monkeypatch):
    """By fault injection: the disk fills as the replay file is synced. StorageFull names the
    bytes the arrays need; neither the replay file nor its temporary file is left."""
    import errno
    import os

    from agentax.errors import StorageFull
    from agentax.replay.files import save_replay
    from agentax.replay.host import ReplayBuffer

    buffer = ReplayBuffer(16, {"obs": np.zeros(3, np.float32), "reward": np.float32(0)})

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(StorageFull) as raised:
        save_replay(buffer, tmp_path / "replay-1.npz")
    assert raised.value.needed == sum(np.asanyarray(a).nbytes for a in buffer.state_dict().values()) > 0
    assert list(tmp_path.iterdir()) == []


def test_a_host_replay_larger_than_memory_is_one_line_before_anything_is_allocated():
    """CarRacing's 96×96×3 observations in SAC's default million-transition replay: a UsageError
    naming the size and the flag, not NumPy's allocation error."""
    from agentax.errors import UsageError
    from agentax.replay import host as host_replay

    one = {"obs": np.zeros(27_648, np.float32), "next_obs": np.zeros(27_648, np.float32)}
    with pytest.raises(
        UsageError, match=r"a replay of 1,000,000 transitions needs 221\.18 GB .* lower --buffer-size"
    ):
        host_replay.init(1_000_000, one)
