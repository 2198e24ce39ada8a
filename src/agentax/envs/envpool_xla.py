"""Atari games stepped inside a jitted program: EnvPool's XLA interface, agentax's preprocessing.

:class:`XlaAtari` makes an EnvPool pool with the very arguments of the host adapter's EnvPool
backend (:func:`agentax.envs.atari.envpool_kwargs`: 84x84 gray, frame skip 4, up to 30 no-ops,
4 stacked frames, ``episodic_life``, raw rewards, sticky actions as asked) and hands out its
``step(handle, action)``, which runs inside ``jax.jit`` and ``lax.scan`` (EnvPool's ``env.xla()``,
as CleanRL's ``ppo_atari_envpool_xla_jax.py`` uses it). The pool's ``handle`` is threaded through
the program like any state. One pool per program: the handle cannot be vmapped over seeds.

**EnvPool's next-step reset.** EnvPool does not reset an env on the step that ends its episode
(a lost life under ``episodic_life``, a game over, the frame limit) but on the *next* one, which
ignores its action, pays nothing and returns the new first observation (sail-sg/envpool#194). The
host adapter hides this by stepping the ended envs again at once, alone; a program with fixed
shapes cannot step some envs of the pool, so here every env takes that reset step with the
others. :class:`EpisodeTracker` (carried through the program) remembers which envs ended on the
last step, and :func:`track` marks their next step not ``valid``: it is no transition of the game
(its observation is the last one of the ended episode, its action was ignored, its next
observation is the first of the next episode), so a learner must leave it out. The step before it
is itself marked done (``terminated`` or ``truncated``), so GAE neither bootstraps nor carries its
λ-trace across it. Learning view: ``terminated`` on every lost life and at game over (as the host
adapter's ``training=True``), rewards clipped to their sign by the learner's side (:func:`track`
returns the raw ones).

**Whole-game scores.** :func:`track` also sums the raw rewards (``info["reward"]``, unclipped
whatever ``reward_clip`` says) of the valid steps of each game over all its lives, and reports
each game that ends (the emulator's game over, ``info["terminated"]``, or the frame limit) with its
score and its length in valid agent steps: the numbers the host adapter's ``drain_scores()``
gives for the same seed and actions (``tests/test_atari_compiled.py`` checks it).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.envs.atari import (
    FRAME_SKIP,
    SCREEN,
    STACK,
    envpool_ends,
    envpool_kwargs,
    game_of,
    import_envpool,
)
from agentax.envs.core import Box, Discrete
from agentax.errors import UsageError


@struct.dataclass
class PoolStep:
    """One step of every env of the pool, in env-id order (arrays ``[num_envs]`` unless said)."""

    obs: jax.Array  # uint8 [num_envs, 4, 84, 84]: the observation reached (a reset step: the next first one)
    reward: jax.Array  # float32: the raw reward, unclipped
    life_lost: jax.Array  # bool: a life was lost, the game goes on (after EnvPool's reset step)
    game_over: jax.Array  # bool: the emulator's game over
    truncated: jax.Array  # bool: the game reached the frame limit (and no game over)

    @property
    def terminated(self) -> jax.Array:
        """The learning view's end without bootstrapping: a lost life or a game over."""
        return self.life_lost | self.game_over

    @property
    def ended(self) -> jax.Array:
        """Whether EnvPool resets this env on its next step."""
        return self.life_lost | self.game_over | self.truncated


