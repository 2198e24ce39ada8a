"""The frame-deduplicated replay against a naive one that stores whole stacks (differential tests),
then its priorities, bytes, memory refusal, checkpoints and thread safety."""

from __future__ import annotations

import threading
import time
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agentax.errors import UsageError
from agentax.replay import files, frames
from agentax.replay.core import Transition
from agentax.replay.frames import FrameReplayBuffer, required_bytes
from agentax.runners.driver import ReplayObserver

FIELDS = ("obs", "action", "reward", "next_obs", "terminated", "truncated", "num_steps")


def env_stream(seed, num_envs, stack, frame_shape, mean_length, num_steps):
    """Random one-step transitions ``[num_envs]`` of stacked random frames: episode lengths
    geometric with mean ``mean_length`` (1: every episode one step), ends terminated, truncated or
    both, first stacks padded with zeros (Dopamine), copies of the first frame (Gymnasium), the
    frames before (the Atari env after a lost life) or other frames. ``action`` is the env's step
    count, so a sampled transition names its step."""
    rng = np.random.default_rng(seed)

    def first_stack(before):
        frame = rng.integers(0, 256, (1, *frame_shape), dtype=np.uint8)
        padding = [
            np.zeros((stack - 1, *frame_shape), np.uint8),
            np.repeat(frame, stack - 1, axis=0),
            before[1:],
            rng.integers(0, 256, (stack - 1, *frame_shape), dtype=np.uint8),
        ][rng.integers(4)]
        return np.concatenate([padding, frame])

    noise = rng.integers(0, 256, (num_envs, stack, *frame_shape), dtype=np.uint8)
    obs = np.stack([first_stack(before) for before in noise])
    for step in range(num_steps):
        new_frame = rng.integers(0, 256, (num_envs, 1, *frame_shape), dtype=np.uint8)
        next_obs = np.concatenate([obs[:, 1:], new_frame], axis=1)
        ended = rng.random(num_envs) < 1 / mean_length
        kind = rng.integers(3, size=num_envs)  # 0 terminated, 1 truncated, 2 both
        yield Transition(
            obs=obs,
            action=np.full(num_envs, step, np.int32),
            reward=rng.normal(size=num_envs).astype(np.float32),
            next_obs=next_obs,
            terminated=ended & (kind != 1),
            truncated=ended & (kind != 0),
            num_steps=np.ones(num_envs, np.int32),
        )
        obs = next_obs.copy()
        for e in np.flatnonzero(ended):
            obs[e] = first_stack(next_obs[e])


