"""The compiled EnvPool runner (kinds ``compiled-atari`` and ``compiled-mujoco``): EnvPool's step
inside the program, one seed per process (a pool handle cannot be vmapped).

PPO runs an iteration as one jitted call (:func:`make_update`): the rollout on :class:`PoolEnvs`,
then ``agent.learn``; SAC and TD3 (MuJoCo) run acting, replay and learning in one program
(:func:`train_off_policy`). EnvPool's reset steps stay in the rollout, ``info["valid"]`` False,
counted as env steps (``masked_fraction``). The rest is the host runner's, so the two compare
number for number.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax import kernel_choice
from agentax.agents.protocol import Agent, OffPolicy, OnPolicy
from agentax.envs.atari import FRAME_SKIP, is_atari_id
from agentax.envs.core import TimeStep
from agentax.envs.envpool_xla import (
    ENVPOOL_MUJOCO,
    EpisodeTracker,
    XlaAtari,
    XlaMujoco,
    is_envpool_mujoco_id,
    track,
)
from agentax.errors import UsageError
from agentax.returns import EpisodeStats
from agentax.runners import host, kind_for
from agentax.runners.replay_program import off_policy_program
from agentax.runners.rollout import OnPolicyCarry, Program, on_policy_carry, on_policy_rollout
from agentax.runners.session import TrainResult, split_key
from agentax.runs import Run

XlaPool = XlaAtari | XlaMujoco


@dataclass(frozen=True)
class Config:
    """The compiled EnvPool runner's settings, saved in config.json under "runner" (a run written
    before ``policy_lag`` existed resumes with 0, as it ran). The fields the host runner's config
    also has mean the same, so the two compare number for number; neither is the other's."""

    seed: int = 0
    """seed of the agent and of the pool"""
    log_every_steps: int = 2_048
    """write a metrics row every this many env steps (the pool's, reset steps included)"""
    eval_episodes: int = 10
    """games of the final evaluation (and of the stop-at-return checks), on the host adapter"""
    stop_at_return: float | None = None
    """stop once an evaluation (run at each row) reaches this mean return (None: train to the end)"""
    checkpoint_every_seconds: float = 30.0
    """write a checkpoint at most this often (and at the end)"""
    env_backend: str = "auto"
    """envpool (auto); the evaluation's host adapter follows it"""
    sticky_actions: float = 0.25
    """Atari: the probability that the emulator repeats the last action (Gymnasium's v5: 0.25)"""
    checkpoint_replay: bool = True
    """SAC and TD3: save the program's replay beside the checkpoints (PPO keeps none)"""
    replay_checkpoint_every_seconds: float = 600.0
    """SAC and TD3: save the replay at most this often (and with the first and last checkpoints)"""
    policy_lag: int = 0
    """parameter versions between collecting a rollout and learning from it: 0 runs rollout and
    learning one after the other in one program; 1 collects rollout k+1 in a thread beside the
    learning on rollout k, with the parameters that learning starts from"""


def configure(run_args: Any, agent: Agent, preset: Any) -> tuple[Config, str]:
    """The runner's settings for a run (:mod:`agentax.runners.launch`), refused where the program
    cannot step the env or train the agent."""
    common = host.one_seed_settings(run_args, preset, kind_for("compiled", run_args.env))
    on_policy = isinstance(agent.experience, OnPolicy)  # an off-policy agent acts on its newest parameters
    runner = Config(**common, policy_lag=run_args.policy_lag if on_policy else 0)
    check(agent, run_args.env, runner, run_args.seeds)
    if not on_policy:
        return runner, "compiled, EnvPool and the replay inside the program"
    return runner, f"compiled, EnvPool inside the program, policy lag {runner.policy_lag}"


restore = host.restore
"""its checkpoints are the host runner's ``(agent state, learner key)``"""


@struct.dataclass
class Games:
    """The whole games a rollout finished, ``[T, num_envs]`` each (read where ``finished``)."""

    finished: jax.Array  # bool
    score: jax.Array  # float32: true score
    length: jax.Array  # int32: valid agent steps


@struct.dataclass
class Pool:
    """The pool's state in the program (the rollout's ``env_state``)."""

    handle: jax.Array  # EnvPool's pool handle (uint8 bytes), threaded through the program
    tracker: EpisodeTracker  # the pending reset steps, the running games' scores


