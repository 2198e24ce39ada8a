"""A frame-deduplicated host replay buffer for stacked frames (Atari), n-step and prioritized on top.

A stacked buffer stores every observation whole: ``obs`` and ``next_obs`` of ``[4, 84, 84]`` uint8
are 56 KB per transition (float32: 225 KB), although consecutive stacks share three frames and
``next_obs`` is the next step's ``obs``. Here each frame is stored once and the stacks are rebuilt
at sampling, as Dopamine's ``OutOfGraphReplayBuffer`` does; the n-step return is also computed at
sampling from the stored one-step rewards (Dopamine again), so the actors add one-step transitions
and no n-step copy of anything is kept.

**Layout.** Each env ``e`` of the ``num_envs`` streams has two rings, indexed by absolute counters
that only grow (``position % ring size`` is the slot):

* a **frame ring** ``frames[e, F, *frame_shape]``. Every step appends the newest frame of the
  observation it reached (``next_obs[-1]``); the first step of an episode first appends its whole
  first stack: ``stack − 1`` zero frames and ``obs[-1]``. So the frames of an episode lie
  contiguously: ``0, …, 0, f_0, f_1, …, f_T`` (``f_T`` the final frame, which a truncated episode
  bootstraps from), and the stack of step ``t`` is the ``stack`` frames ending at ``frame_pos[t]``,
  the position of ``obs_t[-1]``. No stack reaches into an earlier episode: where it would, it holds
  zero frames, as Dopamine's (the Atari env's first stack after a lost life still shows frames of
  the life before; a Gymnasium ``FrameStackObservation`` pads with copies of ``f_0``).
  ``zero_pad_starts=False`` stores the env's first ``obs`` whole instead, so every stack comes back
  exactly as the env gave it.
* a **step ring** ``[e, S]`` of ``action``, ``reward``, ``terminated``, ``truncated``, ``cut`` and
  ``frame_pos``; its slot ``e · S + t mod S`` is also the transition's sum-tree leaf.

``sample``'s ``indices`` name a transition by its absolute step: ``t · num_envs + e``. Unlike a slot
number it is never reused, so ``update_priorities`` can tell a transition overwritten since it was
sampled (by an actor thread, meanwhile) and leave the step that now holds its slot alone.

The observation reached after step ``t`` is always the ``stack`` frames ending at ``frame_pos[t] + 1``
(the next step's newest frame, or the final frame of the episode), so the n-step transition from
``t`` that ends after ``k`` steps (the first ``terminated | truncated`` inside the window, else ``n``)
has ``next_obs`` ending at ``frame_pos[t + k − 1] + 1`` and ``reward = Σ_{i<k} γ^i r_{t+i}``
(``agentax.returns.n_step_return``, ``agentax.replay.nstep``). ``cut`` marks a step after which the
stream broke without the episode ending (a buffer restored from a checkpoint continues with new env
streams): an n-step window stops there too and bootstraps from the observation it reached.

**What can be sampled.** Per env, a contiguous range ``[lo, hi)`` of absolute steps: ``hi`` is the
first step whose n-step window is not complete yet (``t + n − 1`` not added and no episode end
between), ``lo`` the oldest step still in the step ring whose oldest stack frame is still in the
frame ring. Both only move forward; prioritized replay keeps the sum-tree leaves outside the ranges
at zero, so no sampler ever returns a window that reads across the overwrite boundary.

**Bytes.** ``F = S + ⌈S/20⌉ + stack`` frames per env: one per step, and 5 % slack for the ``stack``
extra frames each episode start writes (episodes of 80 steps or more never evict a step early;
shorter ones make the frame ring, not the step ring, decide how far back ``lo`` reaches, so fewer
than ``capacity`` transitions are kept). Per transition: ``7056 · 1.05`` frame bytes + 19 bytes of
step data + 16 to 32 bytes of sum-tree ≤ 7.46 KB, so a million transitions take 7.5 GB.
:func:`required_bytes` says it before anything is allocated, and the constructor refuses
(``UsageError``) a capacity the memory available cannot hold.

Rejected: zeroing the frames before an episode's start at sampling (from per-step counters) would
save the ``stack − 1`` stored zero frames per episode but tie the layout to one kind of padding;
an n-step accumulator before the buffer would need the window's frames twice; a pickle of the
object would be unsafe to load and tied to the class.
"""

