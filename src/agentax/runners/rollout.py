"""Programs from the Agent: the compiled runner's iteration, built once for every algorithm.

:func:`program` takes any :class:`~agentax.agents.protocol.Agent` and a JAX env and returns a
:class:`Program`: ``init(key) -> carry`` and ``update(carry) -> (carry, metrics)``, pure and
jittable, which :mod:`agentax.runners.compiled` scans, vmaps over seeds and evaluates. What the
iteration does follows from ``agent.experience``:

=================  ==============================================================================
``OnPolicy``       a rollout of ``num_steps`` steps from ``num_envs`` envs with ``agent.act``, then
                   ``agent.learn`` on the trajectory ``[T, E]`` (PPO); :func:`on_policy_rollout`,
                   over any :class:`BatchedEnv`, is also the compiled Atari runner's rollout
``Episodes``       ``num_envs`` whole episodes from fresh resets, steps after an episode's end marked
                   in ``info["valid"]``, then ``agent.learn`` (REINFORCE)
``OffPolicy``      ``train_frequency`` env steps (one in the episode schedule) into the jittable
                   replay through an n-step accumulator, then, where the learning gates open, a
                   phase of ``gradient_steps`` learning steps on sampled batches, with priorities
                   written back for prioritized replay (DQN)
=================  ==============================================================================

The gates are the host runner's (:func:`agentax.runners.host.learning_started`), written with
``lax.cond``: learning starts after ``learning_starts`` env steps (or episodes), runs every
``train_frequency`` episodes in the episode schedule, and ends with ``max_episodes``. With
:class:`Freeze` a seed stops learning once its greedy policy, played on side envs, keeps reaching a
return (a compiled-runner option: the other runners refuse it).

What the runner reads of the agent's answers is written down in the protocol: ``act``'s scalar
``info`` entries (DQN's ``epsilon``) and every scalar metric of ``learn`` become columns, a
prioritized ``learn`` returns ``metrics["priority"]`` ``[batch]``, and ``importance_exponent`` is
a traced scalar. Each program splits its keys as the algorithm's own loop did before this module
(PPO ``(key, act, step)`` per step, DQN ``(key, act, step, monitor)``), so a seed's numbers are the
same as they were; the carries keep their field names, so older checkpoints load.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import jax
import jax.numpy as jnp
from flax import struct

from agentax.agents.protocol import PRIORITY, Agent, Episodes, OffPolicy, OnPolicy
from agentax.envs.core import Environment, EnvParams, Policy, TimeStep
from agentax.replay import Transition, example_transition, nstep, prioritized, uniform
from agentax.returns import EpisodeStats

SEED_AXIS = "seeds"  # the name of the compiled runner's vmap axis over seeds


def any_seed(flag: jax.Array) -> jax.Array:
    """Whether ``flag`` holds for any seed of the compiled runner's batch, as one unbatched bool.

    Under the runner's vmap a ``lax.cond`` on a per-seed flag becomes a select that runs both
    branches for every seed; on ``any_seed(flag)`` it stays a branch (the branch then keeps its
    result only where ``flag`` holds). Outside the runner (no seed axis) this is ``flag`` itself.
    """
    try:
        return jax.lax.psum(flag.astype(jnp.int32), SEED_AXIS) > 0
    except NameError:  # not traced under the runner's vmap
        return flag


@dataclass(frozen=True)
class Program:
    """One seed's training as the compiled runner runs it: ``num_updates`` calls of ``update``,
    each ``steps_per_update`` env steps; ``greedy_policy(carry)`` is the evaluation policy."""

    init: Callable[[jax.Array], Any]
    update: Callable[[Any], tuple[Any, dict[str, jax.Array]]]
    num_updates: int
    steps_per_update: int
    greedy_policy: Callable[[Any], Policy]


@dataclass(frozen=True)
class Freeze:
    """Per-seed early stopping: ``episodes`` side envs play the greedy policy during training; once
    each of their last ``episodes`` finished episodes returned at least ``at_return``, the seed
    keeps collecting (the schedule is unchanged) but learns no more."""

    at_return: float
    episodes: int = 8


class BatchedEnv(Protocol):
    """``num_envs`` envs stepped together inside ``jit``: a :class:`VectorEnv`, or the compiled Atari
    runner's EnvPool pool (:class:`agentax.runners.compiled_pool.PoolEnvs`).

    ``step(key, state, action [num_envs]) -> (time_step, state, info)``: the :class:`TimeStep`
    ``[num_envs]`` of the learning view, the envs' new state, and the envs' own entries for each
    transition's ``info`` (``{}`` for a JAX env; the Atari pool's ``"valid"`` and ``"games"``).
    """

    num_envs: int

    def step(self, key: jax.Array, state: Any, action: jax.Array) -> tuple[TimeStep, Any, dict[str, Any]]: ...


@dataclass(frozen=True)
class VectorEnv:
    """``num_envs`` copies of a JAX env with its params, batched by ``vmap`` (a :class:`BatchedEnv`)."""

    env: Environment
    params: EnvParams
    num_envs: int

    def reset(self, key: jax.Array) -> tuple[jax.Array, Any]:
        return jax.vmap(self.env.reset, in_axes=(0, None))(jax.random.split(key, self.num_envs), self.params)

    def step(self, key: jax.Array, state: Any, action: jax.Array) -> tuple[TimeStep, Any, dict[str, Any]]:
        keys = jax.random.split(key, self.num_envs)
        time_step, state = jax.vmap(self.env.step, in_axes=(0, 0, 0, None))(keys, state, action, self.params)
        return time_step, state, {}


def transition_of(obs: jax.Array, action: jax.Array, time_step: TimeStep, info: Any = None) -> Transition:
    """The transition ``[num_envs]`` of one env step: ``next_obs`` is the observation the step
    really reached (``final_obs``), ``terminated`` and ``truncated`` apart."""
    return Transition(
        obs=obs,
        action=action,
        reward=time_step.reward,
        next_obs=time_step.final_obs,
        terminated=time_step.terminated,
        truncated=time_step.truncated,
        num_steps=jnp.ones_like(time_step.terminated, jnp.int32),
        info=info,
    )


def scalars(metrics: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """The scalar entries of ``metrics`` (what a row can hold), as float32."""
    return {k: jnp.asarray(v, jnp.float32) for k, v in metrics.items() if jnp.ndim(v) == 0}


def _program(agent: Agent, init: Callable, update: Callable, steps_per_update: int) -> Program:
    """A :class:`Program` of ``agent`` whose ``update`` takes ``steps_per_update`` env steps."""
    num_updates = max(1, agent.total_steps // steps_per_update)
    return Program(
        init, update, num_updates, steps_per_update, lambda carry: agent.greedy_policy(carry.agent)
    )


def program(
    agent: Agent, env: Environment, env_params: EnvParams = None, *, freeze: Freeze | None = None
) -> Program:
    """The compiled runner's :class:`Program` for ``agent`` on the JAX env ``env``."""
    params = env.default_params() if env_params is None else env_params
    experience = agent.experience
    if isinstance(experience, OffPolicy):
        return off_policy_program(agent, VectorEnv(env, params, experience.num_envs), freeze)
    if freeze is not None:
        raise ValueError(f"freezing seeds needs an off-policy agent's learning gates, not {agent.name}'s")
    if isinstance(experience, Episodes):
        return episodes_program(agent, VectorEnv(env, params, experience.num_envs))
    return on_policy_program(agent, VectorEnv(env, params, experience.num_envs))