class PoolEnvs:
    """``env``'s pool (Atari or MuJoCo) as a :class:`~agentax.runners.rollout.BatchedEnv`; ``first``:
    the pool's ``(handle, obs)`` after its reset on the host, what :meth:`reset` gives a program."""

    def __init__(self, env: XlaPool, first: tuple[jax.Array, jax.Array] | None = None):
        self.env, self.num_envs, self.first = env, env.num_envs, first

    def reset(self, key: jax.Array) -> tuple[jax.Array, Pool]:
        """The pool's first observations and state (``key`` unused: EnvPool reset it on the host)."""
        handle, obs = self.first
        return obs, Pool(handle, EpisodeTracker.create(self.num_envs))

    def step(self, key: jax.Array, pool: Pool, action: jax.Array) -> tuple[TimeStep, Pool, dict[str, Any]]:
        """EnvPool's step (``key`` unused): the learning view ``[num_envs]`` (Atari's rewards clipped;
        ``final_obs`` is ``obs``, EnvPool's last observation on an ending step), ``info["valid"]``
        (False on reset steps) and ``info["games"]``, the :class:`Games` (MuJoCo: episodes) it finished."""
        handle, step = self.env.step(pool.handle, action)
        tracker, tracked = track(pool.tracker, step)
        reward = jnp.sign(step.reward) if self.env.clip_rewards else step.reward
        time_step = TimeStep(step.obs, reward, step.terminated, step.truncated, step.obs)
        games = Games(tracked.game_finished, tracked.game_score, tracked.game_length)
        return time_step, Pool(handle, tracker), {"valid": tracked.valid, "games": games}


def check(agent: Agent, env_id: str, runner: Config, num_seeds: int = 1) -> None:
    """A ``UsageError`` for what this runner cannot train, before anything is made or written."""
    if runner.policy_lag not in (0, 1):
        raise UsageError(
            "the compiled EnvPool runner collects with policy lag 0 or 1, "
            f"not --policy-lag {runner.policy_lag}"
        )
    if num_seeds != 1:
        raise UsageError(
            "the compiled EnvPool runner trains one seed per process (--seeds 1): EnvPool's pool, stepped "
            "inside the program, cannot be vmapped over seeds; start one run per seed"
        )
    if not (is_atari_id(env_id) or is_envpool_mujoco_id(env_id)):
        raise UsageError(
            "the compiled EnvPool runner trains Atari games (ALE/<Game>-v5) and EnvPool's MuJoCo tasks "
            f"({', '.join(ENVPOOL_MUJOCO)}), not {env_id!r}"
        )
    if runner.env_backend not in ("auto", "envpool"):
        raise UsageError(
            f"the compiled EnvPool runner steps EnvPool inside the program; --env-backend "
            f"{runner.env_backend} cannot run there (use envpool, or --runner host)"
        )
    experience = agent.experience
    if isinstance(experience, OffPolicy):
        if not is_envpool_mujoco_id(env_id):
            raise UsageError(
                "the compiled EnvPool runner trains off-policy agents (sac, td3) on EnvPool's MuJoCo tasks "
                f"only; {agent.name} on {env_id} needs --runner host"
            )
        if experience.num_envs != 1 or experience.n_step != 1:
            raise UsageError(
                f"the compiled EnvPool runner trains {agent.name} with one env and one-step targets (the "
                "mujoco preset's); other settings need --runner host"
            )
    elif not isinstance(experience, OnPolicy):
        raise UsageError(
            f"the compiled EnvPool runner trains on-policy agents (ppo) and, on MuJoCo tasks, sac and "
            f"td3; {agent.name} needs --runner host"
        )


def make_pool(env_id: str, num_envs: int, seed: int, runner: Config) -> XlaPool:
    """The pool of ``env_id``: Atari with the runner's sticky actions, or a MuJoCo task's v5 settings."""
    if is_atari_id(env_id):
        return XlaAtari(env_id, num_envs, seed=seed, sticky_actions=runner.sticky_actions)
    return XlaMujoco(env_id, num_envs, seed=seed)


def start(
    agent_state: Any, env: XlaPool, key: jax.Array, env_steps: int, agent: Agent | None = None
) -> OnPolicyCarry:
    """The rollout's carry on new games in ``env``'s pool (a host call): the actor's key chain from
    ``key``, ``env_steps`` the pool's steps so far; for an ``agent`` with memory a ``RecurrentCarry``."""
    obs, pool = PoolEnvs(env, env.reset()).reset(key)
    episodes = EpisodeStats.create(env.num_envs).replace(env_steps=jnp.int32(env_steps))
    return on_policy_carry(agent, env.num_envs, agent_state, pool, obs, key, episodes)


def make_collect(agent: Agent, env: XlaPool) -> Callable:
    """``collect(carry) -> (carry, trajectory, games [T, E])`` (jittable): the on-policy rollout on
    ``env`` with ``carry.agent``'s parameters, the games it finished taken out of the trajectory."""
    rollout = on_policy_rollout(
        agent, PoolEnvs(env), kernel_choice.learning_loop_for(env.observation_space().shape)
    )

    def collect(carry: OnPolicyCarry):
        carry, trajectory = rollout(carry)
        info = dict(trajectory.info)
        games = info.pop("games")
        return carry, trajectory.replace(info=info), games

    return collect


