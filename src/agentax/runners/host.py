"""The host runner: any agent of :mod:`agentax.agents.protocol` on any env id, stepped on the host.

TF-Agents' loop, one step after the other: an :class:`Actor` collects a rollout, whole episodes or
replay through a :class:`~agentax.runners.driver.Driver`, then ``agent.learn`` (jitted) trains on
it. Checkpoints hold ``(agent state, learner key)``, the replay buffer or a recurrent agent's actor
beside them (design.md, "The host runners, module by module").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from agentax import _xla, kernel_choice
from agentax.agents.protocol import PRIORITY, Agent, Episodes, Loop, OffPolicy, OnPolicy
from agentax.envs import make_host_env
from agentax.errors import UsageError
from agentax.evaluate import host_episode_returns
from agentax.nets import is_image
from agentax.policies import Policy, with_random_actions
from agentax.replay import Transition, example_transition
from agentax.replay.host import ReplayBuffer
from agentax.runners.driver import (
    Driver,
    EnvironmentSteps,
    FinishedReturns,
    NumberOfEpisodes,
    ReplayObserver,
    TrajectoryObserver,
    first_time_step,
)
from agentax.runners.host_memory import CarriedMemory, act_and_split, keep_actor
from agentax.runners.replay_program import example_action
from agentax.runners.rollout import scalars
from agentax.runners.session import Session, TrainResult, checkpoint_target, split_key
from agentax.runs import Run, load_checkpoint


@dataclass(frozen=True)
class HostRunnerConfig:
    """How the host runner schedules one training; saved in config.json under "runner"."""

    seed: int = 0
    """seed of the agent and of the envs"""
    log_every_steps: int = 2_048
    """write a metrics row every this many env steps"""
    eval_episodes: int = 10
    """episodes of the final evaluation (and of the stop-at-return checks)"""
    stop_at_return: float | None = None
    """stop once an evaluation (run at each row) reaches this mean return (None: train to the end)"""
    checkpoint_every_seconds: float = 30.0
    """write a checkpoint at most this often (and at the end)"""
    env_backend: str = "auto"
    """Atari only: envpool or ale (auto: envpool where it is installed)"""
    sticky_actions: float = 0.25
    """Atari only: the probability that the emulator repeats the last action (Gymnasium's v5: 0.25)"""
    checkpoint_replay: bool = True
    """off-policy: keep the replay buffer beside the checkpoints, so a resumed run has its experience"""
    replay_checkpoint_every_seconds: float = 600.0
    """off-policy: save the replay at most this often (it can hold gigabytes), and at the end"""


Config = HostRunnerConfig


def one_seed_settings(run_args: Any, preset: Any, kind: str) -> dict[str, Any]:
    """The settings of ``run_args`` every one-seed-per-process runner reads; the compiled runner's
    own flags refused for the ``kind`` runner."""
    if (run_args.workers or 1) > 1:
        raise UsageError(
            f"--workers splits the compiled runner's seeds over processes; the {kind} runner trains one "
            "seed (train a JAX env with --runner compiled, or drop the flag)"
        )
    if run_args.freeze_at_return not in ("auto", "none"):
        raise UsageError(
            f"--freeze-at-return stops seeds inside the compiled runner's program; the {kind} "
            "runner cannot (train a JAX env with --runner compiled, or drop the flag)"
        )
    return {
        "seed": run_args.seed,
        "eval_episodes": preset.eval_episodes,
        "stop_at_return": run_args.stop_at_return,
        "checkpoint_replay": run_args.checkpoint_replay,
        "env_backend": run_args.env_backend,
        "sticky_actions": run_args.sticky_actions,
    }


def refuse_seeds(run_args: Any, kind: str) -> None:
    """``--seeds N`` is the compiled runner's: the ``kind`` runner trains one seed per process."""
    if run_args.seeds != 1:
        raise UsageError(
            f"the {kind} runner trains one seed per process (--seeds 1); --seeds N is compiled-only"
        )


def configure(run_args: Any, agent: Agent, preset: Any) -> tuple[HostRunnerConfig, str]:
    """The host runner's settings for a run (:mod:`agentax.runners.launch`)."""
    refuse_seeds(run_args, "host")
    return HostRunnerConfig(**one_seed_settings(run_args, preset, "host")), "host"


def env_factory(env_id: str, runner: Any) -> Callable[..., Any]:
    """``make(num_envs, training=False)``: the run's envs, with the runner's Atari options."""
    options = {"backend": runner.env_backend, "sticky_actions": runner.sticky_actions}
    return lambda num_envs, training=False: make_host_env(env_id, num_envs, training=training, **options)


def fold_actor_key(actors_key: jax.Array, index: int, updates: int) -> jax.Array:
    """Actor ``index``'s key, in a run (re)started after ``updates`` learning steps."""
    return jax.random.fold_in(jax.random.fold_in(actors_key, updates), index)


def actor_seed(seed: int, index: int, updates: int) -> int:
    """The seed of actor ``index``'s envs, in a run (re)started after ``updates`` learning steps."""
    return seed + 1000 * index + 7919 * updates


class _Ends(NamedTuple):  # what a returns tracker reads of one step [E]
    reward: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray


def record_returns(returns: FinishedReturns, trajectory: Transition, episodes: bool) -> int:
    """Feed a trajectory ``[T, E]`` to ``returns``; the env steps it holds. With ``episodes`` only
    each env's first episode counts (``info["valid"]``), ended by the step limit."""
    reward, terminated, truncated = trajectory.reward, trajectory.terminated, trajectory.truncated
    if episodes:
        valid = trajectory.info["valid"]
        reward, terminated = reward * valid, terminated & valid
        truncated = (truncated | (np.arange(len(reward)) == len(reward) - 1)[:, None]) & valid
    for t in range(len(reward)):
        returns(_Ends(reward[t], terminated[t], truncated[t]))
    return int(trajectory.info["valid"].sum()) if episodes else reward.size


class Actor:
    """One actor: its own vector env, the collect policy on the parameters it is given, a Driver.
    ``progress()`` is what the policy's schedules (DQN's ε) read: the run's env steps (or episodes)."""

    def __init__(self, agent: Agent, env: Any, seed: int, key: jax.Array, done_steps: int = 0):
        self.agent, self.env, self.num_envs = agent, env, env.num_envs
        self.obs_shape = tuple(env.observation_space().shape)
        self.keeps_scores = hasattr(env, "drain_scores")  # true scores of whole games (Atari)
        self.seed, self.key = seed, key
        self.memory = CarriedMemory(agent, self.num_envs) if agent.recurrent is not None else None
        self.act = self.memory.act if self.memory is not None else jax.jit(act_and_split(agent.act))
        self.env_action = jax.jit(agent.env_action)  # one call, not one per jnp operation on the host
        self.state: Any = None
        self.steps, self.episodes = EnvironmentSteps(done_steps), NumberOfEpisodes()
        self.returns = FinishedReturns()
        self.by_episode = isinstance(agent.experience, OffPolicy) and agent.experience.by_episode
        self.progress = lambda: self.episodes.count if self.by_episode else self.steps.count
        self.time_step = first_time_step(self.env, seed)

    def finished_returns(self) -> list[float]:
        """The returns of the episodes (or whole Atari games) finished since the last call."""
        if self.keeps_scores:
            return [score for score, _ in self.env.drain_scores()]
        return self.returns.drain()

    def policy(self, obs: np.ndarray, key: jax.Array) -> tuple[np.ndarray, jax.Array, Any]:
        action, info, key = self.act(self.state, obs, key, self.progress())
        action, info = jax.device_get((action, info))
        return action, key, info or None

    def _run(self, observers: list, **limits: int) -> None:
        counters = [self.steps, self.episodes, self.returns, *([self.memory] if self.memory else [])]
        driver = Driver(
            self.env, self.policy, [*counters, *observers], action_to_env=self.env_action, **limits
        )
        self.time_step, self.key = driver.run(self.time_step, self.key)

    def rollout(self, state: Any, num_steps: int) -> Transition:
        """``num_steps`` steps of every env with ``state``'s collect policy: a trajectory ``[T, E]``."""
        self.state, trajectory = state, TrajectoryObserver()
        self._run([trajectory], max_steps=num_steps * self.env.num_envs)
        return trajectory.trajectory()

    def episodes_from_reset(self, state: Any, max_steps: int) -> Transition:
        """One episode per env from a fresh reset: a trajectory ``[max_steps, E]`` whose
        ``info["valid"]`` marks the steps inside each first episode."""
        self.state, trajectory = state, TrajectoryObserver()
        self.seed += self.env.num_envs
        self.time_step = first_time_step(self.env, self.seed)
        if self.memory is not None:
            self.memory.restart()
        alive = np.ones(self.env.num_envs, bool)
        steps_before = self.steps.count
        for _ in range(max_steps):
            if alive.any():
                self._run([trajectory], max_steps=self.env.num_envs)
                last = trajectory.transitions[-1]
                step = last.replace(info={**(last.info or {}), "valid": alive.copy()})  # memory, first
                trajectory.transitions[-1] = step
                alive &= ~(step.terminated | step.truncated)
            else:  # everyone finished: pad (a fixed shape, one compiled learning step)
                pad = jax.tree.map(np.zeros_like, trajectory.transitions[-1])
                trajectory.transitions.append(pad)
        self.steps.count = steps_before + int(sum(t.info["valid"].sum() for t in trajectory.transitions))
        return trajectory.trajectory()

    def collect(self, state: Any, replay: ReplayObserver, amount: int) -> None:
        """``amount`` steps per env (or ``amount`` episodes, in the episode schedule) into the replay."""
        self.state = state
        limit = {"max_episodes": amount} if self.by_episode else {"max_steps": amount * self.num_envs}
        self._run([replay], **limit)

    def close(self) -> None:
        self.env.close()


def replay_for(agent: Agent, obs_shape: tuple[int, ...], seed: int) -> Any:
    """An empty host replay buffer for ``agent`` on observations ``obs_shape``: frame-deduplicated
    for stacked frames, else a plain one."""
    experience = agent.experience
    sampling = {
        "prioritized": experience.prioritized,
        "priority_exponent": experience.priority_exponent,
        "seed": seed,
    }
    if is_image(obs_shape):
        from agentax.replay.frames import FrameReplayBuffer

        return FrameReplayBuffer(
            experience.capacity,
            experience.num_envs,
            stack=obs_shape[0],
            frame_shape=obs_shape[1:],
            n_step=experience.n_step,
            discount_factor=experience.discount_factor,
            **sampling,
        )
    obs = np.zeros(obs_shape, np.float32)
    one = jax.device_get(example_transition(obs, example_action(agent, obs[None])))
    return ReplayBuffer(experience.capacity, one, **sampling)


class OffPolicyLearner:
    """Learning phases of ``gradient_steps`` steps on a replay buffer: one compiled call on batches
    drawn ahead (uniform replay), step by step (prioritized); each returns the scalar metrics' means."""

    def __init__(self, agent: Agent, replay: Any, loop: Loop = jax.lax.scan):
        self.experience: OffPolicy = agent.experience
        self.replay = replay
        self.learn = jax.jit(agent.learn)

        def learn_many(state, samples, key):
            def one(state, sample_and_key):
                state, metrics = agent.learn(state, *sample_and_key)
                return state, scalars(metrics)

            keys = jax.random.split(key, self.experience.gradient_steps)
            state, metrics = loop(one, state, (samples, keys))
            return state, jax.tree.map(lambda m: m.mean(), metrics)

        self.learn_many = jax.jit(learn_many)
        self.dataset = None

    def phase(self, state: Any, key: jax.Array, env_steps: int) -> tuple[Any, dict[str, Any]]:
        experience = self.experience
        if not experience.prioritized:
            if self.dataset is None:
                self.dataset = self.replay.as_dataset(experience.batch_size, experience.gradient_steps)
            learned = self.learn_many(state, next(self.dataset), key)  # dispatched: XLA works on it
            self.dataset.refill()  # meanwhile the batch of a later phase is drawn
            return learned
        beta = float(experience.importance_exponent(env_steps))
        steps = []
        for step_key in jax.random.split(key, experience.gradient_steps):
            sample = self.replay.sample(experience.batch_size, beta)
            state, metrics = self.learn(state, sample, step_key)
            metrics = jax.device_get(metrics)
            self.replay.update_priorities(sample.indices, metrics[PRIORITY])
            steps.append({name: value for name, value in metrics.items() if np.ndim(value) == 0})
        return state, {name: np.mean([step[name] for step in steps]) for name in steps[0]}


def learning_started(experience: OffPolicy, actor_steps: int, actor_episodes: int) -> bool:
    if experience.by_episode:
        return actor_episodes > experience.learning_starts
    return actor_steps >= experience.learning_starts


def num_updates(agent: Agent) -> int:
    """Learning iterations of an on-policy agent's whole run (as the compiled runner counts them)."""
    experience = agent.experience
    steps = experience.max_steps if isinstance(experience, Episodes) else experience.num_steps
    return max(1, agent.total_steps // (experience.num_envs * steps))


def collection_over(agent: Agent, env_steps: int, episodes: int, updates: int = 0) -> bool:
    """Whether a run has collected all it should: its env steps (off-policy) or iterations (on-policy)."""
    experience = agent.experience
    if not isinstance(experience, OffPolicy):
        return updates >= num_updates(agent)
    max_episodes = experience.max_episodes
    return env_steps >= agent.total_steps or bool(max_episodes and episodes >= max_episodes)


ATARI_EVAL_EPSILON = 0.01  # Atari games are evaluated with 1 % random actions


class Evaluator:
    """The greedy policy's returns and lengths on a side env (whole games with
    ``ATARI_EVAL_EPSILON`` random actions on Atari)."""

    def __init__(self, agent: Agent, make_env: Callable[..., Any], episodes: int):
        self.agent, self.episodes = agent, episodes
        self.env = make_env(min(episodes, 8))
        self.epsilon = ATARI_EVAL_EPSILON if hasattr(self.env, "drain_scores") else 0.0
        self.count = 0

    def __call__(self, state: Any, seed: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        if seed is None:
            seed, self.count = 10_000 + self.count, self.count + 1
        policy = self.agent.greedy_policy(state)
        if self.epsilon:
            policy = with_random_actions(policy, self.epsilon, self.env.action_space().n)
        return host_episode_returns(self.env, policy, self.episodes, seed=seed)

    def close(self) -> None:
        self.env.close()


def host_session(agent: Agent, env_id: str, runner: Any, run: Run | None, resume: bool) -> Session:
    """The :class:`Session` of a run on host envs (XLA on every CPU for actors and learner)."""
    _xla.let_xla_use_every_cpu()
    evaluator = Evaluator(agent, env_factory(env_id, runner), runner.eval_episodes)
    replayed = isinstance(agent.experience, OffPolicy) and runner.checkpoint_replay
    return Session(agent, run, runner, evaluator, resume=resume, with_replay=replayed)


def train(
    agent: Agent,
    env_id: str,
    runner: HostRunnerConfig,
    run: Run | None = None,
    *,
    resume: bool = False,
    progress: bool = False,
) -> TrainResult:
    """Train ``agent`` on ``env_id`` (any Gymnasium id or agentax env), one step after the other."""
    session = host_session(agent, env_id, runner, run, resume)
    experience, make_env = agent.experience, env_factory(env_id, runner)
    state, learner_key, updates = session.state, session.learner_key, session.updates
    actor = Actor(
        agent,
        make_env(experience.num_envs, training=True),
        actor_seed(runner.seed, 0, updates),
        fold_actor_key(session.actors_key, 0, updates),
        session.env_steps,
    )
    actor.episodes.count = int(session.meta.get("episodes", 0))
    learn = jax.jit(agent.learn)
    replayed = isinstance(experience, OffPolicy)
    if replayed:
        replay = replay_for(agent, actor.obs_shape, runner.seed)
        observer = ReplayObserver(replay, experience.n_step, experience.discount_factor)
        learner = OffPolicyLearner(agent, replay, loop=kernel_choice.learning_loop_for(actor.obs_shape))
        session.keep_replay(replay)
    metrics: dict[str, Any] = {}
    # rows' returns: from what was learned (on-policy, as a parallel run logs them), else the actor's
    learned_returns = FinishedReturns()
    keep_actor(session, actor, learned_returns)
    from_actor = replayed or actor.keeps_scores
    drain_returns = actor.finished_returns if from_actor else learned_returns.drain
    with session.begin(f"{agent.name} {env_id}", progress):
        try:
            while not collection_over(agent, actor.steps.count, actor.episodes.count, updates):
                learner_key, learn_key = split_key(learner_key)
                if isinstance(experience, (OnPolicy, Episodes)):
                    if isinstance(experience, Episodes):
                        trajectory = actor.episodes_from_reset(state, experience.max_steps)
                    else:
                        trajectory = actor.rollout(state, experience.num_steps)
                    state, metrics = learn(state, trajectory, learn_key)
                    record_returns(learned_returns, trajectory, isinstance(experience, Episodes))
                    updates += 1
                else:
                    actor.collect(state, observer, experience.train_frequency)
                    if learning_started(experience, actor.steps.count, actor.episodes.count) and replay.size:
                        state, metrics = learner.phase(state, learn_key, actor.steps.count)
                        updates += experience.gradient_steps
                env_steps = actor.steps.count
                finished = collection_over(agent, env_steps, actor.episodes.count, updates)
                if not session.row_due(env_steps, finished):
                    continue
                extra = {"replay_size": replay.size, "replay_bytes": replay.nbytes} if replayed else {}
                counts = {"episodes": actor.episodes.count}
                args = (state, learner_key, env_steps, updates, drain_returns(), metrics)
                if session.log_row(*args, final=finished, extra=extra, counts=counts):
                    break
        finally:
            actor.close()
    return session.finish(state, actor.steps.count, updates)


def restore(run_dir: Path, config: dict[str, Any], agent: Agent) -> Policy:
    """The greedy policy of the newest loadable ``(agent state, learner key)`` checkpoint."""
    (state, _), _, _ = load_checkpoint(run_dir, checkpoint_target(agent))
    return agent.greedy_policy(state)
