"""The compiled Atari runner: an on-policy agent's rollout *and* EnvPool's Atari step in one program.

For ``agentax train ppo --env ALE/Breakout-v5 --runner compiled``. Each iteration is one jitted call,
:func:`make_update`: a ``lax.scan`` of ``num_steps`` steps, each the agent's collect policy on the
``num_envs`` observations and EnvPool's step of the pool (:mod:`agentax.envs.envpool_xla`, the
host adapter's preprocessing and settings), then ``agent.learn`` on the rollout — no Python between
the env and the network (CleanRL's ``ppo_atari_envpool_xla_jax.py`` does the same). One seed per
process: EnvPool's pool handle cannot be vmapped.

**EnvPool's reset step.** The step after an episode's end (a lost life, a game over, the frame
limit) is EnvPool's reset: it ignores its action and returns the next episode's first observation.
The rollout keeps it (fixed shapes), marks it ``info["valid"] = False`` and learns nothing from it
(PPO leaves such steps out of every loss term and of the advantages' normalisation); the step before
it carries the episode's end (``terminated``, or ``truncated`` at the frame limit), so GAE neither
bootstraps through it nor carries its λ-trace across. The env steps counted (``env_steps``, the
progress bar, ``total_steps``) are the pool's steps, reset steps included; ``masked_fraction``
in metrics.csv is their share.

**The rest is the host runner's** (:mod:`agentax.runners.host`), so the two compare number for
number where they can: the same :class:`~agentax.runners.host.HostRunnerConfig`, the same keys (the
agent from ``agent_keys(seed)``'s first key, the learner's chain from the second, the actor's from
the third, its envs seeded ``actor_seed(seed, 0, updates)``), the same rows
(:func:`~agentax.runners.host.row_of`: ``mean_return`` is the mean true score of the whole games
finished since the last row — every life, raw rewards), the same checkpoints (``(agent state,
learner key)``, so :func:`agentax.runners.host.restore_policy` loads them and a resumed run restarts
its pool from a new seed), the same final evaluation (:class:`~agentax.runners.host.Evaluator`:
whole games on the host adapter, greedy with 1 % random actions).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from agentax import _xla
from agentax.agents.protocol import Agent, OnPolicy
from agentax.envs.atari import FRAME_SKIP, is_atari_id
from agentax.envs.envpool_xla import EpisodeTracker, XlaAtari, track
from agentax.errors import UsageError
from agentax.replay import Transition
from agentax.runners import host
from agentax.runners.session import Session, TrainResult
from agentax.runs import Run

RUNNER_KIND = "compiled-atari"
"""config.json's ``runner_kind`` of these runs; their ``runner`` is a ``HostRunnerConfig``."""


@struct.dataclass
class Collector:
    """What the rollout carries from one iteration to the next."""

    handle: jax.Array  # EnvPool's pool handle (uint8 bytes), threaded through the program
    obs: jax.Array  # uint8 [num_envs, 4, 84, 84]
    tracker: EpisodeTracker  # the pending reset steps, the running games' scores
    key: jax.Array  # the actor's key chain
    env_steps: jax.Array  # int32 []: the pool's steps so far (the collect policy's progress)


@struct.dataclass
class Games:
    """The whole games a rollout finished, ``[T, num_envs]`` each (read where ``finished``)."""

    finished: jax.Array  # bool
    score: jax.Array  # float32: true score
    length: jax.Array  # int32: valid agent steps


def check(agent: Agent, env_id: str, runner: host.HostRunnerConfig, num_seeds: int = 1) -> None:
    """A ``UsageError`` for what this runner cannot train, before anything is made or written."""
    if num_seeds != 1:
        raise UsageError(
            "the compiled Atari runner trains one seed per process (--seeds 1): EnvPool's pool, stepped "
            "inside the program, cannot be vmapped over seeds; start one run per seed"
        )
    if not is_atari_id(env_id):
        raise UsageError(f"the compiled Atari runner trains Atari games (ALE/<Game>-v5), not {env_id!r}")
    if runner.env_backend not in ("auto", "envpool"):
        raise UsageError(
            f"the compiled Atari runner steps EnvPool inside the program; --env-backend "
            f"{runner.env_backend} cannot run there (use envpool, or --runner host)"
        )
    if not isinstance(agent.experience, OnPolicy):
        raise UsageError(
            f"the compiled Atari runner trains on-policy agents (ppo); {agent.name} needs --runner host"
        )


def start_collector(env: XlaAtari, key: jax.Array, env_steps: int) -> Collector:
    """New games in ``env``'s pool (a host call); the actor's key chain starts at ``key``."""
    handle, obs = env.reset()
    return Collector(handle, obs, EpisodeTracker.create(env.num_envs), key, jnp.int32(env_steps))


