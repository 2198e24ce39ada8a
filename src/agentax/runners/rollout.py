"""Programs from the Agent: the compiled runner's iteration, written once for every algorithm.

A :class:`Program` is ``init(key) -> carry`` and ``update(carry) -> (carry, metrics)``, pure and
jittable, its update chosen by ``agent.experience`` (:func:`agentax.runners.compiled.program_of`):
:func:`on_policy_program` (PPO), :func:`episodes_program` (REINFORCE) or
:func:`agentax.runners.replay_program.off_policy_program` (DQN, SAC, TD3). ``act``'s scalar
``info`` entries and ``learn``'s scalar metrics become columns.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import jax
import jax.numpy as jnp
from flax import struct

from agentax.agents.protocol import Agent, Episodes, OnPolicy
from agentax.envs.core import Environment, EnvParams, Policy, TimeStep
from agentax.replay import Transition
from agentax.returns import EpisodeStats

SEED_AXIS = "seeds"  # the name of the compiled runner's vmap axis over seeds


def any_seed(flag: jax.Array) -> jax.Array:
    """Whether ``flag`` holds for any seed of the compiled runner's batch, one unbatched bool that a
    ``lax.cond`` branches on under the seeds' vmap (``flag`` itself outside it)."""
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


class BatchedEnv(Protocol):
    """``num_envs`` envs stepped together inside ``jit``: a :class:`VectorEnv`, or the compiled EnvPool
    runner's pool (:class:`agentax.runners.compiled_pool.PoolEnvs`). ``step`` gives the learning
    view's :class:`TimeStep` ``[num_envs]``, the new state and the envs' own ``info`` entries."""

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


