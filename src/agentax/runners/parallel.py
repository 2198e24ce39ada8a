"""Collection and training in parallel: actor threads, one learner, a rate limiter, a parameter channel.

Each actor thread steps its own vector env (the host runner's :class:`Actor`); the learner, the
calling thread, runs ``agent.learn``. On-policy, rollout ``k`` is collected with parameter version
``k - policy_lag`` exactly (lag 0: the host runner's numbers); off-policy, the actors fill one locked
replay buffer as a :class:`RateLimiter` allows. An exception in any thread is raised from
:func:`train` (design.md, "Collection and learning in parallel").
"""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from agentax import kernel_choice
from agentax.agents.protocol import Agent, Episodes, OffPolicy
from agentax.errors import UsageError
from agentax.runners import host
from agentax.runners.coordination import (
    Coordinator,
    ParameterChannel,
    RateLimiter,
    Stopped,
    interrupted_at_a_safe_point,
    put,
    take,
)
from agentax.runners.driver import FinishedReturns, ReplayObserver
from agentax.runners.host import (
    Actor,
    HostRunnerConfig,
    OffPolicyLearner,
    actor_seed,
    collection_over,
    env_factory,
    fold_actor_key,
    host_session,
    num_updates,
    one_seed_settings,
    record_returns,
    refuse_seeds,
    replay_for,
)
from agentax.runners.session import Session, TrainResult, split_key
from agentax.runs import Run


@dataclass(frozen=True)
class ParallelRunnerConfig(HostRunnerConfig):
    """The host runner's settings and the actors'; saved in config.json under "runner"."""

    actors: int = 2
    """actor threads; the agent's envs are split evenly between them"""
    policy_lag: int = 1
    """on-policy: parameter versions between collecting a rollout and learning from it (0: sequential)"""
    publish_every: int = 1
    """off-policy: learning phases between parameter publishes"""

    def check(self, agent: Agent) -> None:
        """A ``UsageError`` for settings this agent cannot run with."""
        if self.actors < 1 or self.policy_lag < 0 or self.publish_every < 1:
            raise UsageError("--actors and --publish-every must be at least 1, --policy-lag at least 0")
        num_envs = agent.experience.num_envs
        if num_envs % self.actors:
            raise UsageError(
                f"{num_envs} envs do not split evenly over {self.actors} actors (set --num-envs)"
            )
        if isinstance(agent.experience, OffPolicy) and agent.experience.by_episode:
            raise UsageError("the episode schedule (--schedule-unit episodes) runs on the host runner only")


Config = ParallelRunnerConfig
restore = host.restore  # the checkpoints hold (agent state, learner key) too
DEFAULT_ACTORS = 2  # without --actors, where the envs split in two


def algorithm_config(cfg: Any, run_args: Any) -> Any:
    """The algorithm's ``cfg`` with ``--actors × --envs-per-actor`` envs (or episodes per update)."""
    if run_args.envs_per_actor is None:
        return cfg
    envs = "num_envs" if hasattr(cfg, "num_envs") else "episodes_per_update"
    actors = run_args.actors or DEFAULT_ACTORS
    return dataclasses.replace(cfg, **{envs: actors * run_args.envs_per_actor}).validate()


def configure(run_args: Any, agent: Agent, preset: Any) -> tuple[ParallelRunnerConfig, str]:
    """The parallel runner's settings for a run (:mod:`agentax.runners.launch`)."""
    return configure_actors(run_args, agent, preset, "parallel", ParallelRunnerConfig, "actor")


def configure_actors(
    run_args: Any, agent: Agent, preset: Any, kind: str, config_type: type, actor: str, **settings: Any
) -> tuple[Any, str]:
    """The ``kind`` runner's settings (the one-seed ones, ``--actors``, ``--policy-lag`` and
    ``settings``), checked against the agent, and its announcement: "2 actors, policy lag 1"."""
    refuse_seeds(run_args, kind)
    num_envs = agent.experience.num_envs
    actors = run_args.actors or (DEFAULT_ACTORS if num_envs % DEFAULT_ACTORS == 0 else 1)
    common = one_seed_settings(run_args, preset, kind)
    runner = config_type(**common, actors=actors, policy_lag=run_args.policy_lag, **settings)
    runner.check(agent)
    where = f"{runner.actors} {actor}{'s' if runner.actors > 1 else ''}"
    if not isinstance(agent.experience, OffPolicy):
        where += f", policy lag {runner.policy_lag}"
    return runner, where