# ---------------------------------------------------------------- on-policy rollouts (PPO)


@struct.dataclass
class OnPolicyCarry:
    """What an on-policy rollout carries from one step (and one iteration) to the next."""

    agent: Any
    env_state: Any
    obs: jax.Array  # [num_envs, *obs_shape]
    key: jax.Array  # the actor's key chain (in the compiled runner's program also the learner's)
    episodes: EpisodeStats  # its env_steps (every env step) are the collect policy's progress


def on_policy_rollout(
    agent: Agent, envs: BatchedEnv, loop: Callable = jax.lax.scan
) -> Callable[[OnPolicyCarry], tuple[OnPolicyCarry, Transition]]:
    """``rollout(carry) -> (carry, trajectory)`` (jittable): ``num_steps`` steps of ``agent.act`` on
    ``envs``, the trajectory a :class:`Transition` ``[num_steps, num_envs]`` whose ``info`` holds
    ``act``'s entries and the envs' own. ``loop`` (``lax.scan``'s signature) runs the steps: the
    runner's :func:`agentax.kernels.learning_loop` where ``act`` runs a CNN on XLA's CPU backend.

    Per step ``key, act_key, step_key = split(carry.key, 3)``. Threefry splits are prefix-stable:
    ``key`` and ``act_key`` are those of a split in two, so on envs that ignore ``step_key`` (the
    Atari pool) the act keys are the host actor's (:func:`agentax.runners.host.act_and_split`).
    """

    def env_step(carry: OnPolicyCarry, _) -> tuple[OnPolicyCarry, Transition]:
        key, act_key, step_key = jax.random.split(carry.key, 3)
        action, info = agent.act(carry.agent, carry.obs, act_key, carry.episodes.env_steps)
        time_step, env_state, env_info = envs.step(step_key, carry.env_state, agent.env_action(action))
        transition = transition_of(carry.obs, action, time_step, {**info, **env_info})
        episodes = carry.episodes.record(time_step.reward, time_step.done)
        return carry.replace(env_state=env_state, obs=time_step.obs, key=key, episodes=episodes), transition

    def rollout(carry: OnPolicyCarry) -> tuple[OnPolicyCarry, Transition]:
        return loop(env_step, carry, None, agent.experience.num_steps)

    return rollout


