"""A host actor's memory of its envs, carried across rollouts, and the actor kept with checkpoints.

A recurrent agent (``Agent.recurrent``) acts with each env's memory. A host actor
(:class:`agentax.runners.host.Actor`) carries it as the compiled runner's
:class:`~agentax.runners.rollout.RecurrentCarry` does: every env starts at
:func:`~agentax.runners.rollout.fresh_memory` (``first`` all true); each step's memory goes on to
the next step and from one rollout to the next; ``first`` marks the envs whose last step ended an
episode (the env auto-reset, so the observation starts the next one). ``agent.recurrent.act`` keeps
the memory it received and ``first`` in each step's ``info``, so the learner replays the rollout's
sequences from the memory that collected them (under a policy lag too: the actor's memory is the one
its own, older, parameters computed).

:class:`ActorCheckpoints`: the host runner saves its actor beside each checkpoint, where its envs
can give their state (agentax's JAX envs behind Gymnasium, :meth:`agentax.envs.GymnasiumEnv.snapshot`):
the envs' states and random generators, the observations, each env's memory and ``first``, the
actor's key. A resumed run then continues the very episodes it was playing, number for number. A
Gymnasium env's state cannot be saved in general (nor an Atari emulator's here): such a run restarts
its envs on resume (from seeds that depend on how far it had come) and their memory with them.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from agentax import formats
from agentax.agents.protocol import Agent, OffPolicy
from agentax.envs.core import TimeStep
from agentax.errors import UsageError
from agentax.replay import Transition
from agentax.runners.driver import EpisodeAverage
from agentax.runners.rollout import fresh_memory
from agentax.runners.session import Session
from agentax.runs import CHECKPOINT_PREFIX, Run, checkpoints, load_tree, save_tree

ACTORS_PREFIX = "actors-"


def act_and_split(act):
    """``act(..., key, progress)`` (``agent.act``, or ``agent.recurrent.act``) that also advances its
    key: its results and the next key, so a host actor makes one compiled call per step."""

    def act_next(*inputs):
        *inputs, key, progress = inputs
        key, act_key = jax.random.split(key)
        return (*act(*inputs, act_key, progress), key)

    return act_next


class CarriedMemory:
    """Each env's memory of a host actor of a recurrent agent: ``act`` has the signature of the
    actor's feed-forward act (``(action, info, key)``) and moves the memory on; as an observer of
    every transition it marks ``first`` where the step ended an episode; ``restart()`` after a reset."""

    def __init__(self, agent: Agent, num_envs: int):
        self.agent, self.num_envs = agent, num_envs
        self._act = jax.jit(act_and_split(agent.recurrent.act))
        self.restart()

    def restart(self) -> None:
        """Every env starts an episode: fresh memory, ``first`` all true."""
        memory, first = fresh_memory(self.agent, self.num_envs)
        self.memory, self.first = memory, np.asarray(first)

    def act(self, state: Any, obs: np.ndarray, key: jax.Array, progress: int) -> tuple[Any, Any, jax.Array]:
        self.memory, action, info, key = self._act(state, self.memory, obs, self.first, key, progress)
        return action, info, key

    def __call__(self, transition: Transition) -> None:
        self.first = np.asarray(transition.terminated | transition.truncated)


def actors_beside(checkpoint: Path) -> Path:
    """The actor saved with ``checkpoints/ckpt-<updates>.msgpack``: ``actors-<updates>.msgpack``."""
    updates = checkpoint.stem.removeprefix(CHECKPOINT_PREFIX)
    return checkpoint.with_name(f"{ACTORS_PREFIX}{updates}.msgpack")


def actor_snapshot(actor: Any, trackers: Sequence[EpisodeAverage] = ()) -> tuple[dict, dict] | None:
    """``(arrays, meta)`` of where ``actor`` is: its envs' states, observations, memory and key and
    the sums of the episodes under way of the returns ``trackers`` (the arrays), its envs' random
    generators and seed (JSON); None where its envs cannot be saved."""
    envs = actor.env.snapshot() if hasattr(actor.env, "snapshot") else None
    if envs is None or actor.memory is None:
        return None
    env_arrays, generators = envs
    memory = actor.memory
    arrays = {
        "envs": env_arrays,
        "obs": actor.time_step.obs,
        "key": actor.key,
        "memory": jax.device_get(memory.memory),
        "first": memory.first,
        "returns": [np.zeros(actor.num_envs) if t.running is None else t.running for t in trackers],
    }
    return arrays, {"generators": generators, "seed": actor.seed, "format": formats.FORMAT}


def continue_actor(
    actor: Any, arrays: dict[str, Any], meta: dict[str, Any], trackers: Sequence[EpisodeAverage] = ()
) -> None:
    """Put ``actor`` (and its returns ``trackers``) where :func:`actor_snapshot` found it."""
    actor.env.restore(arrays["envs"], meta["generators"])
    obs = np.asarray(arrays["obs"])
    zeros = np.zeros(len(obs), bool)
    actor.time_step = TimeStep(obs, np.zeros(len(obs), np.float32), zeros, zeros, obs)
    actor.key, actor.seed = arrays["key"], int(meta["seed"])
    actor.memory.memory, actor.memory.first = arrays["memory"], np.asarray(arrays["first"], bool)
    for tracker, running in zip(trackers, arrays["returns"], strict=True):
        tracker.running = np.array(running)  # a writable copy


class ActorCheckpoints:
    """The host runner's actor saved with the agent's checkpoints (where its envs can be saved):
    ``checkpoints/actors-<updates>.msgpack`` written before its checkpoint, which commits the pair
    (as :class:`~agentax.runners.session.ReplayCheckpoints`); those of checkpoints no longer kept
    are removed."""

    def __init__(self, run: Run | None, actor: Any, trackers: Sequence[EpisodeAverage] = ()):
        self.run, self.actor, self.trackers = run, actor, trackers

    def before_checkpoint(self, updates: int, force: bool) -> None:
        snapshot = actor_snapshot(self.actor, self.trackers)
        if self.run is None or snapshot is None:
            return
        folder = self.run.path / "checkpoints"
        path = actors_beside(folder / f"{CHECKPOINT_PREFIX}{updates}.msgpack")
        save_tree(path, *snapshot)
        kept = {actors_beside(p) for p in checkpoints(self.run.path)} | {path}
        for old in folder.glob(f"{ACTORS_PREFIX}*.msgpack"):
            if old not in kept:
                old.unlink(missing_ok=True)

    def restore(self, checkpoint: Path) -> bool:
        """Continue the actor saved with ``checkpoint``, if it was (a file that does not load: a
        note on stderr, and the envs restart); whether it did."""
        path, snapshot = actors_beside(checkpoint), actor_snapshot(self.actor, self.trackers)
        if snapshot is None or not path.is_file():
            return False
        target = jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), x.dtype), snapshot[0])
        try:
            arrays, meta = load_tree(path, target)
        except UsageError as error:
            print(f"note: {error}; the envs restart, and their memory with them", file=sys.stderr)
            return False
        continue_actor(self.actor, arrays, meta, self.trackers)
        return True


def keep_actor(session: Session, actor: Any, *trackers: EpisodeAverage) -> None:
    """Keep the host runner's ``actor`` of a recurrent agent (and the returns ``trackers`` of its
    episodes beside its own) with ``session``'s checkpoints (:class:`ActorCheckpoints`, where its
    envs can be saved), continued where the run resumed from."""
    if actor.memory is None or isinstance(actor.agent.experience, OffPolicy):
        return
    session.keep(ActorCheckpoints(session.run, actor, [actor.returns, *trackers]))