def make_learn(agent: Agent) -> Callable:
    """``learn(state, trajectory, learner_key) -> (state, learner_key, metrics)`` (jittable):
    ``agent.learn`` on one rollout, its key split from the learner's chain (the host runner's)."""

    def learn(state: Any, trajectory: Any, learner_key: jax.Array):
        learner_key, learn_key = split_key(learner_key)
        state, metrics = agent.learn(state, trajectory, learn_key)
        metrics = {**metrics, "masked_fraction": 1.0 - trajectory.info["valid"].mean()}
        return state, learner_key, metrics

    return learn


def make_update(agent: Agent, env: XlaPool):
    """``update(carry, learner_key) -> (carry, learner_key, metrics, games [T, E])`` (jittable): one
    iteration, the rollout on ``env`` then ``agent.learn`` on it (policy lag 0, one program)."""
    collect, learn = make_collect(agent, env), make_learn(agent)

    def update(carry: OnPolicyCarry, learner_key: jax.Array):
        carry, trajectory, games = collect(carry)
        state, learner_key, metrics = learn(carry.agent, trajectory, learner_key)
        return carry.replace(agent=state), learner_key, metrics, games

    return update


Iteration = tuple[Any, jax.Array, dict[str, jax.Array], Games]
"""``(agent state, learner key, metrics, games)`` after one learning iteration."""


def in_one_program(update: Callable, carry: OnPolicyCarry, learner_key: jax.Array) -> Iterator[Iteration]:
    """Policy lag 0: each iteration ``update`` (rollout, then learning on it) in one call."""
    while True:
        carry, learner_key, metrics, games = update(carry, learner_key)
        yield carry.agent, learner_key, metrics, games


def side_by_side(
    collect: Callable, learn: Callable, carry: OnPolicyCarry, learner_key: jax.Array, count: int
) -> Iterator[Iteration]:
    """Policy lag 1, ``count`` iterations: while ``learn`` runs on rollout k here, a thread runs
    ``collect`` for rollout k+1 with the parameters learning on rollout k starts from (the first two
    rollouts both use the starting ones). Closed early, it waits for the thread's rollout to end."""

    def collected(carry: OnPolicyCarry):
        return jax.block_until_ready(collect(carry))

    state = carry.agent
    with ThreadPoolExecutor(1, thread_name_prefix="agentax-collect") as thread:
        pending = thread.submit(collected, carry)
        for k in range(count):
            carry, trajectory, games = pending.result()
            if k + 1 < count:
                pending = thread.submit(collected, carry.replace(agent=state))
            state, learner_key, metrics = learn(state, trajectory, learner_key)
            yield state, learner_key, metrics, games


def train(
    agent: Agent,
    env_id: str,
    runner: Config,
    run: Run | None = None,
    *,
    resume: bool = False,
    progress: bool = False,
) -> TrainResult:
    """Train ``agent`` on an Atari game or EnvPool's MuJoCo task into ``run`` as
    :func:`agentax.runners.host.train` does (the evaluation on the host adapter)."""
    check(agent, env_id, runner)
    if isinstance(agent.experience, OffPolicy):
        return train_off_policy(agent, env_id, runner, run, resume=resume, progress=progress)
    session = host.host_session(agent, env_id, runner, run, resume)  # (on-policy: no replay)
    learner_key, updates, env_steps = session.learner_key, session.updates, session.env_steps
    games_done = int(session.meta.get("games", 0))
    experience: OnPolicy = agent.experience
    env = make_pool(env_id, experience.num_envs, host.actor_seed(runner.seed, 0, updates), runner)
    carry = start(session.state, env, host.fold_actor_key(session.actors_key, 0, updates), env_steps, agent)
    total_updates, lag = host.num_updates(agent), runner.policy_lag
    if lag == 0:
        steps = in_one_program(jax.jit(make_update(agent, env), donate_argnums=0), carry, learner_key)
    else:  # the collector's carry shares the parameters the learner reads: nothing donated
        collect, learn = jax.jit(make_collect(agent, env)), jax.jit(make_learn(agent))
        steps = side_by_side(collect, learn, carry, learner_key, total_updates - updates)
    state, scores = carry.agent, []
    with session.begin(f"{agent.name} {env_id} (compiled{', policy lag 1' if lag else ''})", progress):
        try:
            while updates < total_updates:
                state, learner_key, metrics, games = next(steps)
                updates += 1
                env_steps += experience.num_envs * experience.num_steps
                done, score = jax.device_get((games.finished, games.score))  # waits: speeds count all of it
                finished = score[done].tolist()  # the finished games' true scores, in time order
                games_done += len(finished)
                scores += finished
                last = updates >= total_updates
                if not session.row_due(env_steps, last):
                    continue
                args = (state, learner_key, env_steps, updates, scores, metrics)
                extra = {"frames": FRAME_SKIP * env_steps} if isinstance(env, XlaAtari) else {}
                scores = []
                if session.log_row(*args, final=last, extra=extra, counts={"games": games_done}):
                    break
        finally:
            steps.close()  # the collector's rollout ends before its pool does
            env.close()
    return session.finish(state, env_steps, updates)