def on_policy_program(agent: Agent, envs: VectorEnv) -> Program:
    experience: OnPolicy = agent.experience
    rollout = on_policy_rollout(agent, envs)

    def init(key: jax.Array) -> OnPolicyCarry:
        key, agent_key, reset_key = jax.random.split(key, 3)
        obs, env_state = envs.reset(reset_key)
        return OnPolicyCarry(agent.init(agent_key), env_state, obs, key, EpisodeStats.create(envs.num_envs))

    def update(carry: OnPolicyCarry) -> tuple[OnPolicyCarry, dict[str, jax.Array]]:
        carry, trajectory = rollout(carry)
        key, learn_key = jax.random.split(carry.key)
        agent_state, metrics = agent.learn(carry.agent, trajectory, learn_key)
        return carry.replace(agent=agent_state, key=key), scalars(metrics)

    return _program(agent, init, update, envs.num_envs * experience.num_steps)


# ---------------------------------------------------------------- whole episodes (REINFORCE)


@struct.dataclass
class EpisodesCarry:
    agent: Any
    key: jax.Array
    episodes: EpisodeStats


def episodes_program(agent: Agent, envs: VectorEnv) -> Program:
    experience: Episodes = agent.experience

    def init(key: jax.Array) -> EpisodesCarry:
        key, agent_key = jax.random.split(key)
        return EpisodesCarry(agent.init(agent_key), key, EpisodeStats.create(envs.num_envs))

    def update(carry: EpisodesCarry) -> tuple[EpisodesCarry, dict[str, jax.Array]]:
        learn_key, reset_key, play_key, key = jax.random.split(carry.key, 4)
        obs, env_state = envs.reset(reset_key)

        def env_step(step_carry, t):
            obs, env_state, alive, episodes, key = step_carry
            key, act_key, step_key = jax.random.split(key, 3)
            action, info = agent.act(carry.agent, obs, act_key, episodes.env_steps)
            time_step, env_state, _ = envs.step(step_key, env_state, agent.env_action(action))
            ended = time_step.done | (t == experience.max_steps - 1)
            episodes = episodes.record(time_step.reward, ended, alive)
            transition = transition_of(obs, action, time_step, {**info, "valid": alive})
            return (time_step.obs, env_state, alive & ~ended, episodes, key), transition

        alive = jnp.ones(envs.num_envs, bool)
        step_carry = (obs, env_state, alive, carry.episodes, play_key)
        (_, _, _, episodes, _), trajectory = jax.lax.scan(
            env_step, step_carry, jnp.arange(experience.max_steps)
        )
        agent_state, metrics = agent.learn(carry.agent, trajectory, learn_key)
        return EpisodesCarry(agent_state, key, episodes), scalars(metrics)

    return _program(agent, init, update, envs.num_envs * experience.max_steps)


# ---------------------------------------------------------------- replay and learning gates (DQN)
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
    """The jittable replay an ``OffPolicy`` experience asks for: uniform or prioritized, one call shape."""

    init: Callable  # (capacity, example) -> state
    add: Callable  # (state, batch, valid) -> state
    sample: Callable  # (state, key, batch_size, beta) -> ReplaySample
    update_priorities: Callable  # (state, indices, priority) -> state