class ActorThread(threading.Thread):
    """Runs ``work(actor)`` in a daemon thread; an error stops the whole run through the coordinator."""

    def __init__(self, actor: Actor, work: Callable[[Actor], None], coordinator: Coordinator, index: int):
        super().__init__(daemon=True, name=f"actor-{index}")
        self.actor, self.work, self.coordinator = actor, work, coordinator
        self.wait_seconds = 0.0
        self.lag_sum, self.lag_count = 0.0, 0

    def run(self) -> None:
        try:
            self.work(self)
        except Stopped:
            pass
        except BaseException as error:  # handed to the learner, never lost in a thread
            self.coordinator.fail(error)


class Meter:
    """A row's speeds, wait fractions and mean policy lag since the row before."""

    def __init__(self, threads: list[ActorThread], extra: Callable[[], dict[str, float]] | None = None):
        self.threads, self.extra = threads, extra
        self.time = time.perf_counter()
        self.collected = self.learned = 0
        self.actor_wait = self.learner_wait = 0.0
        self.lag_sum, self.lag_count, self.lag = 0.0, 0, 0.0

    def row(self, collected: int, learned: int, learner_wait: float) -> dict[str, float]:
        now = time.perf_counter()
        seconds = max(now - self.time, 1e-9)
        actor_wait = sum(t.wait_seconds for t in self.threads)
        lag_sum, lag_count = sum(t.lag_sum for t in self.threads), sum(t.lag_count for t in self.threads)
        if lag_count > self.lag_count:  # else no rollout since the last row: the last lag stands
            self.lag = (lag_sum - self.lag_sum) / (lag_count - self.lag_count)
        figures = {
            "actor_steps_per_second": (collected - self.collected) / seconds,
            "learner_updates_per_second": (learned - self.learned) / seconds,
            "actor_wait_fraction": (actor_wait - self.actor_wait) / (seconds * len(self.threads)),
            "learner_wait_fraction": (learner_wait - self.learner_wait) / seconds,
            "policy_lag": float(self.lag),
            **(self.extra() if self.extra else {}),
        }
        self.time, self.collected, self.learned = now, collected, learned
        self.actor_wait, self.learner_wait = actor_wait, learner_wait
        self.lag_sum, self.lag_count = lag_sum, lag_count
        return figures


@dataclass
class Fleet:
    """A parallel training's actors (with the host :class:`Actor`'s interface); ``share`` turns a
    published state into what they receive, ``figures()`` adds columns to each row."""

    actors: list[Any]
    description: str
    share: Callable[[int, Any], Any] = lambda version, state: state  # threads share the learner's memory
    figures: Callable[[], dict[str, float]] | None = None

    def finished_returns(self) -> list[float]:
        """The actors' returns of the episodes (or whole games) finished since the last call."""
        return [r for actor in self.actors for r in actor.finished_returns()]

    def close(self) -> None:
        for actor in self.actors:
            actor.close()


MakeFleet = Callable[[Coordinator, int, int, jax.Array], Fleet]
"""``make(coordinator, updates, done_steps, actors_key) -> Fleet``: a run's actors, (re)started
after ``updates`` learning steps and ``done_steps`` env steps."""


def thread_fleet(agent: Agent, env_id: str, runner: ParallelRunnerConfig) -> MakeFleet:
    """Actors in this process, run by actor threads."""
    make_env = env_factory(env_id, runner)
    envs_per_actor = agent.experience.num_envs // runner.actors

    def make(coordinator: Coordinator, updates: int, done_steps: int, actors_key: jax.Array) -> Fleet:
        actors = [
            Actor(
                agent,
                make_env(envs_per_actor, training=True),
                actor_seed(runner.seed, i, updates),
                fold_actor_key(actors_key, i, updates),
                done_steps // runner.actors,
            )
            for i in range(runner.actors)
        ]
        return Fleet(actors, f"{runner.actors} actor{'s' if runner.actors > 1 else ''}")

    return make


