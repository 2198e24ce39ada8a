"""Actors on a Ray cluster: the parallel runner with its actors in Ray actor processes, on any node.

``--runner ray`` is :mod:`agentax.runners.parallel` with another :class:`~parallel.Fleet`: each
actor is a :class:`Collector` process holding a host :class:`~agentax.runners.host.Actor`, driven
through a :class:`RemoteActor`. Parameters go out through Ray's object store, experience comes back
as NumPy batches (:class:`PackedFrames`), and a collector that dies is replaced
(docs/howto/ray-cluster.md, "What happens inside").
"""

from __future__ import annotations

import collections
import functools
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from agentax.agents.protocol import Agent, acting_view
from agentax.errors import NodeLost, UsageError
from agentax.replay import Transition
from agentax.runners import parallel
from agentax.runners.coordination import POLL_SECONDS, Coordinator
from agentax.runners.driver import EnvironmentSteps, TrajectoryObserver
from agentax.runners.host import Actor, actor_seed, env_factory, fold_actor_key
from agentax.runners.parallel import Fleet, ParallelRunnerConfig
from agentax.runners.ray_cluster import ray_session
from agentax.runners.session import TrainResult
from agentax.runs import Run, checkpoints

CHECK_SECONDS = 1.0  # how often a waiting replacement collector checks that its CPUs still exist
RESTART_SEED_STRIDE = 104_729  # a restarted collector's envs: actor_seed + stride × restarts


@dataclass(frozen=True)
class RayRunnerConfig(ParallelRunnerConfig):
    """The parallel runner's settings and where its actors run; saved in config.json under "runner"."""

    ray_address: str | None = None
    """an existing Ray cluster to join ('auto' or HOST:PORT); None: a local Ray for this run"""
    cpus_per_actor: float = 1.0
    """CPUs Ray reserves for each actor process (it places the actors by them)"""
    max_actor_restarts: int = 100
    """collector processes replaced over the whole run before it gives up"""


Config = RayRunnerConfig
REMAKES_AGENT = True  # its actors build the agent again in their processes: train takes make_agent
algorithm_config = parallel.algorithm_config
restore = parallel.restore


def configure(run_args: Any, agent: Agent, preset: Any) -> tuple[RayRunnerConfig, str]:
    """The Ray runner's settings for a run: the parallel runner's and where its actors run."""
    where = {"ray_address": run_args.ray_address, "cpus_per_actor": run_args.cpus_per_actor}
    return parallel.configure_actors(run_args, agent, preset, "ray", RayRunnerConfig, "Ray actor", **where)


# ---------------------------------------------------------------- the wire format of stacked frames


@dataclass
class PackedFrames:
    """A trajectory ``[T, E]`` of stacked frames ``[C, H, W]`` with each frame sent once.

    ``obs[t]`` is ``obs[t - 1]`` shifted by one frame plus ``new_frames[t]``, except at ``fresh``
    (``t = 0``, a new episode) whose stacks are in ``fresh_stacks``; ``next_obs[t]`` is ``obs[t + 1]``,
    except at ``ends`` whose stacks are in ``end_stacks``. Both are found by comparing frames: exact."""

    new_frames: np.ndarray  # [T, E, H, W]
    fresh: np.ndarray  # bool [T, E]
    fresh_stacks: np.ndarray  # [K, C, H, W]
    ends: np.ndarray  # bool [T, E]
    end_stacks: np.ndarray  # [M, C, H, W]
    rest: Transition  # the trajectory without obs and next_obs (None there)


def pack_frames(trajectory: Transition) -> Transition | PackedFrames:
    """``trajectory`` with each frame once when its observations are stacked frames, else itself."""
    obs, next_obs = trajectory.obs, trajectory.next_obs
    if obs.ndim != 5:
        return trajectory
    fresh = np.ones(obs.shape[:2], bool)
    fresh[1:] = ~(obs[1:, :, :-1] == obs[:-1, :, 1:]).all(axis=(2, 3, 4))
    ends = np.ones(obs.shape[:2], bool)
    ends[:-1] = ~(next_obs[:-1] == obs[1:]).all(axis=(2, 3, 4))
    return PackedFrames(
        obs[:, :, -1], fresh, obs[fresh], ends, next_obs[ends], trajectory.replace(obs=None, next_obs=None)
    )