def agent_program(agent: Agent, init: Callable, update: Callable, steps_per_update: int) -> Program:
    """A :class:`Program` of ``agent`` whose ``update`` takes ``steps_per_update`` env steps."""
    num_updates = max(1, agent.total_steps // steps_per_update)
    return Program(
        init, update, num_updates, steps_per_update, lambda carry: agent.greedy_policy(carry.agent)
    )


@struct.dataclass
class OnPolicyCarry:
    """What an on-policy rollout carries from one step (and one iteration) to the next."""

    agent: Any
    env_state: Any
    obs: jax.Array  # [num_envs, *obs_shape]
    key: jax.Array  # the actor's key chain (in the compiled runner's program also the learner's)
    episodes: EpisodeStats  # its env_steps (every env step) are the collect policy's progress


@struct.dataclass
class RecurrentCarry(OnPolicyCarry):
    """An on-policy carry of an agent with memory (``agent.recurrent``): also each env's memory and
    whether its observation starts an episode."""

    memory: Any  # leaves [num_envs, ...]
    first: jax.Array  # bool [num_envs]


def fresh_memory(agent: Agent, num_envs: int) -> tuple[Any, jax.Array]:
    """``(memory, first)`` of ``num_envs`` envs whose observations start episodes: the recurrent
    agent's initial memory and ``first`` all true (every runner that carries memory starts so)."""
    return agent.recurrent.initial(num_envs), jnp.ones(num_envs, bool)


def on_policy_carry(agent: Agent | None, num_envs: int, *fields: Any) -> OnPolicyCarry:
    """``OnPolicyCarry(*fields)``, a :class:`RecurrentCarry` (fresh memory) for an agent with memory."""
    if agent is None or agent.recurrent is None:
        return OnPolicyCarry(*fields)
    return RecurrentCarry(*fields, *fresh_memory(agent, num_envs))


def on_policy_rollout(
    agent: Agent, envs: BatchedEnv, loop: Callable = jax.lax.scan
) -> Callable[[OnPolicyCarry], tuple[OnPolicyCarry, Transition]]:
    """``rollout(carry) -> (carry, trajectory)`` (jittable): ``num_steps`` steps of the collect policy
    on ``envs``, the trajectory a :class:`Transition` ``[num_steps, num_envs]`` whose ``info`` holds
    ``act``'s entries and the envs' own; ``loop`` (``lax.scan``'s signature) runs the steps."""

    def env_step(carry: OnPolicyCarry, _) -> tuple[OnPolicyCarry, Transition]:
        key, act_key, step_key = jax.random.split(carry.key, 3)
        progress = carry.episodes.env_steps
        if agent.recurrent is None:
            action, info = agent.act(carry.agent, carry.obs, act_key, progress)
        else:
            memory, action, info = agent.recurrent.act(
                carry.agent, carry.memory, carry.obs, carry.first, act_key, progress
            )
        time_step, env_state, env_info = envs.step(step_key, carry.env_state, agent.env_action(action))
        transition = transition_of(carry.obs, action, time_step, {**info, **env_info})
        episodes = carry.episodes.record(time_step.reward, time_step.done)
        carry = carry.replace(env_state=env_state, obs=time_step.obs, key=key, episodes=episodes)
        if agent.recurrent is not None:
            # an episode starts where the step ended one (the env auto-reset), or on envs with reset
            # steps (EnvPool's pool: info["valid"] False) where the step was a reset step
            first = ~env_info["valid"] if "valid" in env_info else time_step.done
            carry = carry.replace(memory=memory, first=first)
        return carry, transition

    def rollout(carry: OnPolicyCarry) -> tuple[OnPolicyCarry, Transition]:
        return loop(env_step, carry, None, agent.experience.num_steps)

    return rollout


def on_policy_program(agent: Agent, envs: VectorEnv) -> Program:
    experience: OnPolicy = agent.experience
    rollout = on_policy_rollout(agent, envs)

    def init(key: jax.Array) -> OnPolicyCarry:
        key, agent_key, reset_key = jax.random.split(key, 3)
        obs, env_state = envs.reset(reset_key)
        episodes = EpisodeStats.create(envs.num_envs)
        return on_policy_carry(agent, envs.num_envs, agent.init(agent_key), env_state, obs, key, episodes)

    def update(carry: OnPolicyCarry) -> tuple[OnPolicyCarry, dict[str, jax.Array]]:
        carry, trajectory = rollout(carry)
        key, learn_key = jax.random.split(carry.key)
        agent_state, metrics = agent.learn(carry.agent, trajectory, learn_key)
        return carry.replace(agent=agent_state, key=key), scalars(metrics)

    return agent_program(agent, init, update, envs.num_envs * experience.num_steps)


@struct.dataclass
class EpisodesCarry:
    """What the whole-episodes program (REINFORCE) carries from one update to the next."""

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
            obs, env_state, alive, episodes, key, memory = step_carry
            key, act_key, step_key = jax.random.split(key, 3)
            if agent.recurrent is None:
                action, info = agent.act(carry.agent, obs, act_key, episodes.env_steps)
            else:  # memory: zeros at the episodes' start (t = 0), nothing later starts one that counts
                memory, action, info = agent.recurrent.act(
                    carry.agent, memory, obs, jnp.full(envs.num_envs, t == 0), act_key, episodes.env_steps
                )
            time_step, env_state, _ = envs.step(step_key, env_state, agent.env_action(action))
            ended = time_step.done | (t == experience.max_steps - 1)
            episodes = episodes.record(time_step.reward, ended, alive)
            transition = transition_of(obs, action, time_step, {**info, "valid": alive})
            return (time_step.obs, env_state, alive & ~ended, episodes, key, memory), transition

        alive = jnp.ones(envs.num_envs, bool)
        memory = None if agent.recurrent is None else agent.recurrent.initial(envs.num_envs)
        step_carry = (obs, env_state, alive, carry.episodes, play_key, memory)
        (_, _, _, episodes, _, _), trajectory = jax.lax.scan(
            env_step, step_carry, jnp.arange(experience.max_steps)
        )
        agent_state, metrics = agent.learn(carry.agent, trajectory, learn_key)
        return EpisodesCarry(agent_state, key, episodes), scalars(metrics)

    return agent_program(agent, init, update, envs.num_envs * experience.max_steps)