from __future__ import annotations

import json
import math
import os
import threading
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from agentax.errors import UsageError
from agentax.replay._numpy import Dataset, find_prefix_sum, set_leaves
from agentax.replay.core import ReplaySample, Transition
from agentax.replay.prioritized import tree_size

FRAME_SLACK = 1 / 20
"""extra frame slots per step slot, for the whole first stack each episode start stores"""

_STEP_DTYPES = {
    "action": np.int32,
    "reward": np.float32,
    "terminated": np.bool_,
    "truncated": np.bool_,
    "cut": np.bool_,
    "frame_pos": np.int64,
}
_ENV_COUNTERS = ("steps", "frames_written", "lo", "hi", "last_end")


def ring_sizes(capacity: int, num_envs: int, stack: int, frame_slack: float = FRAME_SLACK) -> tuple[int, int]:
    """``(S, F)``: step slots and frame slots per env (``num_envs · S ≥ capacity``)."""
    slots = -(-capacity // num_envs)
    return slots, slots + math.ceil(slots * frame_slack) + stack


def required_bytes(
    capacity: int,
    num_envs: int,
    *,
    stack: int = 4,
    frame_shape: tuple[int, ...] = (84, 84),
    prioritized: bool = False,
    frame_slack: float = FRAME_SLACK,
) -> int:
    """The bytes a :class:`FrameReplayBuffer` of these settings holds, every array included."""
    slots, frame_slots = ring_sizes(capacity, num_envs, stack, frame_slack)
    frames = num_envs * frame_slots * math.prod(frame_shape)
    steps = num_envs * slots * sum(np.dtype(d).itemsize for d in _STEP_DTYPES.values())
    tree = 2 * tree_size(num_envs * slots) * 8 if prioritized else 0
    return frames + steps + tree + len(_ENV_COUNTERS) * num_envs * 8 + num_envs


def available_memory() -> int | None:
    """Bytes of memory this process may still allocate: ``MemAvailable`` of ``/proc/meminfo``
    (free pages via ``sysconf`` where there is none), lowered to the cgroup's limit minus its usage."""
    available = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
    except OSError:
        pass
    if available is None:
        try:
            available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return None
    for limit_file, usage_file in (
        ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
        ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes"),
    ):
        try:
            limit, usage = Path(limit_file).read_text().strip(), Path(usage_file).read_text().strip()
        except OSError:
            continue
        if limit.isdigit() and usage.isdigit():
            available = min(available, int(limit) - int(usage))
        break
    return available


class FrameReplayBuffer(Dataset):
    """Stacked-frame replay (see the module docstring) with :class:`agentax.replay.host.ReplayBuffer`'s
    interface: ``add_batch`` one-step transitions ``[num_envs]`` (env ``e``'s calls are consecutive
    steps of its stream), ``sample``, ``update_priorities``, ``size``, ``as_dataset``; one lock around
    every access so actor threads add while the learner samples. ``handles_n_step``: the buffer builds
    the n-step transitions itself, so the ``ReplayObserver`` hands it one-step ones."""

    handles_n_step = True

    def __init__(
        self,
        capacity: int,
        num_envs: int,
        *,
        stack: int = 4,
        frame_shape: tuple[int, ...] = (84, 84),
        n_step: int = 1,
        discount_factor: float = 0.99,
        prioritized: bool = False,
        priority_exponent: float = 0.6,
        priority_epsilon: float = 1e-6,
        frame_slack: float = FRAME_SLACK,
        zero_pad_starts: bool = True,
        seed: int = 0,
    ):
        if capacity < 1 or num_envs < 1 or stack < 1 or n_step < 1 or frame_slack < 0:
            raise UsageError(
                "a frame replay needs capacity, num_envs, stack and n_step of at least 1 and "
                f"frame_slack >= 0; got {capacity}, {num_envs}, {stack}, {n_step}, {frame_slack}"
            )
        self.config = dict(
            capacity=int(capacity),
            num_envs=int(num_envs),
            stack=int(stack),
            frame_shape=[int(s) for s in frame_shape],
            n_step=int(n_step),
            discount_factor=float(discount_factor),
            prioritized=bool(prioritized),
            priority_exponent=float(priority_exponent),
            priority_epsilon=float(priority_epsilon),
            frame_slack=float(frame_slack),
            zero_pad_starts=bool(zero_pad_starts),
        )
        need = required_bytes(
            capacity,
            num_envs,
            stack=stack,
            frame_shape=tuple(frame_shape),
            prioritized=prioritized,
            frame_slack=frame_slack,
        )
        have = available_memory()
        if have is not None and need > have:
            raise UsageError(
                f"a replay of {capacity:,} transitions needs {need / 1e9:.2f} GB ({need:,} bytes), but only "
                f"{have / 1e9:.2f} GB of memory is available; lower --buffer-size"
            )
        self.num_envs, self.stack, self.n_step = num_envs, stack, n_step
        self.frame_shape = tuple(frame_shape)
        self.zero_pad_starts = zero_pad_starts
        self.prioritized = prioritized
        self.priority_exponent, self.priority_epsilon = priority_exponent, priority_epsilon
        self.slots, self.frame_slots = ring_sizes(capacity, num_envs, stack, frame_slack)
        self.discounts = (np.float32(discount_factor) ** np.arange(n_step, dtype=np.float32))[None]
        self.frames = np.zeros((num_envs, self.frame_slots, *frame_shape), np.uint8)
        self.frames.fill(0)  # touch every page now: an out-of-memory fails here, not hours into a run
        self.step_data = {k: np.zeros((num_envs, self.slots), d) for k, d in _STEP_DTYPES.items()}
        self.counters = {k: np.zeros(num_envs, np.int64) for k in _ENV_COUNTERS}
        self.counters["last_end"][:] = -1
        self.new_stream = np.ones(num_envs, bool)  # the next add starts a stream: store its whole obs
        self.tree = np.zeros(2 * tree_size(num_envs * self.slots)) if prioritized else None
        self.max_priority = 1.0
        self.rng = np.random.default_rng(seed)
        self.lock = threading.RLock()

    # ------------------------------------------------------------------ reading the state

    @property
    def size(self) -> int:
        """Transitions that can be sampled now."""
        with self.lock:
            return int(np.sum(self.counters["hi"] - self.counters["lo"]))

    @property
    def nbytes(self) -> int:
        """Bytes held, every array included."""
        arrays = [self.frames, *self.step_data.values(), *self.counters.values(), self.new_stream]
        return sum(a.nbytes for a in arrays) + (0 if self.tree is None else self.tree.nbytes)

    def valid_indices(self) -> np.ndarray:
        """Every index ``sample`` may return now (``step · num_envs + env``), ascending within each env."""
        with self.lock:
            lo, hi = self.counters["lo"], self.counters["hi"]
            parts = [np.arange(lo[e], hi[e]) * self.num_envs + e for e in range(self.num_envs)]
            return np.concatenate(parts).astype(np.int64)

    def leaves(self, indices: np.ndarray) -> np.ndarray:
        """The step-ring slots (and sum-tree leaves) of ``indices``."""
        step, env = np.divmod(np.asarray(indices, np.int64), self.num_envs)
        return env * self.slots + step % self.slots

    def _valid(self, indices: np.ndarray) -> np.ndarray:
        step, env = np.divmod(np.asarray(indices, np.int64), self.num_envs)
        return (step >= self.counters["lo"][env]) & (step < self.counters["hi"][env])

    def gather(self, indices: np.ndarray) -> Transition:
        """The n-step transitions at ``indices`` (sampleable ones; see :meth:`valid_indices`)."""
        with self.lock:
            return self._gather(np.asarray(indices, np.int64))

    def _gather(self, indices: np.ndarray) -> Transition:
        data, slots, stack = self.step_data, self.slots, self.stack
        step, env = np.divmod(indices, self.num_envs)
        slot = step % slots
        window = (slot[:, None] + np.arange(self.n_step)) % slots  # [B, n]
        rows = env[:, None]
        ended = data["terminated"][rows, window] | data["truncated"][rows, window] | data["cut"][rows, window]
        alive = (np.cumsum(ended, axis=1) - ended) == 0  # no episode ended strictly before step i
        num_steps = alive.sum(axis=1)
        reward = np.sum(alive * self.discounts * data["reward"][rows, window], axis=1, dtype=np.float32)
        last = (slot + num_steps - 1) % slots
        offsets = np.arange(1 - stack, 1)
        obs_frames = data["frame_pos"][env, slot][:, None] + offsets
        next_frames = data["frame_pos"][env, last][:, None] + 1 + offsets
        stacks = self.frames[rows, np.concatenate([obs_frames, next_frames], axis=1) % self.frame_slots]
        return Transition(
            obs=stacks[:, :stack],
            action=data["action"][env, slot],
            reward=reward,
            next_obs=stacks[:, stack:],
            terminated=data["terminated"][env, last],
            truncated=data["truncated"][env, last],
            num_steps=num_steps.astype(np.int32),
        )

    # ------------------------------------------------------------------ adding

    def add_batch(self, transition: Transition, envs: Any = None) -> None:
        """Add one step of the env streams ``envs`` (an int array or a slice of ``range(num_envs)``;
        None: all of them): one-step transition fields ``[len(envs), ...]``, ``obs`` and ``next_obs``
        uint8 ``[len(envs), stack, *frame_shape]``, ``next_obs`` the observation the step really
        reached (``TimeStep.final_obs``), ``action`` integer (stored as int32). Only
        ``next_obs[:, -1]`` is stored, and a first stack where a stream or an episode starts. Actors
        that each step a share of the envs add their share with its ``envs``; each stream's calls must
        be consecutive steps of that env."""
        envs = self._env_ids(envs)
        obs, next_obs = np.asarray(transition.obs), np.asarray(transition.next_obs)
        shape = (len(envs), self.stack, *self.frame_shape)
        for name, x in (("obs", obs), ("next_obs", next_obs)):
            if x.shape != shape or x.dtype != np.uint8:
                raise ValueError(f"{name} must be uint8 {list(shape)}, got {x.dtype}{list(x.shape)}")
        if not np.issubdtype(np.asarray(transition.action).dtype, np.integer):
            raise ValueError(
                f"a frame replay stores discrete actions, got {np.asarray(transition.action).dtype}"
            )
        terminated = np.asarray(transition.terminated, bool)
        truncated = np.asarray(transition.truncated, bool)
        with self.lock:
            self._add(envs, obs, next_obs, transition.action, transition.reward, terminated, truncated)

    def _env_ids(self, envs: Any) -> np.ndarray:
        """``envs`` (None, a slice or integers) as distinct env indices ``int64 [k]``."""
        if envs is None:
            return np.arange(self.num_envs)
        if isinstance(envs, slice):
            return np.arange(self.num_envs)[envs]
        ids = np.asarray(envs)
        if ids.ndim != 1 or not np.issubdtype(ids.dtype, np.integer):
            raise ValueError(f"envs must be a slice or a 1-D integer array, got {ids.dtype}{list(ids.shape)}")
        if len(ids) and (ids.min() < 0 or ids.max() >= self.num_envs):
            raise ValueError(f"envs {ids.tolist()} are not all in 0..{self.num_envs - 1}")
        if len(np.unique(ids)) != len(ids):
            raise ValueError(f"envs {ids.tolist()} name an env twice")
        return ids.astype(np.int64)

    def _add(self, envs, obs, next_obs, action, reward, terminated, truncated) -> None:
        """One step of the streams ``envs``: their counters are read, advanced and written back."""
        c, data = self.counters, self.step_data
        slots, frame_slots = self.slots, self.frame_slots
        steps, written, last_end = c["steps"][envs], c["frames_written"][envs], c["last_end"][envs]
        old_lo, old_hi = c["lo"][envs], c["hi"][envs]
        new_stream = self.new_stream[envs]
        # a stream that restarts mid-episode ends the n-step windows of its last step there
        broken = new_stream & (steps > 0) & (last_end != steps - 1)
        data["cut"][envs[broken], (steps[broken] - 1) % slots] = True
        last_end[broken] = steps[broken] - 1
        starting = np.flatnonzero(new_stream)
        if len(starting):
            positions = (written[starting, None] + np.arange(self.stack)) % frame_slots
            first = obs[starting]
            if self.zero_pad_starts:
                first = np.concatenate([np.zeros_like(first[:, 1:]), first[:, -1:]], axis=1)
            self.frames[envs[starting, None], positions] = first
            written[starting] += self.stack
        self.frames[envs, written % frame_slots] = next_obs[:, -1]
        slot = steps % slots
        data["frame_pos"][envs, slot] = written - 1  # where obs[-1] is
        data["action"][envs, slot] = action
        data["reward"][envs, slot] = reward
        data["terminated"][envs, slot] = terminated
        data["truncated"][envs, slot] = truncated
        data["cut"][envs, slot] = False
        written += 1
        ended = terminated | truncated
        last_end[ended] = steps[ended]
        steps += 1
        # the oldest sampleable step: still in the step ring, its first stack frame still in the frame ring
        lo = np.maximum(old_lo, steps - slots)
        while True:
            stale = (lo < steps) & (
                data["frame_pos"][envs, lo % slots] - (self.stack - 1) < written - frame_slots
            )
            if not stale.any():
                break
            lo += stale
        hi = np.maximum(np.maximum(steps - self.n_step + 1, last_end + 1), lo)
        c["steps"][envs], c["frames_written"][envs], c["last_end"][envs] = steps, written, last_end
        c["lo"][envs], c["hi"][envs] = lo, hi
        self.new_stream[envs] = ended
        if self.tree is not None:
            self._update_leaves(envs, old_lo, old_hi, lo, hi)

    def _update_leaves(self, envs, old_lo, old_hi, lo, hi) -> None:
        """Zero the leaves of steps no longer sampleable, give the newly sampleable ones max priority
        (the streams ``envs``; the bounds are theirs, in the same order)."""
        gone, new = [], []
        for i, e in enumerate(envs):
            gone.append(e * self.slots + np.arange(old_lo[i], min(lo[i], old_hi[i])) % self.slots)
            new.append(e * self.slots + np.arange(max(old_hi[i], lo[i]), hi[i]) % self.slots)
        gone, new = np.concatenate(gone).astype(np.int64), np.concatenate(new).astype(np.int64)
        if len(gone) and len(new):  # a slot can hold a step that left and one that came in
            gone = gone[~np.isin(gone, new)]
        if len(gone) or len(new):  # one walk up the tree
            priority = self.max_priority**self.priority_exponent
            values = np.concatenate([np.zeros(len(gone)), np.full(len(new), priority)])
            set_leaves(self.tree, np.concatenate([gone, new]), values)

    # ------------------------------------------------------------------ sampling

    def sample(self, batch_size: int, beta: float = 1.0) -> ReplaySample:
        """``batch_size`` n-step transitions: uniformly with replacement, or ``∝ p^ζ`` (stratified)
        with importance weights ``(N · P(i))^−β`` divided by the batch's largest
        (``agentax.replay.prioritized``)."""
        with self.lock:
            total = self.size
            if total == 0:
                raise ValueError("cannot sample from a replay buffer that holds no complete transition yet")
            if self.tree is None:
                indices = self._sample_uniform(batch_size)
                weights = np.ones(batch_size, np.float32)
            else:
                indices, probability = self._sample_prioritized(batch_size)
                weights = (total * probability) ** (-beta)
                weights = (weights / weights.max()).astype(np.float32)
            return ReplaySample(transition=self._gather(indices), indices=indices, weights=weights)

    def _sample_uniform(self, batch_size: int) -> np.ndarray:
        lo, hi = self.counters["lo"], self.counters["hi"]
        ends = np.cumsum(hi - lo)
        draw = self.rng.integers(0, ends[-1], batch_size)
        env = np.searchsorted(ends, draw, side="right")
        return (lo[env] + draw - (ends - (hi - lo))[env]) * self.num_envs + env

    def _sample_prioritized(self, batch_size: int) -> tuple[np.ndarray, np.ndarray]:
        num_leaves = len(self.tree) // 2
        mass_total = self.tree[1]
        points = (np.arange(batch_size) + self.rng.uniform(size=batch_size)) * (mass_total / batch_size)
        leaf = find_prefix_sum(self.tree, np.minimum(points, mass_total * (1 - 1e-9)))
        empty = self.tree[num_leaves + leaf] <= 0  # rounding can end a walk on an empty leaf
        if empty.any():
            full = np.flatnonzero(self.tree[num_leaves:] > 0)
            leaf[empty] = full[np.searchsorted(full, leaf[empty]).clip(0, len(full) - 1)]
        env, slot = np.divmod(leaf, self.slots)
        base = self.counters["steps"][env] - self.slots  # the step that holds the slot now
        step = base + (slot - base) % self.slots
        return step * self.num_envs + env, self.tree[num_leaves + leaf] / mass_total

    def update_priorities(self, indices: np.ndarray, td_error: np.ndarray) -> None:
        """Transitions ``indices`` get priority ``|td_error| + ε``; those no longer sampleable (overwritten
        since they were sampled) are left alone."""
        if self.tree is None:
            return
        with self.lock:
            valid = self._valid(indices)
            priority = np.abs(np.asarray(td_error, np.float64))[valid] + self.priority_epsilon
            if len(priority):
                set_leaves(self.tree, self.leaves(indices)[valid], priority**self.priority_exponent)
                self.max_priority = max(self.max_priority, float(priority.max()))

    # ------------------------------------------------------------------ checkpoints

    def state_dict(self) -> dict[str, np.ndarray]:
        """Every array (not copies: hold ``lock`` while using them) and the settings, as NumPy arrays."""
        with self.lock:
            state = {"frames": self.frames, "new_stream": self.new_stream}
            state.update({f"step_{k}": v for k, v in self.step_data.items()})
            state.update({f"env_{k}": v for k, v in self.counters.items()})
            if self.tree is not None:
                state["tree"] = self.tree
            state["max_priority"] = np.float64(self.max_priority)
            state["config"] = np.array(json.dumps(self.config))
            state["rng"] = np.array(json.dumps(self.rng.bit_generator.state))
            return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned (copied). Every env then starts a new stream: its
        next ``add_batch`` stores its whole ``obs``, and a window left open ends where the stream broke."""
        self._restore(state, copy=True)

    def _restore(self, state: dict[str, Any], copy: bool) -> None:
        config = json.loads(str(state["config"]))
        if config != self.config:
            raise UsageError(f"a replay saved with {config} cannot be loaded into one with {self.config}")
        arrays = {"frames": self.frames, **{f"step_{k}": v for k, v in self.step_data.items()}}
        arrays.update({f"env_{k}": v for k, v in self.counters.items()})
        if self.tree is not None:
            arrays["tree"] = self.tree
        restored = {}
        for name, mine in arrays.items():
            got = np.asarray(state[name])
            if got.shape != mine.shape or got.dtype != mine.dtype:
                raise UsageError(
                    f"replay array {name} is {got.dtype}{list(got.shape)}, not {mine.dtype}{list(mine.shape)}"
                )
            restored[name] = got.copy() if copy else got
        with self.lock:
            self.frames = restored["frames"]
            self.step_data = {k: restored[f"step_{k}"] for k in _STEP_DTYPES}
            self.counters = {k: restored[f"env_{k}"] for k in _ENV_COUNTERS}
            self.tree = restored.get("tree")
            self.max_priority = float(state["max_priority"])
            self.rng.bit_generator.state = json.loads(str(state["rng"]))
            self.new_stream = np.ones(self.num_envs, bool)


def load(path: str | Path) -> FrameReplayBuffer:
    """The buffer :func:`save` wrote to ``path``, with its settings and random state (the memory check
    applies). The frames are decompressed straight into the new buffer, so loading needs no more
    memory than the buffer. A missing, truncated or foreign file raises :class:`UsageError`."""
    try:
        with np.load(path, allow_pickle=False) as data:
            buffer = FrameReplayBuffer(**json.loads(str(data["config"])))
            state = {name: data[name] for name in data.files if name != "frames"}
        with zipfile.ZipFile(path) as archive, archive.open("frames.npy") as member:
            _read_array_into(member, buffer.frames)
        buffer._restore({**state, "frames": buffer.frames}, copy=False)
    except UsageError:
        raise
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as error:
        raise UsageError(f"{path} holds no replay buffer saved by agentax ({error})") from error
    return buffer


def _read_array_into(member: Any, target: np.ndarray) -> None:
    """Read the ``.npy`` stream ``member`` into the C-contiguous ``target``, chunk by chunk."""
    version = np.lib.format.read_magic(member)
    read_header = (
        np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    )
    shape, fortran_order, dtype = read_header(member)
    if shape != target.shape or dtype != target.dtype or fortran_order:
        raise ValueError(f"frames are {dtype}{list(shape)}, not {target.dtype}{list(target.shape)}")
    view, done = memoryview(target.reshape(-1)).cast("B"), 0
    while done < len(view):
        count = member.readinto(view[done : done + (1 << 24)])
        if not count:
            raise EOFError(f"frames end after {done:,} of {len(view):,} bytes")
        done += count