def unpack_frames(packed: Transition | PackedFrames) -> Transition:
    """The trajectory :func:`pack_frames` packed, exactly."""
    if not isinstance(packed, PackedFrames):
        return packed
    num_steps, num_envs, height, width = packed.new_frames.shape
    obs = np.empty(
        (num_steps, num_envs, packed.fresh_stacks.shape[1], height, width), packed.new_frames.dtype
    )
    obs[0] = packed.fresh_stacks[:num_envs]  # every stack starts afresh at t = 0
    fresh_index = np.cumsum(packed.fresh.ravel()).reshape(packed.fresh.shape) - 1
    for t in range(1, num_steps):
        obs[t, :, :-1], obs[t, :, -1] = obs[t - 1, :, 1:], packed.new_frames[t]
        restart = packed.fresh[t]
        obs[t, restart] = packed.fresh_stacks[fresh_index[t, restart]]
    next_obs = np.empty_like(obs)
    next_obs[:-1] = obs[1:]
    next_obs[packed.ends] = packed.end_stacks
    return packed.rest.replace(obs=obs, next_obs=next_obs)


# ---------------------------------------------------------------- the actor process


class Collector:
    """One actor in its own process (a Ray actor): a host :class:`Actor` and the newest parameters.
    Each call gets the published ``(version, ref)`` inside a list, so Ray passes the reference on
    and the collector fetches a version only when it is new."""

    def __init__(self, make_agent: Callable[[], Agent], env_id: str, runner: Any, num_envs: int, seed, key):
        from agentax import _xla

        _xla.enable_compilation_cache()  # a restarted collector skips compiling its policy
        agent, make_env = make_agent(), env_factory(env_id, runner)
        self.actor = Actor(agent, make_env(num_envs, training=True), seed, jax.random.wrap_key_data(key))
        self.version: int | None = None

    def describe(self) -> dict[str, Any]:
        import ray

        actor = self.actor
        return {
            "num_envs": actor.num_envs,
            "obs_shape": actor.obs_shape,
            "keeps_scores": actor.keeps_scores,
            "node": ray.get_runtime_context().get_node_id(),
        }

    def _state(self, published: list) -> Any:
        import ray

        version, ref = published[0]
        if version != self.version:
            self.state, self.version = jax.device_put(ray.get(ref)), version
        return self.state

    def _result(self, trajectory: Transition, steps_before: int):
        """The trajectory (each frame once), finished games' scores and the env steps taken."""
        return pack_frames(trajectory), self.actor.finished_returns(), self.actor.steps.count - steps_before

    def rollout(self, published: list, num_steps: int):
        before = self.actor.steps.count
        return self._result(self.actor.rollout(self._state(published), num_steps), before)

    def episodes_from_reset(self, published: list, max_steps: int):
        before = self.actor.steps.count
        return self._result(self.actor.episodes_from_reset(self._state(published), max_steps), before)

    def collect(self, published: list, amount: int, progress: int):
        before, trajectory = self.actor.steps.count, TrajectoryObserver()
        self.actor.progress = lambda: progress
        self.actor.collect(self._state(published), trajectory, amount)
        return self._result(trajectory.trajectory(), before)


# ---------------------------------------------------------------- the learner's end of it