def make_rollout(agent: Agent, env: XlaAtari):
    """``rollout(agent_state, collector) -> (collector, trajectory [T, E], games [T, E])`` (jittable).

    ``trajectory`` is a :class:`~agentax.replay.Transition` with clipped rewards (the sign), the
    learning view's ends, and ``info`` from ``agent.act`` plus ``"valid"`` (False on reset steps).
    """
    act = host.act_and_split(agent.act)
    num_steps = agent.experience.num_steps

    def env_step(carry: tuple[Any, Collector], _):
        state, collector = carry
        action, info, key = act(state, collector.obs, collector.key, collector.env_steps)
        handle, step = env.step(collector.handle, agent.env_action(action))
        tracker, tracked = track(collector.tracker, step)
        transition = Transition(
            obs=collector.obs,
            action=action,
            reward=jnp.sign(step.reward),
            next_obs=step.obs,  # on an ending step EnvPool returns the last observation itself
            terminated=step.terminated,
            truncated=step.truncated,
            num_steps=jnp.ones(env.num_envs, jnp.int32),
            info={**info, "valid": tracked.valid},
        )
        games = Games(tracked.game_finished, tracked.game_score, tracked.game_length)
        collector = Collector(handle, step.obs, tracker, key, collector.env_steps + env.num_envs)
        return (state, collector), (transition, games)

    def rollout(state: Any, collector: Collector) -> tuple[Collector, Transition, Games]:
        (_, collector), (trajectory, games) = jax.lax.scan(env_step, (state, collector), None, num_steps)
        return collector, trajectory, games

    return rollout


def make_update(agent: Agent, env: XlaAtari):
    """``update(agent_state, collector, learner_key) -> (agent_state, collector, learner_key,
    metrics, games)``: one iteration, rollout then ``agent.learn`` (jittable; keys as the host runner's)."""
    rollout = make_rollout(agent, env)

    def update(state: Any, collector: Collector, learner_key: jax.Array):
        learner_key, learn_key = jax.random.split(learner_key)
        collector, trajectory, games = rollout(state, collector)
        state, metrics = agent.learn(state, trajectory, learn_key)
        metrics = {**metrics, "masked_fraction": 1.0 - trajectory.info["valid"].mean()}
        return state, collector, learner_key, metrics, games

    return update


def finished_games(games: Games) -> list[tuple[float, int]]:
    """``(true score, length)`` of each game a rollout finished, in time order (``drain_scores``'s)."""
    finished, score, length = jax.device_get((games.finished, games.score, games.length))
    return [(float(s), int(n)) for s, n in zip(score[finished], length[finished], strict=True)]


def train(
    agent: Agent,
    env_id: str,
    runner: host.HostRunnerConfig,
    run: Run | None = None,
    *,
    resume: bool = False,
    progress: bool = False,
    num_seeds: int = 1,
) -> TrainResult:
    """Train an on-policy ``agent`` (PPO) on an Atari game, env and learning in one program per
    iteration; log, checkpoint and evaluate into ``run`` as :func:`agentax.runners.host.train` does."""
    check(agent, env_id, runner, num_seeds)
    _xla.let_xla_use_every_cpu()
    evaluator = host.Evaluator(agent, host.env_factory(env_id, runner), runner.eval_episodes)
    session = Session(agent, run, runner, evaluator, resume=resume)
    state, learner_key, updates, env_steps = (
        session.state,
        session.learner_key,
        session.updates,
        session.env_steps,
    )
    games_done = int(session.meta.get("games", 0))
    experience: OnPolicy = agent.experience
    env = XlaAtari(
        env_id,
        experience.num_envs,
        seed=host.actor_seed(runner.seed, 0, updates),
        sticky_actions=runner.sticky_actions,
    )
    collector = start_collector(env, host.fold_actor_key(session.actors_key, 0, updates), env_steps)
    update = jax.jit(make_update(agent, env), donate_argnums=(0, 1))
    total_updates = host.num_updates(agent)
    scores: list[float] = []
    with session.begin(f"{agent.name} {env_id} (compiled)", progress):
        try:
            while updates < total_updates:
                state, collector, learner_key, metrics, games = update(state, collector, learner_key)
                updates += 1
                env_steps += experience.num_envs * experience.num_steps
                finished = finished_games(games)  # waits for the iteration: speeds count all of it
                games_done += len(finished)
                scores += [score for score, _ in finished]
                last = updates >= total_updates
                if not session.row_due(env_steps, last):
                    continue
                args = (state, learner_key, env_steps, updates, scores, metrics)
                extra, counts = {"frames": FRAME_SKIP * env_steps}, {"games": games_done}
                scores = []
                if session.log_row(*args, final=last, extra=extra, counts=counts):
                    break
        finally:
            env.close()
    return session.finish(state, env_steps, updates)