def replay_for(experience: OffPolicy) -> Replay:
    if experience.prioritized:
        return Replay(
            init=functools.partial(prioritized.init, priority_exponent=experience.priority_exponent),
            add=prioritized.add,
            sample=prioritized.sample,
            update_priorities=prioritized.update_priorities,
        )
    return Replay(
        init=uniform.init,
        add=uniform.add,
        sample=lambda state, key, batch_size, beta: uniform.sample(state, key, batch_size),
        update_priorities=lambda state, indices, priority: state,
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


def off_policy_program(agent: Agent, envs: VectorEnv, freeze: Freeze | None = None) -> Program:
    experience: OffPolicy = agent.experience
    replay = replay_for(experience)
    by_episode = experience.by_episode
    side_envs = None if freeze is None else VectorEnv(envs.env, envs.params, freeze.episodes)

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
        time_step, env_state, _ = envs.step(step_key, carry.env_state, agent.env_action(action))
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
            replay=replay.add(carry.replay, emitted, full & active),
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

    def learn_phase(carry: OffPolicyCarry) -> tuple[OffPolicyCarry, dict[str, jax.Array]]:
        beta = experience.importance_exponent(carry.episodes.env_steps)

        def one(inner, _):
            agent_state, replay_state, key = inner
            # (threefry splits are prefix-stable: key and sample_key are those of a split in two)
            key, sample_key, learn_key = jax.random.split(key, 3)
            sample = replay.sample(replay_state, sample_key, experience.batch_size, beta)
            agent_state, metrics = agent.learn(agent_state, sample, learn_key)
            if experience.prioritized:
                replay_state = replay.update_priorities(replay_state, sample.indices, metrics[PRIORITY])
            return (agent_state, replay_state, key), scalars(metrics)

        key, learn_key = jax.random.split(carry.key)
        inner, steps = (carry.agent, carry.replay, learn_key), experience.gradient_steps
        if isinstance(steps, int):
            (agent_state, replay_state, _), metrics = jax.lax.scan(one, inner, length=steps)
            metrics = jax.tree.map(jnp.mean, metrics)
        else:  # a traced count (a sweep over SAC's utd): a loop as long, its metrics averaged
            (agent_state, replay_state, _), metrics = traced_count_loop(one, inner, steps)
        return carry.replace(agent=agent_state, replay=replay_state, key=key), metrics

    def learn_where(carry: OffPolicyCarry, due: jax.Array) -> tuple[OffPolicyCarry, dict[str, jax.Array]]:
        """Learn, keeping the result only where ``due`` (a branch taken when any seed is due). Only
        what learning changes is selected (the agent, the key, prioritized replay's priorities): a
        uniform replay buffer (millions of transitions) passes through uncopied."""
        learned, metrics = learn_phase(carry)
        no_metrics = skip_learning(carry)[1]
        keep = functools.partial(jax.tree.map, lambda new, old: jnp.where(due, new, old))
        replay = keep(learned.replay, carry.replay) if experience.prioritized else carry.replay
        learned = carry.replace(
            agent=keep(learned.agent, carry.agent), replay=replay, key=keep(learned.key, carry.key)
        )
        return learned, keep(metrics, no_metrics)

    def skip_learning(carry: OffPolicyCarry) -> tuple[OffPolicyCarry, dict[str, jax.Array]]:
        shapes = jax.eval_shape(learn_phase, carry)[1]
        return carry, jax.tree.map(lambda m: jnp.zeros(m.shape, m.dtype), shapes)

    def update(carry: OffPolicyCarry) -> tuple[OffPolicyCarry, dict[str, jax.Array]]:
        episodes_before = carry.episodes.completed
        length = 1 if by_episode else experience.train_frequency
        carry, act_info = jax.lax.scan(collect_step, carry, length=length)
        due = learning_due(experience, episodes_before, carry.episodes)
        extra = {}
        if freeze is not None:
            due = due & ~carry.greedy.frozen
            extra = {"frozen": carry.greedy.frozen.astype(jnp.float32)}
        carry, metrics = jax.lax.cond(any_seed(due), lambda c: learn_where(c, due), skip_learning, carry)
        if agent.learning_steps is not None:
            extra["learning_steps"] = agent.learning_steps(carry.agent).astype(jnp.float32)
        last_act = jax.tree.map(lambda x: x[-1], act_info)
        return carry, {**metrics, **last_act, **extra}

    return _program(agent, init, update, envs.num_envs * (1 if by_episode else experience.train_frequency))