class RemoteActor:
    """The learner's handle on one :class:`Collector`, with the host Actor's interface: each call
    waits for the collector's batch while the run goes on; a collector that died is replaced."""

    def __init__(
        self,
        spawn: Callable[[int], Any],
        coordinator: Coordinator,
        done_steps: int,
        max_restarts: int,
        still_held: Callable[[], None],
    ):
        self.spawn, self.coordinator, self.max_restarts = spawn, coordinator, max_restarts
        self.still_held = still_held  # raises NodeLost while a replacement waits for CPUs that are gone
        self.restarts = 0
        self.handle = spawn(0)
        self.steps = EnvironmentSteps(done_steps)
        self.scores: collections.deque[float] = collections.deque(maxlen=100_000)
        self.progress: Callable[[], int] = lambda: self.steps.count
        self.info: dict[str, Any] = {}

    def started(self, info: dict[str, Any]) -> None:
        self.info = info
        self.num_envs, self.obs_shape = info["num_envs"], tuple(info["obs_shape"])
        self.keeps_scores = info["keeps_scores"]

    def wait(self, ref: Any, check: Callable[[], None] | None = None) -> Any:
        """The value of ``ref``, once ready, while the run goes on and ``check()`` passes."""
        import ray

        polls = 0
        while not ray.wait([ref], timeout=POLL_SECONDS)[0]:
            self.coordinator.check()
            polls += 1
            if check is not None and polls % round(CHECK_SECONDS / POLL_SECONDS) == 0:
                check()
        return ray.get(ref)

    def _call(self, method: str, *args: Any) -> Transition:
        import ray
        from ray.exceptions import RayActorError, WorkerCrashedError

        while True:
            try:
                if self.handle is None:  # a replacement for a collector that died
                    self.handle = self.spawn(self.restarts)
                    self.started(self.wait(self.handle.describe.remote(), self.still_held))
                trajectory, scores, steps = self.wait(getattr(self.handle, method).remote(*args))
                break
            except (RayActorError, WorkerCrashedError) as error:
                self.coordinator.check()  # the run is ending: its actors are being killed
                self.restarts += 1
                if self.restarts > self.max_restarts:
                    raise RuntimeError(f"Ray actor processes died {self.restarts} times") from error
                died = type(error).__name__
                print(f"warning: a Ray actor process died ({died}); restarting it", file=sys.stderr)
                ray.kill(self.handle, no_restart=True)
                self.handle = None
        self.steps.count += steps
        self.scores.extend(scores)
        return unpack_frames(trajectory)

    def rollout(self, published: Any, num_steps: int) -> Transition:
        return self._call("rollout", [published], num_steps)

    def episodes_from_reset(self, published: Any, max_steps: int) -> Transition:
        return self._call("episodes_from_reset", [published], max_steps)

    def collect(self, published: Any, observer: Callable[[Transition], None], amount: int) -> None:
        trajectory = self._call("collect", [published], amount, int(self.progress()))
        for t in range(len(trajectory.reward)):
            observer(jax.tree.map(lambda x, t=t: x[t], trajectory))

    def finished_returns(self) -> list[float]:
        return [self.scores.popleft() for _ in range(len(self.scores))]

    def close(self) -> None:
        import ray

        if self.handle is not None:
            ray.kill(self.handle, no_restart=True)


def ray_fleet(agent: Agent, make_agent: Callable[[], Agent], env_id: str, runner: RayRunnerConfig, ray: Any):
    """A :data:`~agentax.runners.parallel.MakeFleet` of :class:`Collector` processes spread over the
    cluster, each with a thread actor's envs, seeds and key."""
    envs_per_actor = agent.experience.num_envs // runner.actors
    collector = ray.remote(Collector)

    def share(version: int, state: Any) -> tuple[int, Any]:
        return version, ray.put(jax.device_get(acting_view(state)))

    def make(coordinator: Coordinator, updates: int, done_steps: int, actors_key: jax.Array) -> Fleet:
        check_cpus(runner, ray.cluster_resources().get("CPU", 0))

        def spawn(index: int, restarts: int) -> Any:
            seed = actor_seed(runner.seed, index, updates) + RESTART_SEED_STRIDE * restarts
            key = fold_actor_key(actors_key, index, updates)
            if restarts:
                key = jax.random.fold_in(key, restarts)
            options = {"num_cpus": runner.cpus_per_actor, "scheduling_strategy": "SPREAD", "max_restarts": 0}
            return collector.options(**options).remote(
                make_agent, env_id, runner, envs_per_actor, seed, np.asarray(jax.random.key_data(key))
            )

        actors = [
            RemoteActor(
                functools.partial(spawn, i),
                coordinator,
                done_steps // runner.actors,
                runner.max_actor_restarts,
                lambda: check_cpus(runner, ray.cluster_resources().get("CPU", 0), started=True),
            )
            for i in range(runner.actors)
        ]
        try:
            infos = [actor.handle.describe.remote() for actor in actors]  # they start side by side
            for actor, info in zip(actors, infos, strict=True):
                actor.started(actor.wait(info))
        except BaseException:
            for actor in actors:
                actor.close()
            raise

        def figures() -> dict[str, float]:
            return {
                "actor_restarts": sum(a.restarts for a in actors),
                "actor_nodes": len({a.info["node"] for a in actors}),
            }

        nodes = figures()["actor_nodes"]
        where = f"{runner.actors} Ray actors on {nodes} node{'s' if nodes > 1 else ''}"
        return Fleet(actors, where, share, figures)

    return make


