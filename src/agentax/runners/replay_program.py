"""The compiled runner's program for an off-policy agent (DQN, SAC, TD3): :func:`off_policy_program`.

Each ``update`` steps ``train_frequency`` env steps (one in the episode schedule) into a jittable
replay through an n-step accumulator, then, where the host runner's learning gates open
(:func:`learning_due`), takes ``gradient_steps`` learning steps on sampled batches. Keys split per
step as ``(key, act, step, monitor)``, as DQN's own loop did, so older runs' numbers hold.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from agentax.agents.protocol import PRIORITY, Agent, OffPolicy
from agentax.replay import example_transition, nstep, prioritized, uniform
from agentax.returns import EpisodeStats
from agentax.runners.rollout import Program, VectorEnv, agent_program, any_seed, scalars, transition_of


@dataclass(frozen=True)
class Freeze:
    """Per-seed early stopping: once each of the last ``episodes`` episodes of the greedy policy on
    ``episodes`` side envs returned at least ``at_return``, the seed collects on but learns no more."""

    at_return: float
    episodes: int = 8


def traced_count_loop(step: Callable, carry: Any, count: jax.Array) -> tuple[Any, dict[str, jax.Array]]:
    """``step(carry, None) -> (carry, metrics)`` run ``count`` times (a traced int: under vmap, as
    long as the largest, the others masked), and the mean of its metrics: the scan of a fixed count."""
    shapes = jax.eval_shape(step, carry, None)[1]
    zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    def body(_, state):
        inner, total = state
        inner, metrics = step(inner, None)
        return inner, jax.tree.map(jnp.add, total, metrics)

    carry, total = jax.lax.fori_loop(0, count, body, (carry, zeros))
    return carry, jax.tree.map(lambda t: t / count, total)


@struct.dataclass
class GreedyMonitor:
    """The side envs of :class:`Freeze`, played by the greedy policy."""

    env_state: Any
    obs: jax.Array  # [episodes, *obs_shape]
    running: jax.Array  # float32 [episodes]: return of each side env's running episode
    returns: jax.Array  # float32 [episodes]: ring of the last finished episodes' returns
    finished: jax.Array  # int32 []: episodes finished so far
    frozen: jax.Array  # bool []


@struct.dataclass
class OffPolicyCarry:
    agent: Any
    replay: Any  # uniform.UniformState or prioritized.PrioritizedState
    accumulator: nstep.NStepState
    env_state: Any
    obs: jax.Array  # float32 [num_envs, *obs_shape]
    episodes: EpisodeStats
    key: jax.Array
    greedy: GreedyMonitor | None = None


@dataclass(frozen=True)
class Replay:
    """The jittable replay an ``OffPolicy`` experience asks for: uniform or prioritized, one call
    shape (prioritized replay's ``update_priorities`` is called where the experience is prioritized)."""

    init: Callable  # (capacity, example) -> state
    add: Callable  # (state, batch, valid) -> state
    sample: Callable  # (state, key, batch_size, beta) -> ReplaySample


def replay_for(experience: OffPolicy) -> Replay:
    if experience.prioritized:
        return Replay(
            init=functools.partial(prioritized.init, priority_exponent=experience.priority_exponent),
            add=prioritized.add,
            sample=prioritized.sample,
        )
    return Replay(
        init=uniform.init,
        add=uniform.add,
        sample=lambda state, key, batch_size, beta: uniform.sample(state, key, batch_size),
    )


def stored_action(action: jax.Array) -> jax.Array:
    """An action as replay keeps it: discrete ones int32, continuous ones float32."""
    return action.astype(jnp.float32 if jnp.issubdtype(action.dtype, jnp.floating) else jnp.int32)


def example_action(agent: Agent, obs: jax.Array) -> jax.Array:
    """A zero action shaped and typed as ``agent.act`` gives one env's (``[]`` int32, or ``[d]`` float32)."""
    state = jax.eval_shape(agent.init, jax.random.key(0))
    action = jax.eval_shape(agent.act, state, obs, jax.random.key(0), jnp.int32(0))[0]
    return stored_action(jnp.zeros(action.shape[1:], action.dtype))


def init_monitor(side_envs: VectorEnv, freeze: Freeze, key: jax.Array) -> GreedyMonitor:
    """The greedy side episodes' monitor before any step: ``freeze.episodes`` envs just reset."""
    obs, env_state = side_envs.reset(key)
    zeros = jnp.zeros(freeze.episodes, jnp.float32)
    return GreedyMonitor(env_state, obs.astype(jnp.float32), zeros, zeros, jnp.int32(0), jnp.bool_(False))


def monitor_step(
    agent: Agent,
    side_envs: VectorEnv,
    freeze: Freeze,
    monitor: GreedyMonitor,
    agent_state: Any,
    key: jax.Array,
) -> GreedyMonitor:
    """One greedy step of every side env; freeze once every return in the ring reaches the mark."""
    num = freeze.episodes
    policy_keys = jax.random.split(jax.random.fold_in(key, 1), num)
    action = jax.vmap(agent.greedy_policy(agent_state))(monitor.obs, policy_keys)
    time_step, env_state, _ = side_envs.step(key, monitor.env_state, action)
    running = monitor.running + time_step.reward
    done = time_step.done
    slot = (monitor.finished + jnp.cumsum(done) - 1) % num  # ring slots of this step's finished episodes
    returns = monitor.returns.at[jnp.where(done, slot, num)].set(running, mode="drop")
    finished = monitor.finished + done.sum(dtype=jnp.int32)
    solved = (finished >= num) & (returns.min() >= freeze.at_return)
    return GreedyMonitor(
        env_state=env_state,
        obs=time_step.obs.astype(jnp.float32),
        running=jnp.where(done, 0.0, running),
        returns=returns,
        finished=finished,
        frozen=monitor.frozen | solved,
    )


def learning_due(experience: OffPolicy, episodes_before: jax.Array, episodes: EpisodeStats) -> jax.Array:
    """Whether a learning phase is due after a collection phase (per env's seed): by env steps once
    ``learning_starts`` passed, or (``by_episode``) every ``train_frequency`` finished episodes."""
    if experience.by_episode:
        ended = episodes.completed > episodes_before
        due = (
            ended
            & (episodes.completed % experience.train_frequency == 0)
            & (episodes_before >= experience.learning_starts)
        )
    else:
        due = episodes.env_steps >= experience.learning_starts
    if experience.max_episodes:
        due = due & (episodes_before < experience.max_episodes)
    return due


def learning_phase(
    agent: Agent, replay: Replay, carry: OffPolicyCarry
) -> tuple[OffPolicyCarry, dict[str, jax.Array]]:
    """``gradient_steps`` learning steps on batches sampled from ``carry.replay`` (priorities written
    back for prioritized replay); the mean of each scalar metric."""
    experience: OffPolicy = agent.experience
    beta = experience.importance_exponent(carry.episodes.env_steps)

    def one(inner, _):
        agent_state, replay_state, key = inner
        # (threefry splits are prefix-stable: key and sample_key are those of a split in two)
        key, sample_key, learn_key = jax.random.split(key, 3)
        sample = replay.sample(replay_state, sample_key, experience.batch_size, beta)
        agent_state, metrics = agent.learn(agent_state, sample, learn_key)
        if experience.prioritized:
            replay_state = prioritized.update_priorities(replay_state, sample.indices, metrics[PRIORITY])
        return (agent_state, replay_state, key), scalars(metrics)

    key, learn_key = jax.random.split(carry.key)
    inner, steps = (carry.agent, carry.replay, learn_key), experience.gradient_steps
    if isinstance(steps, int):
        (agent_state, replay_state, _), metrics = jax.lax.scan(one, inner, length=steps)
        metrics = jax.tree.map(jnp.mean, metrics)
    else:  # a traced count (a sweep over SAC's utd): a loop as long, its metrics averaged
        (agent_state, replay_state, _), metrics = traced_count_loop(one, inner, steps)
    return carry.replace(agent=agent_state, replay=replay_state, key=key), metrics


def no_learning(
    agent: Agent, replay: Replay, carry: OffPolicyCarry
) -> tuple[OffPolicyCarry, dict[str, jax.Array]]:
    """``carry`` as it is, and zeros for :func:`learning_phase`'s metrics."""
    shapes = jax.eval_shape(functools.partial(learning_phase, agent, replay), carry)[1]
    return carry, jax.tree.map(lambda m: jnp.zeros(m.shape, m.dtype), shapes)


def learn_where(
    agent: Agent, replay: Replay, carry: OffPolicyCarry, due: jax.Array
) -> tuple[OffPolicyCarry, dict[str, jax.Array]]:
    """:func:`learning_phase`, what it changes (the agent, the key, prioritized replay's priorities)
    kept only where ``due``: a uniform replay buffer passes through uncopied."""
    learned, metrics = learning_phase(agent, replay, carry)
    no_metrics = no_learning(agent, replay, carry)[1]
    keep = functools.partial(jax.tree.map, lambda new, old: jnp.where(due, new, old))
    kept_replay = keep(learned.replay, carry.replay) if agent.experience.prioritized else carry.replay
    learned = carry.replace(
        agent=keep(learned.agent, carry.agent), replay=kept_replay, key=keep(learned.key, carry.key)
    )
    return learned, keep(metrics, no_metrics)


def off_policy_program(agent: Agent, envs: Any, freeze: Freeze | None = None) -> Program:
    """The :class:`Program` of an off-policy ``agent`` on ``envs``: a :class:`VectorEnv`, or the EnvPool
    runner's pool of one env, whose reset steps store nothing; ``freeze`` needs a VectorEnv."""
    experience: OffPolicy = agent.experience
    replay = replay_for(experience)
    by_episode = experience.by_episode
    length = 1 if by_episode else experience.train_frequency  # collected steps per env an update
    side_envs = None if freeze is None else VectorEnv(envs.env, envs.params, freeze.episodes)
    # On the step schedule every seed of a batch steps alike, so all are due to learn at once and keep
    # what they learned without a select of each state leaf between learned and kept (XLA drops a
    # select on a constant): a copy of every seed's parameters and moments an update saved. Frozen
    # seeds, an episode cap, the episode schedule or a sweep's traced learning_starts set seeds apart.
    alike = not (by_episode or experience.max_episodes or freeze is not None) and not isinstance(
        experience.learning_starts, jax.core.Tracer
    )

    def init(key: jax.Array) -> OffPolicyCarry:
        key, agent_key, reset_key, monitor_key = jax.random.split(key, 4)
        obs, env_state = envs.reset(reset_key)
        one = example_transition(obs[0].astype(jnp.float32), example_action(agent, obs))
        batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (envs.num_envs, *x.shape)), one)
        return OffPolicyCarry(
            agent=agent.init(agent_key),
            replay=replay.init(min(experience.capacity, agent.total_steps), one),  # never more is kept
            accumulator=nstep.init(experience.n_step, batch),
            env_state=env_state,
            obs=obs.astype(jnp.float32),
            episodes=EpisodeStats.create(envs.num_envs),
            key=key,
            greedy=None if freeze is None else init_monitor(side_envs, freeze, monitor_key),
        )

    def collect_step(carry: OffPolicyCarry, _) -> tuple[OffPolicyCarry, dict[str, jax.Array]]:
        key, act_key, step_key, monitor_key = jax.random.split(carry.key, 4)
        progress = carry.episodes.completed if by_episode else carry.episodes.env_steps
        action, info = agent.act(carry.agent, carry.obs, act_key, progress)
        time_step, env_state, env_info = envs.step(step_key, carry.env_state, agent.env_action(action))
        valid = jnp.all(env_info.get("valid", True))  # False on EnvPool's reset step (its one env)
        time_step = time_step.replace(
            obs=time_step.obs.astype(jnp.float32), final_obs=time_step.final_obs.astype(jnp.float32)
        )
        active = (
            carry.episodes.completed < experience.max_episodes if experience.max_episodes else jnp.bool_(True)
        )
        one_step = transition_of(carry.obs, stored_action(action), time_step)
        accumulator, emitted, full = nstep.push(
            carry.accumulator,
            one_step.replace(reward=one_step.reward.astype(jnp.float32)),
            experience.discount_factor,
        )
        carry = carry.replace(
            replay=replay.add(carry.replay, emitted, full & active & valid),
            accumulator=accumulator,
            env_state=env_state,
            obs=time_step.obs,
            episodes=carry.episodes.record(
                time_step.reward, time_step.done, jnp.broadcast_to(active, time_step.done.shape)
            ),
            key=key,
        )
        if freeze is not None:
            greedy = monitor_step(agent, side_envs, freeze, carry.greedy, carry.agent, monitor_key)
            carry = carry.replace(greedy=greedy)
        return carry, scalars(info)

    def update(carry: OffPolicyCarry) -> tuple[OffPolicyCarry, dict[str, jax.Array]]:
        episodes_before = carry.episodes.completed
        carry, act_info = jax.lax.scan(collect_step, carry, length=length)
        due = learning_due(experience, episodes_before, carry.episodes)
        extra = {}
        if freeze is not None:
            due = due & ~carry.greedy.frozen
            extra = {"frozen": carry.greedy.frozen.astype(jnp.float32)}
        carry, metrics = jax.lax.cond(
            any_seed(due),
            lambda c: learn_where(agent, replay, c, jnp.bool_(True) if alike else due),
            lambda c: no_learning(agent, replay, c),
            carry,
        )
        if agent.learning_steps is not None:
            extra["learning_steps"] = agent.learning_steps(carry.agent).astype(jnp.float32)
        last_act = jax.tree.map(lambda x: x[-1], act_info)
        return carry, {**metrics, **last_act, **extra}

    return agent_program(agent, init, update, envs.num_envs * length)
