"""A host actor's memory of its envs, carried across rollouts (:class:`CarriedMemory`, as the
compiled runner's :class:`~agentax.runners.rollout.RecurrentCarry`), and the actor saved beside each
checkpoint where its envs can be saved (:class:`ActorCheckpoints`), so a resumed run continues
its episodes (design.md, "The host runners, module by module").
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
    """``act(..., key, progress)`` that also returns the next key: one compiled call a step."""

    def act_next(*inputs):
        *inputs, key, progress = inputs
        key, act_key = jax.random.split(key)
        return (*act(*inputs, act_key, progress), key)

    return act_next


class CarriedMemory:
    """Each env's memory of a recurrent agent's host actor: ``act`` (the feed-forward act's signature)
    moves it on; as an observer it marks ``first`` where a step ended an episode."""

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
    """``(arrays, meta)`` of where ``actor`` and its returns ``trackers`` are; None where its envs
    cannot be saved."""
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
    """The actor saved as ``checkpoints/actors-<updates>.msgpack`` before its checkpoint, which commits
    the pair (as :class:`~agentax.runners.session.ReplayCheckpoints`)."""

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
        """Continue the actor saved with ``checkpoint`` (one that does not load: a note); whether it did."""
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
    """Keep a recurrent on-policy agent's ``actor`` (and returns ``trackers``) with ``session``'s
    checkpoints, continued where the run resumed from."""
    if actor.memory is None or isinstance(actor.agent.experience, OffPolicy):
        return
    session.keep(ActorCheckpoints(session.run, actor, [actor.returns, *trackers]))