def train(
    agent: Agent,
    env_id: str,
    runner: ParallelRunnerConfig,
    run: Run | None = None,
    *,
    resume: bool = False,
    progress: bool = False,
    fleet: MakeFleet | None = None,
) -> TrainResult:
    """Train ``agent`` on ``env_id`` with ``runner.actors`` actors (threads, unless ``fleet`` makes
    them elsewhere) and a learner."""
    runner.check(agent)
    session = host_session(agent, env_id, runner, run, resume)
    state, updates, done_steps = session.state, session.updates, session.env_steps
    coordinator = Coordinator()
    make_fleet = fleet or thread_fleet(agent, env_id, runner)
    threads: list[ActorThread] = []
    fleet = None
    try:
        fleet = make_fleet(coordinator, updates, done_steps, session.actors_key)
        logger = session.begin(f"{agent.name} {env_id} ({fleet.description})", progress)
        learner = _off_policy if isinstance(agent.experience, OffPolicy) else _on_policy
        loop = Loop(agent, runner, fleet, threads, coordinator, session)
        with logger, interrupted_at_a_safe_point(coordinator):
            state, updates, env_steps = learner(loop, state, session.learner_key, updates, done_steps)
    finally:
        coordinator.stop.set()
        for thread in threads:
            thread.join(timeout=10)
        if fleet is not None:
            fleet.close()
    return session.finish(state, env_steps, updates)


@dataclass
class Loop:
    """What a learner's loop works with; ``drain()`` gives the returns finished since the last row."""

    agent: Agent
    runner: ParallelRunnerConfig
    fleet: Fleet
    threads: list[ActorThread]
    coordinator: Coordinator
    session: Session
    drain: Callable[[], list[float]] | None = None
    meter: Meter | None = None
    replay: Any = None
    learner_wait: float = 0.0

    def start(self, collect: Callable[[ActorThread, int], None]) -> None:
        """Start an actor thread per actor, running ``collect(thread, index)``."""
        for i, actor in enumerate(self.fleet.actors):
            self.threads.append(
                ActorThread(actor, lambda thread, i=i: collect(thread, i), self.coordinator, i)
            )
        self.meter = Meter(self.threads, self.fleet.figures)
        for thread in self.threads:
            thread.start()

    def maybe_log(self, state, learner_key, env_steps, collected, updates, metrics, final) -> bool:
        """Log (and checkpoint) when due; returns True once the run has reached ``stop_at_return``."""
        if not self.session.row_due(env_steps, final):
            return False
        extra = self.meter.row(collected, updates, self.learner_wait)
        if self.replay is not None:
            extra.update(replay_size=self.replay.size, replay_bytes=self.replay.nbytes)
        args = (state, learner_key, env_steps, updates, self.drain(), metrics)
        return self.session.log_row(*args, final=final, extra=extra, counts={"episodes": 0})