class XlaAtari:
    """``num_envs`` games of an Atari id in one EnvPool pool whose :meth:`step` runs inside ``jit``.

    The pool is seeded when made (env ``i`` with ``seed + i``, as the host adapter's); make a new
    ``XlaAtari`` for a new seed. A program that calls :meth:`step` is bound to this pool: keep the
    object alive while the program runs, and :meth:`close` it afterwards.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        *,
        seed: int = 0,
        sticky_actions: float = 0.25,
        noop_max: int = 30,
        max_frames: int = 108_000,
    ):
        if num_envs < 1:
            raise UsageError(f"num_envs must be at least 1, got {num_envs}")
        if not 0.0 <= sticky_actions <= 1.0:
            raise UsageError(f"sticky actions is a probability in [0, 1], got {sticky_actions}")
        game, _ = game_of(env_id)
        envpool = import_envpool()
        kwargs = envpool_kwargs(game, num_envs, sticky_actions, noop_max, max_frames // FRAME_SKIP, seed)
        self.pool = envpool.make(**kwargs)
        self.id, self.game, self.num_envs, self.seed = f"ALE/{game}-v5", game, num_envs, seed
        self.sticky_actions = sticky_actions
        self.num_actions = int(self.pool.action_space.n)
        self._xla_step = None

    def observation_space(self, params: Any = None) -> Box:
        return Box(0, 255, (STACK, SCREEN, SCREEN), np.uint8)

    def action_space(self, params: Any = None) -> Discrete:
        return Discrete(self.num_actions)

    def reset(self) -> tuple[jax.Array, jax.Array]:
        """Start new games (a host call, outside ``jit``): ``(handle, obs uint8 [num_envs, 4, 84, 84])``.
        No reset step is pending afterwards (a fresh :class:`EpisodeTracker`)."""
        obs, info = self.pool.reset()
        handle, _, _, step = self.pool.xla()
        self._xla_step = step
        return jnp.asarray(handle), jnp.asarray(obs[np.argsort(info["env_id"])])

    def step(self, handle: jax.Array, action: jax.Array) -> tuple[jax.Array, PoolStep]:
        """Step every env with ``action: int [num_envs]`` (jittable): ``(handle, PoolStep)``."""
        if self._xla_step is None:
            raise RuntimeError("XlaAtari.step before reset()")
        handle, (obs, _, terminated, truncated, info) = self._xla_step(handle, action.astype(jnp.int32))
        order = jnp.argsort(info["env_id"])  # a synchronous pool answers in env-id order; made sure
        game_over = info["terminated"][order].astype(bool)
        life_lost, game_over, truncated = envpool_ends(terminated[order], truncated[order], game_over)
        reward = info["reward"][order].astype(jnp.float32)
        return handle, PoolStep(obs[order], reward, life_lost, game_over, truncated)

    def close(self) -> None:
        self.pool.close()

    def __repr__(self) -> str:
        return (
            f"XlaAtari({self.id!r}, num_envs={self.num_envs}, seed={self.seed}, "
            f"sticky_actions={self.sticky_actions})"
        )


@struct.dataclass
class EpisodeTracker:
    """What the program carries to read EnvPool's steps (arrays ``[num_envs]``)."""

    reset_next: jax.Array  # bool: the last step ended an episode, so this env's next step is a reset step
    score: jax.Array  # float32: the running game's true score (raw rewards of every life)
    length: jax.Array  # int32: the running game's valid agent steps

    @classmethod
    def create(cls, num_envs: int) -> EpisodeTracker:
        """After ``reset()``: no reset step pending, no score yet."""
        return cls(
            jnp.zeros(num_envs, bool), jnp.zeros(num_envs, jnp.float32), jnp.zeros(num_envs, jnp.int32)
        )


@struct.dataclass
class TrackedStep:
    """How to read one :class:`PoolStep` (arrays ``[num_envs]``)."""

    valid: jax.Array  # bool: a real transition; False on EnvPool's reset step (leave it out of learning)
    game_finished: jax.Array  # bool: a whole game ended on this step (game over or frame limit)
    game_score: jax.Array  # float32: that game's true score where game_finished, else 0
    game_length: jax.Array  # int32: its length in valid agent steps where game_finished, else 0


def track(tracker: EpisodeTracker, step: PoolStep) -> tuple[EpisodeTracker, TrackedStep]:
    """Mark the reset step, and keep the whole-game score and length (see the module docstring).

    A reset step (``tracker.reset_next``) adds neither reward nor length; a game finishes on a
    valid step with a game over or the frame limit.
    """
    valid = ~tracker.reset_next
    score = tracker.score + jnp.where(valid, step.reward, 0.0)
    length = tracker.length + valid.astype(jnp.int32)
    finished = valid & (step.game_over | step.truncated)
    tracked = TrackedStep(
        valid=valid,
        game_finished=finished,
        game_score=jnp.where(finished, score, 0.0),
        game_length=jnp.where(finished, length, 0),
    )
    tracker = EpisodeTracker(
        reset_next=step.ended,
        score=jnp.where(finished, 0.0, score),
        length=jnp.where(finished, 0, length),
    )
    return tracker, tracked