def check_cpus(runner: RayRunnerConfig, cpus: float, started: bool = False) -> None:
    """A ``UsageError`` (``NodeLost`` once ``started``) where a cluster of ``cpus`` CPUs has fewer
    than the actors reserve: they would wait forever."""
    wanted = runner.actors * runner.cpus_per_actor
    if wanted <= cpus:
        return
    if started:
        raise NodeLost(
            f"a Ray node was lost and with it the CPUs of the run's actors ({runner.actors} actors × "
            f"{runner.cpus_per_actor:g} CPU, {cpus:g} CPUs left): join a node"
        )
    raise UsageError(
        f"{runner.actors} actors × {runner.cpus_per_actor:g} CPU need {wanted:g} CPUs, the Ray cluster "
        f"has {cpus:g}: join more nodes, or set --cpus-per-actor {cpus / runner.actors:.2g}"
    )


# the watcher: reads until this process ends; without a "done" first, it says what to do
RESUME_HINT_CODE = """import os, shlex, sys
if sys.stdin.buffer.read() != b"done":
    run = sys.argv[1]
    checkpoints = os.path.join(run, "checkpoints")
    if os.path.isdir(checkpoints) and os.listdir(checkpoints):
        then = "continue from its last checkpoint with: agentax train --resume " + shlex.quote(run)
    else:
        then = "it had saved no checkpoint yet: start it again"
    lost = "the Ray node of its learner was lost (or the process was killed)"
    sys.stderr.write(f"agentax train: error: Ray ended the run in {run}: {lost}; {then}\\n")
"""


@contextmanager
def hint_if_ray_ends_this_process(run: Run | None) -> Iterator[None]:
    """A watcher process (:data:`RESUME_HINT_CODE`) that says how to continue where Ray ends this
    process itself (``_Exit(1)``: its node lost), and ends quietly when the block ends any other way."""
    if run is None:
        yield
        return
    watcher = subprocess.Popen(  # fork_exec in C: no Python runs in a fork of this multithreaded process
        [sys.executable, "-I", "-S", "-c", RESUME_HINT_CODE, str(run.path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        start_new_session=True,  # Ctrl-C in the terminal is the run's, not the watcher's
    )
    try:
        yield
    finally:
        try:
            watcher.communicate(b"done", timeout=10)  # the watcher ends once it has read "done"
        except subprocess.TimeoutExpired:
            watcher.kill()
            watcher.wait()


def train(
    agent: Agent,
    env_id: str,
    runner: RayRunnerConfig,
    run: Run | None = None,
    *,
    make_agent: Callable[[], Agent],
    resume: bool = False,
    progress: bool = False,
) -> TrainResult:
    """Train ``agent`` on ``env_id`` with ``runner.actors`` Ray actors and a learner in this process;
    ``make_agent()`` (picklable) builds the same agent in each actor process."""
    imported = sys.modules.get("ray")  # (imported once a run, or the user, connects to a Ray)
    if runner.ray_address is None and not (imported and imported.is_initialized()):
        # the run's own Ray will have this machine's CPUs: too few is said before it starts (seconds)
        check_cpus(runner, os.cpu_count() or 1)
    with hint_if_ray_ends_this_process(run), ray_session(runner.ray_address) as ray:
        fleet = ray_fleet(agent, make_agent, env_id, runner, ray)
        try:
            return parallel.train(agent, env_id, runner, run, resume=resume, progress=progress, fleet=fleet)
        except NodeLost as lost:
            if run is not None and checkpoints(run.path):
                lost.run_dir = str(run.path)  # the CLI adds: continue with agentax train --resume DIR
            elif run is not None:
                lost.args = (f"{lost}; the run had saved no checkpoint yet: start it again",)
            raise