class NaiveReplay:
    """Whole stacks of every step of every env, n-step returns the obvious way, frames from before
    an episode's first one zeroed (``zero_pad_starts``); the same indices ``t · num_envs + e`` over
    the last ``S`` steps of each env."""

    def __init__(self, capacity, num_envs, n_step, discount_factor, zero_pad_starts=True):
        self.slots = -(-capacity // num_envs)
        self.n_step, self.discount_factor, self.zero_pad_starts = n_step, discount_factor, zero_pad_starts
        self.history = [[] for _ in range(num_envs)]

    def add_batch(self, batch):
        for e, steps in enumerate(self.history):
            new_episode = not steps or steps[-1]["terminated"] or steps[-1]["truncated"]
            start = len(steps) if new_episode else steps[-1]["start"]
            steps.append({"start": start, **{name: np.array(getattr(batch, name)[e]) for name in FIELDS}})

    def stack_at(self, stack, start, t):
        """``stack`` (the frames of steps ``t − len + 1 … t``) without the frames before step ``start``."""
        stack = stack.copy()
        if self.zero_pad_starts:
            stack[: max(0, len(stack) - 1 - (t - start))] = 0
        return stack

    def transition(self, e, t):
        """The n-step transition from env ``e``'s step ``t``, or None while its window is open."""
        steps, reward = self.history[e], 0.0
        for k in range(1, self.n_step + 1):
            if t + k - 1 >= len(steps):
                return None
            step = steps[t + k - 1]
            reward += self.discount_factor ** (k - 1) * float(step["reward"])
            if step["terminated"] or step["truncated"]:
                break
        last, start = steps[t + k - 1], steps[t]["start"]
        return {
            "obs": self.stack_at(steps[t]["obs"], start, t),
            "action": steps[t]["action"],
            "reward": reward,
            "next_obs": self.stack_at(last["next_obs"], start, t + k),
            "terminated": last["terminated"],
            "truncated": last["truncated"],
            "num_steps": k,
        }

    def valid(self):
        """``{index: (env, step)}`` of every complete transition in the last ``S`` steps of each env."""
        out = {}
        for e, steps in enumerate(self.history):
            for t in range(max(0, len(steps) - self.slots), len(steps)):
                if self.transition(e, t) is not None:
                    out[t * len(self.history) + e] = (e, t)
        return out


def assert_same(batch, i, expected, where=""):
    for name in FIELDS:
        got = np.asarray(getattr(batch, name))[i]
        if name == "reward":
            np.testing.assert_allclose(got, expected[name], rtol=1e-5, atol=1e-6, err_msg=f"{name} {where}")
        else:
            np.testing.assert_array_equal(got, expected[name], err_msg=f"{name} {where}")


@settings(max_examples=35, deadline=None, database=None)
@given(
    seed=st.integers(0, 2**16),
    num_envs=st.integers(1, 3),
    capacity=st.integers(3, 30),
    n_step=st.integers(1, 4),
    stack=st.integers(1, 4),
    mean_length=st.sampled_from([1.0, 1.5, 3.0, 12.0, 1e9]),
    frame_slack=st.sampled_from([0.0, 0.05, 4.0]),
    prioritized=st.booleans(),
    zero_pad_starts=st.booleans(),
)
@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
def test_matches_a_buffer_of_whole_stacks(
    seed, num_envs, capacity, n_step, stack, mean_length, frame_slack, prioritized, zero_pad_starts
):
    kwargs = dict(
        stack=stack, frame_shape=(2, 3), n_step=n_step, discount_factor=0.9, prioritized=prioritized
    )
    buffer = FrameReplayBuffer(
        capacity, num_envs, frame_slack=frame_slack, zero_pad_starts=zero_pad_starts, seed=seed, **kwargs
    )
    naive = NaiveReplay(capacity, num_envs, n_step, 0.9, zero_pad_starts)
    assert buffer.slots == naive.slots
    for batch in env_stream(
        seed, num_envs, stack, (2, 3), mean_length, num_steps=6 * capacity // num_envs + 8
    ):
        buffer.add_batch(batch)
        naive.add_batch(batch)
        expected = naive.valid()
        valid = buffer.valid_indices()
        assert buffer.size == len(valid) == len(set(valid.tolist()))
        assert set(valid.tolist()) <= set(expected)
        for e in range(num_envs):  # what the frame ring lost first is the oldest steps
            kept = sorted(t for i, (f, t) in expected.items() if f == e and i in set(valid.tolist()))
            every = sorted(t for f, t in expected.values() if f == e)
            assert kept == every[len(every) - len(kept) :]
        if frame_slack >= stack:  # room for a whole first stack per step: nothing lost early
            assert set(valid.tolist()) == set(expected)
        if prioritized:  # sampleable exactly where the sum-tree has mass
            leaves = buffer.tree[len(buffer.tree) // 2 :]
            assert set(np.flatnonzero(leaves > 0).tolist()) == set(buffer.leaves(valid).tolist())
        if not len(valid):
            continue
        gathered = buffer.gather(valid)
        for i, index in enumerate(valid):
            assert_same(gathered, i, naive.transition(*expected[index]), f"index {index}")
        sample = buffer.sample(8)
        assert set(sample.indices.tolist()) <= set(valid.tolist())
        for i, index in enumerate(sample.indices):
            assert_same(sample.transition, i, naive.transition(*expected[index]), f"sampled {index}")


def test_atari_frames_and_zero_padding_at_episode_starts():
    buffer = FrameReplayBuffer(64, 2, n_step=3, discount_factor=0.99)
    naive = NaiveReplay(64, 2, 3, 0.99)
    for batch in env_stream(0, 2, 4, (84, 84), 5.0, 80):
        buffer.add_batch(batch)
        naive.add_batch(batch)
    expected, valid = naive.valid(), buffer.valid_indices()
    assert set(valid.tolist()) <= set(expected)  # 5-step episodes: 1.8 frames a step, more than F holds
    assert len(valid) > 30  # F = 32 + 2 + 4 = 38 frames per env: ~20 steps
    gathered = buffer.gather(valid)
    for i, index in enumerate(valid):
        assert_same(gathered, i, naive.transition(*expected[index]))
    sample = buffer.sample(32)
    assert sample.transition.obs.dtype == np.uint8 and sample.transition.obs.shape == (32, 4, 84, 84)
    assert sample.transition.next_obs.shape == (32, 4, 84, 84) and sample.weights.dtype == np.float32
    for i, index in enumerate(sample.indices):
        assert_same(sample.transition, i, naive.transition(*expected[index]))
    starts = [i for i in valid if naive.history[expected[i][0]][expected[i][1]]["start"] == expected[i][1]]
    env_padding = [naive.history[expected[i][0]][expected[i][1]]["obs"][:-1] for i in starts]
    assert sum(padding.any() for padding in env_padding) >= 2, "the env's first stacks are not all zeros"
    assert not buffer.gather(np.array(starts)).obs[:, :-1].any()  # the replay's are


def test_one_step_episodes_of_hand_made_stacks():
    # env 0: episode A = [0 0 a1] -> [0 a1 a2] (terminated), episode B = [0 0 b1] -> [0 b1 b2] -> [b1 b2 b3]
    f = {name: np.full((1, 1), value, np.uint8) for name, value in dict(a1=1, a2=2, b1=3, b2=4, b3=5).items()}
    z = np.zeros((1, 1), np.uint8)

    def step(obs, next_obs, reward, terminated):
        return Transition(
            obs=np.stack(obs)[None],
            action=np.array([0], np.int32),
            reward=np.array([reward], np.float32),
            next_obs=np.stack(next_obs)[None],
            terminated=np.array([terminated]),
            truncated=np.array([False]),
            num_steps=np.array([1], np.int32),
        )

    buffer = FrameReplayBuffer(8, 1, stack=3, frame_shape=(1, 1), n_step=2, discount_factor=0.5)
    buffer.add_batch(step([z, z, f["a1"]], [z, f["a1"], f["a2"]], 1.0, True))
    buffer.add_batch(step([z, z, f["b1"]], [z, f["b1"], f["b2"]], 2.0, False))
    assert buffer.size == 1  # episode A ended; B's first window (2 steps) is still open
    buffer.add_batch(step([z, f["b1"], f["b2"]], [f["b1"], f["b2"], f["b3"]], 4.0, False))
    got = buffer.gather(np.array([0, 1]))
    # A: one step, reward 1, next_obs the final stack; B: 2 + 0.5 · 4 = 4, next_obs [b1 b2 b3]
    np.testing.assert_array_equal(got.num_steps, [1, 2])
    np.testing.assert_allclose(got.reward, [1.0, 4.0])
    np.testing.assert_array_equal(got.next_obs[:, :, 0, 0], [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(got.obs[:, :, 0, 0], [[0, 0, 1], [0, 0, 3]])
    np.testing.assert_array_equal(got.terminated, [True, False])


def filled(prioritized, capacity=64, num_envs=2, steps=100, n_step=1, seed=0):
    buffer = FrameReplayBuffer(
        capacity, num_envs, stack=2, frame_shape=(1, 1), n_step=n_step, prioritized=prioritized, seed=seed
    )
    for batch in env_stream(seed, num_envs, 2, (1, 1), 1e9, steps):
        buffer.add_batch(batch)
    return buffer


def test_uniform_sampling_covers_the_valid_indices_evenly():
    buffer = filled(prioritized=False, n_step=3)
    valid = buffer.valid_indices()
    assert buffer.size == len(valid) == 64 - 2 * 2  # each env's last 2 windows are open
    indices = np.concatenate([buffer.sample(500).indices for _ in range(100)])
    assert set(indices.tolist()) == set(valid.tolist())
    counts = np.unique(indices, return_counts=True)[1]
    expected = len(indices) / len(valid)
    chi2 = np.sum((counts - expected) ** 2 / expected)
    assert chi2 < len(valid) + 6 * np.sqrt(2 * len(valid))


def test_prioritized_sampling_follows_p_to_the_alpha_and_weights_the_formula():
    buffer = filled(prioritized=True)
    valid = buffer.valid_indices()
    td_error = np.random.default_rng(1).uniform(0.1, 3.0, len(valid))
    buffer.update_priorities(valid, td_error)
    p_alpha = (np.abs(td_error) + 1e-6) ** 0.6
    probability = p_alpha / p_alpha.sum()
    indices = np.concatenate([buffer.sample(500).indices for _ in range(400)])
    counts = np.array([np.sum(indices == i) for i in valid])
    expected = len(indices) * probability
    chi2 = np.sum((counts - expected) ** 2 / expected)  # df = 63: mean 63, std 11
    assert chi2 < len(valid) + 6 * np.sqrt(2 * len(valid))
    sample = buffer.sample(64, beta=0.4)
    p = dict(zip(valid.tolist(), probability, strict=True))
    w = (len(valid) * np.array([p[i] for i in sample.indices.tolist()])) ** -0.4
    np.testing.assert_allclose(sample.weights, w / w.max(), rtol=1e-5)


def test_update_priorities_skips_indices_overwritten_since_sampling():
    buffer = filled(prioritized=True, capacity=8, steps=4)
    sample = buffer.sample(8)
    for batch in env_stream(5, 2, 2, (1, 1), 1e9, 20):
        buffer.add_batch(batch)
    buffer.update_priorities(sample.indices, np.full(8, 100.0))
    assert buffer.max_priority == 1.0  # nothing applied: every sampled step was overwritten


def test_bytes_per_transition_and_nbytes():
    per_transition = required_bytes(100_000, 8, prioritized=True) / 100_000
    assert per_transition <= 7_500, per_transition  # 7.5 KB, so 1M transitions fit in 7.5 GB
    assert required_bytes(1_000_000, 8, prioritized=True) <= 7.5e9
    buffer = FrameReplayBuffer(1_000, 8, prioritized=True)
    assert buffer.nbytes == required_bytes(1_000, 8, prioritized=True)


def test_a_capacity_beyond_the_memory_available_is_refused_before_allocating(monkeypatch):
    monkeypatch.setattr(frames, "available_memory", lambda: 2 * 10**9)

    def no_allocation(*args, **kwargs):
        raise AssertionError("allocated before the memory check")

    monkeypatch.setattr(frames.np, "zeros", no_allocation)
    need = required_bytes(1_000_000, 8)
    with pytest.raises(UsageError, match=f"needs 7.4. GB \\({need:,} bytes\\).*lower --buffer-size"):
        FrameReplayBuffer(1_000_000, 8)


def test_save_and_load_give_identical_samples_and_refuse_foreign_files(tmp_path):
    buffer = filled(prioritized=True, n_step=3, steps=90)
    buffer.update_priorities(buffer.valid_indices()[:20], np.linspace(0, 5, 20))
    path = files.save_replay(buffer, tmp_path / "replay.npz")
    assert [p.name for p in tmp_path.iterdir()] == ["replay.npz"]  # the temporary file was renamed
    with zipfile.ZipFile(path) as archive:
        assert {info.compress_type for info in archive.infolist()} == {zipfile.ZIP_DEFLATED}
    loaded = frames.load(path)
    np.testing.assert_array_equal(loaded.valid_indices(), buffer.valid_indices())
    for _ in range(3):
        a, b = buffer.sample(32, beta=0.5), loaded.sample(32, beta=0.5)
        np.testing.assert_array_equal(a.indices, b.indices)
        np.testing.assert_array_equal(a.weights, b.weights)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(a.transition, name), getattr(b.transition, name))
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    (tmp_path / "cut.npz").write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    for name in ("bad.npz", "cut.npz"):
        with pytest.raises(UsageError, match=name):
            frames.load(tmp_path / name)
    other = FrameReplayBuffer(32, 2, stack=2, frame_shape=(1, 1))
    with pytest.raises(UsageError, match="cannot be loaded"):
        other.load_state_dict(buffer.state_dict())


def test_a_stream_restarted_after_loading_ends_the_open_windows():
    buffer = filled(prioritized=False, capacity=16, num_envs=1, steps=5, n_step=3)
    assert buffer.valid_indices().tolist() == [0, 1, 2]  # steps 3 and 4 wait for steps 5 and 6
    restored = FrameReplayBuffer(16, 1, stack=2, frame_shape=(1, 1), n_step=3)
    restored.load_state_dict(buffer.state_dict())
    batch = next(env_stream(9, 1, 2, (1, 1), 1e9, 1))  # a new stream (e.g. envs reset on resume)
    restored.add_batch(batch)
    got = restored.gather(np.array([3, 4]))
    np.testing.assert_array_equal(got.num_steps, [2, 1])  # cut at step 4, bootstrapping from its next_obs
    last = buffer.gather(np.array([2]))  # step 2's window ran to step 4: same next_obs
    np.testing.assert_array_equal(got.next_obs[0], last.next_obs[0])
    assert not got.terminated.any() and not got.truncated.any()
    first = restored.gather(np.array([5])).obs[0]
    assert not first[0].any() and first[1].tolist() == batch.obs[0, 1].tolist()


def test_actors_add_while_the_learner_samples():
    num_envs, capacity = 3, 120
    buffer = FrameReplayBuffer(capacity, num_envs, stack=4, frame_shape=(3, 3), n_step=3, prioritized=True)
    naive = NaiveReplay(capacity, num_envs, 3, 0.99)
    stream = list(env_stream(3, num_envs, 4, (3, 3), 8.0, 6_000))
    for batch in stream:
        naive.add_batch(batch)  # the whole history: a complete window never changes afterwards
    stop, errors = threading.Event(), []

    def actor():
        try:
            for batch in stream:
                if stop.is_set():
                    return
                buffer.add_batch(batch)
        except BaseException as error:
            errors.append(error)

    for batch in stream[:10]:
        buffer.add_batch(batch)
    stream = stream[10:]
    thread = threading.Thread(target=actor)
    thread.start()
    deadline, samples = time.monotonic() + 1.0, 0
    while time.monotonic() < deadline and thread.is_alive():
        sample = buffer.sample(16)
        buffer.update_priorities(sample.indices, np.ones(16))
        for i, index in enumerate(sample.indices):
            step, env = divmod(int(index), num_envs)
            assert step == sample.transition.action[i]
            assert_same(sample.transition, i, naive.transition(env, step), f"env {env} step {step}")
        samples += 1
    stop.set()
    thread.join()
    assert not errors and samples > 10


def test_replay_observer_hands_one_step_transitions_to_a_buffer_that_does_n_step():
    buffer = FrameReplayBuffer(32, 2, stack=2, frame_shape=(1, 1), n_step=3)
    observer = ReplayObserver(buffer, n_step=3, discount_factor=0.99)
    assert observer.accumulator is None
    for batch in env_stream(0, 2, 2, (1, 1), 1e9, 5):
        observer(batch)
    assert buffer.size == 2 * (5 - 2)


def test_as_dataset_draws_batches_ahead_for_uniform_replay_only():
    buffer = filled(prioritized=False, n_step=2)
    batch = next(iter(buffer.as_dataset(4, num_batches=3)))
    assert batch.transition.obs.shape == (3, 4, 2, 1, 1) and batch.indices.shape == (3, 4)
    assert set(batch.indices.ravel().tolist()) <= set(buffer.valid_indices().tolist())
    with pytest.raises(ValueError, match="uniform replay only"):
        filled(prioritized=True).as_dataset(4)


def split_batch(batch, envs):
    """The rows ``envs`` of a transition ``[num_envs]``: what an actor stepping those envs adds."""
    return Transition(**{name: np.asarray(getattr(batch, name))[envs] for name in FIELDS})


def assert_same_buffers(got, expected):
    valid = expected.valid_indices()
    assert got.size == expected.size and np.array_equal(np.sort(got.valid_indices()), np.sort(valid))
    for name, counter in expected.counters.items():
        np.testing.assert_array_equal(got.counters[name], counter, err_msg=name)
    if len(valid):
        for name, x in vars(got.gather(valid)).items():
            np.testing.assert_array_equal(x, getattr(expected.gather(valid), name), err_msg=name)
    if expected.tree is not None:
        np.testing.assert_array_equal(got.tree, expected.tree)


@settings(max_examples=25, deadline=None, database=None)
@given(
    seed=st.integers(0, 2**16),
    capacity=st.integers(8, 40),
    n_step=st.integers(1, 3),
    mean_length=st.sampled_from([1.5, 4.0, 1e9]),
    prioritized=st.booleans(),
    permuted=st.booleans(),
)
def test_two_actors_adding_interleaved_halves_give_what_one_adder_of_all_envs_gives(
    seed, capacity, n_step, mean_length, prioritized, permuted
):
    num_envs = 4
    kwargs = dict(stack=3, frame_shape=(2, 2), n_step=n_step, prioritized=prioritized, seed=seed)
    one, two = (
        FrameReplayBuffer(capacity, num_envs, **kwargs),
        FrameReplayBuffer(capacity, num_envs, **kwargs),
    )
    halves = [np.array([3, 0]), np.array([1, 2])] if permuted else [slice(0, 2), np.array([2, 3])]
    for t, batch in enumerate(env_stream(seed, num_envs, 3, (2, 2), mean_length, 3 * capacity)):
        one.add_batch(batch)
        for envs in halves if t % 2 else halves[::-1]:  # the actors' order changes from step to step
            two.add_batch(split_batch(batch, envs), envs=envs)
        assert_same_buffers(two, one)
        if not two.size:
            continue
        sample = two.sample(6)
        np.testing.assert_array_equal(sample.transition.obs, one.gather(sample.indices).obs)


def test_actors_at_different_paces_add_their_envs_to_one_buffer():
    num_envs, capacity = 4, 80
    stream = list(env_stream(5, num_envs, 4, (2, 2), 6.0, 60))
    naive = NaiveReplay(capacity, num_envs, 3, 0.99)
    for batch in stream:
        naive.add_batch(batch)  # the whole history: a complete window never changes afterwards
    buffer = FrameReplayBuffer(capacity, num_envs, stack=4, frame_shape=(2, 2), n_step=3, prioritized=True)
    one = FrameReplayBuffer(capacity, num_envs, stack=4, frame_shape=(2, 2), n_step=3, prioritized=True)
    first, second = slice(0, 2), np.array([2, 3])
    for t in range(len(stream) + 7):  # the first actor runs 7 steps ahead of the second
        if t < len(stream):
            buffer.add_batch(split_batch(stream[t], first), envs=first)
        if t >= 7:
            buffer.add_batch(split_batch(stream[t - 7], second), envs=second)
        valid = buffer.valid_indices()
        for i, index in enumerate(valid):
            step, env = divmod(int(index), num_envs)
            assert_same(buffer.gather(valid), i, naive.transition(env, step), f"env {env} step {step}")
        leaves = buffer.tree[len(buffer.tree) // 2 :]
        assert set(np.flatnonzero(leaves > 0).tolist()) == set(buffer.leaves(valid).tolist())
    for batch in stream:
        one.add_batch(batch)
    assert_same_buffers(buffer, one)


def test_add_batch_checks_its_envs():
    buffer = FrameReplayBuffer(16, 4, stack=2, frame_shape=(1, 1))
    batch = next(env_stream(0, 4, 2, (1, 1), 1e9, 1))
    with pytest.raises(ValueError, match=r"uint8 \[2, 2, 1, 1\]"):
        buffer.add_batch(batch, envs=slice(0, 2))  # four envs' rows for two envs
    for envs, message in ((np.array([0, 4]), "not all in 0..3"), (np.array([1, 1]), "twice")):
        with pytest.raises(ValueError, match=message):
            buffer.add_batch(split_batch(batch, [0, 1]), envs=envs)
    with pytest.raises(ValueError, match="1-D integer"):
        buffer.add_batch(split_batch(batch, [0, 1]), envs=np.array([0.0, 1.0]))
    assert buffer.counters["steps"].tolist() == [0, 0, 0, 0]  # nothing was added


def test_replay_observers_of_two_actors_fill_their_envs_of_a_shared_buffer():
    from agentax.replay import example_transition
    from agentax.replay.host import ReplayBuffer

    shared = FrameReplayBuffer(64, 4, stack=2, frame_shape=(1, 1), n_step=3)
    one = FrameReplayBuffer(64, 4, stack=2, frame_shape=(1, 1), n_step=3)
    observers = [ReplayObserver(shared, 3, 0.99, envs=slice(2 * i, 2 * i + 2)) for i in range(2)]
    for batch in env_stream(2, 4, 2, (1, 1), 5.0, 20):
        one.add_batch(batch)
        for i, observer in enumerate(observers):
            observer(split_batch(batch, slice(2 * i, 2 * i + 2)))
    assert_same_buffers(shared, one)
    plain = ReplayBuffer(16, example_transition(np.zeros(3, np.float32), np.int32(0)))
    observer = ReplayObserver(plain, 1, 0.99, envs=slice(2, 4))  # stores transitions: envs ignored
    observer(
        Transition(
            **{
                name: x[:, :1, 0, 0].astype(np.float32) if name.endswith("obs") else x
                for name, x in vars(split_batch(batch, slice(2, 4))).items()
            }
        )
    )
    assert plain.size == 2