def _on_policy(loop: Loop, state: Any, learner_key: jax.Array, updates: int, done_steps: int):
    """Learn from rollout ``k`` of every actor, collected with parameter version ``k - policy_lag``."""
    agent, runner, coordinator = loop.agent, loop.runner, loop.coordinator
    experience, actors = agent.experience, loop.fleet.actors
    last_update = num_updates(agent)
    channel = ParameterChannel(
        coordinator, updates, state, keep=runner.policy_lag + 2, share=loop.fleet.share
    )
    queues = [queue.Queue(maxsize=1) for _ in actors]
    first_update = updates  # the learner's loop below moves ``updates`` on; the actors count from here

    def collect(thread: ActorThread, index: int) -> None:
        for k in range(first_update, last_update):
            version = max(k - runner.policy_lag, first_update)
            params, waited = channel.get(version)
            if isinstance(experience, Episodes):
                trajectory = thread.actor.episodes_from_reset(params, experience.max_steps)
            else:
                trajectory = thread.actor.rollout(params, experience.num_steps)
            thread.wait_seconds += waited + put(queues[index], (version, trajectory), coordinator)

    learn = jax.jit(agent.learn)
    returns = FinishedReturns()
    # from what was learned, so runs repeat; whole Atari games from the envs
    loop.drain = loop.fleet.finished_returns if actors[0].keeps_scores else returns.drain
    env_steps, metrics = done_steps, {}
    loop.start(collect)
    for k in range(updates, last_update):
        parts = []
        for q, thread in zip(queues, loop.threads, strict=True):
            (version, trajectory), waited = take(q, coordinator)
            loop.learner_wait += waited
            thread.lag_sum, thread.lag_count = thread.lag_sum + k - version, thread.lag_count + 1
            parts.append(trajectory)
        trajectory = jax.tree.map(lambda *xs: np.concatenate(xs, axis=1), *parts)
        learner_key, learn_key = split_key(learner_key)
        state, metrics = learn(state, trajectory, learn_key)
        updates = k + 1
        channel.publish(updates, state)
        env_steps += record_returns(returns, trajectory, isinstance(experience, Episodes))
        collected = sum(a.steps.count for a in actors)
        if loop.maybe_log(state, learner_key, env_steps, collected, updates, metrics, updates == last_update):
            break
    return state, updates, env_steps


def _off_policy(loop: Loop, state: Any, learner_key: jax.Array, updates: int, done_steps: int):
    """Actors fill the shared replay as the rate limiter allows; the learner learns as it allows."""
    agent, runner, coordinator = loop.agent, loop.runner, loop.coordinator
    experience: OffPolicy = agent.experience
    actors = loop.fleet.actors
    loop.replay = replay = replay_for(agent, actors[0].obs_shape, runner.seed)
    loop.session.keep_replay(replay)
    loop.drain = loop.fleet.finished_returns
    chunk = experience.train_frequency * (experience.num_envs // runner.actors)
    ratio, slack = experience.learning_steps_per_env_step, chunk * len(actors)
    limiter = RateLimiter(coordinator, ratio, experience.learning_starts, slack=slack)
    limiter.inserted, limiter.learned = done_steps, updates
    channel = ParameterChannel(coordinator, 0, state, keep=2, share=loop.fleet.share)
    total = agent.total_steps

    def collect(thread: ActorThread, index: int) -> None:
        envs = slice(index * thread.actor.num_envs, (index + 1) * thread.actor.num_envs)
        observer = ReplayObserver(replay, experience.n_step, experience.discount_factor, envs)
        thread.actor.progress = lambda: limiter.inserted  # ε follows the whole run's env steps
        while True:
            thread.wait_seconds += limiter.await_insert()
            with limiter.condition:
                if limiter.inserted >= total:
                    return
            version, params = channel.latest()
            before = thread.actor.steps.count
            thread.actor.collect(params, observer, experience.train_frequency)
            thread.lag_sum += channel.latest()[0] - version
            thread.lag_count += 1
            limiter.inserted_steps(thread.actor.steps.count - before)

    learner = OffPolicyLearner(agent, replay, loop=kernel_choice.learning_loop_for(actors[0].obs_shape))
    metrics, phases = {}, 0
    loop.start(collect)
    while True:
        with limiter.condition:
            if limiter.inserted >= total and not limiter.closed:
                limiter.closed = True
        ready, waited = limiter.await_learn()
        loop.learner_wait += waited
        if ready and replay.size:
            learner_key, learn_key = split_key(learner_key)
            state, metrics = learner.phase(state, learn_key, limiter.inserted)
            updates += experience.gradient_steps
            limiter.learned_steps(experience.gradient_steps)
            phases += 1
            if phases % runner.publish_every == 0:
                channel.publish(phases, state)
        env_steps = limiter.inserted
        final = not ready and collection_over(agent, env_steps, 0)
        if env_steps >= total and not final:
            continue  # collected all: the last row waits for the learner to catch up
        if loop.maybe_log(state, learner_key, env_steps, env_steps, updates, metrics, final) or final:
            break
    return state, updates, limiter.inserted