# ---------------------------------------------------------------- off-policy agents (SAC, TD3)


class ProgramReplay:
    """The replay inside the program's carry as the session saves and restores a replay buffer
    (``state_dict``, ``load_state_dict``, ``lock``): ``carry`` is set to the newest carry."""

    def __init__(self, carry: Any):
        self.carry, self.lock = carry, contextlib.nullcontext()

    def state_dict(self) -> dict[str, np.ndarray]:
        leaves = jax.tree_util.tree_flatten_with_path(jax.device_get(self.carry.replay))[0]
        return {jax.tree_util.keystr(path): np.asarray(leaf) for path, leaf in leaves}

    def load_state_dict(self, arrays: dict[str, np.ndarray]) -> None:
        paths, tree = jax.tree_util.tree_flatten_with_path(self.carry.replay)
        leaves = [jnp.asarray(arrays[jax.tree_util.keystr(path)]) for path, _ in paths]
        self.carry = self.carry.replace(replay=jax.tree.unflatten(tree, leaves))


def make_chunk(program: Program, length: int) -> Callable:
    """``chunk(carry, num_active) -> (carry, metrics)`` (jittable): the first ``num_active`` of
    ``length`` updates, the rest skipped by a branch (the replay is never copied); their mean metrics."""

    def chunk(carry: Any, num_active: jax.Array):
        zeros = jax.tree.map(lambda m: jnp.zeros(m.shape, m.dtype), jax.eval_shape(program.update, carry)[1])

        def body(carry, i):
            return jax.lax.cond(i < num_active, program.update, lambda c: (c, zeros), carry)

        carry, metrics = jax.lax.scan(body, carry, jnp.arange(length))
        return carry, jax.tree.map(lambda m: m.sum(0) / jnp.maximum(num_active, 1), metrics)

    return chunk


def episode_means(before: EpisodeStats, after: EpisodeStats) -> list[float]:
    """The mean return of the episodes finished between two EpisodeStats (none: ``[]``)."""
    completed = int(after.completed - before.completed)
    return [float(after.return_sum - before.return_sum) / completed] if completed else []


def train_off_policy(
    agent: Agent, env_id: str, runner: Config, run: Run | None, *, resume: bool, progress: bool
) -> TrainResult:
    """Train SAC or TD3 on an EnvPool MuJoCo task, acting, replay and learning in one program called
    once per row (``log_every_steps`` env steps); the replay is saved beside the checkpoints."""
    session = host.host_session(agent, env_id, runner, run, resume)
    updates, env_steps, experience = session.updates, session.env_steps, agent.experience
    env = make_pool(env_id, experience.num_envs, host.actor_seed(runner.seed, 0, updates), runner)
    program = off_policy_program(agent, PoolEnvs(env, env.reset()))
    carry = jax.jit(program.init)(host.fold_actor_key(session.actors_key, 0, updates))
    episodes = carry.episodes.replace(env_steps=jnp.int32(env_steps))
    replay = ProgramReplay(carry.replace(agent=session.state, episodes=episodes))
    session.keep_replay(replay)  # a resumed run's replay restored into the carry
    # its own buffer for each leaf (an agent's target network starts as its network's arrays): donated
    carry = jax.tree.map(jnp.copy, replay.carry)
    length = max(1, runner.log_every_steps // program.steps_per_update)
    chunk = jax.jit(make_chunk(program, length), donate_argnums=0)
    with session.begin(f"{agent.name} {env_id} (compiled)", progress):
        try:
            while updates < program.num_updates:
                before, active = jax.device_get(carry.episodes), min(length, program.num_updates - updates)
                carry, metrics = chunk(carry, active)
                updates, replay.carry, stats = updates + active, carry, jax.device_get(carry.episodes)
                env_steps, last = int(stats.env_steps), updates >= program.num_updates
                session.row_due(env_steps, True)
                extra, counts = {"replay_size": int(carry.replay.size)}, {"episodes": int(stats.completed)}
                args = (carry.agent, session.learner_key, env_steps, updates, episode_means(before, stats))
                if session.log_row(*args, metrics, final=last, extra=extra, counts=counts):
                    break
        finally:
            env.close()
    return session.finish(carry.agent, env_steps, updates)
