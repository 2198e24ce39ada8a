"""Atari games and MuJoCo tasks stepped inside a jitted program: EnvPool's XLA interface.

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

**MuJoCo.** :class:`XlaMujoco` is EnvPool's pool of a Gymnasium MuJoCo v5 task (``HalfCheetah-v5``,
``Hopper-v5``, ...; EnvPool's own build of the engine, no ``mujoco`` package needed) behind the same
``reset`` / ``step`` and the same :class:`PoolStep`: no lives (``life_lost`` is never set),
``game_over`` is the task's termination (Hopper falling), ``truncated`` its 1000-step limit, and the
same next-step reset, so :func:`track` reads it unchanged (an "episode" for a "game"). EnvPool takes
and returns float64 (its actions must be float64, its observations and rewards are): the pool's
call is made and traced under ``jax.enable_x64`` and its values cast to float32 at once, so the rest
of the program keeps JAX's 32-bit default. How its tasks compare with Gymnasium's is written down in
``docs/howto/mujoco.md`` (the same reset gives the same rewards to ~1e-7 until chaos separates them).
"""

from __future__ import annotations

import os
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

    obs: (
        jax.Array
    )  # the observation reached (a reset step: the next first one): Atari uint8 [num_envs, 4, 84, 84]
    reward: jax.Array  # float32: the raw reward, unclipped
    life_lost: (
        jax.Array
    )  # bool: a life was lost, the game goes on (after EnvPool's reset step); MuJoCo: never
    game_over: jax.Array  # bool: the emulator's game over; MuJoCo: the task's termination
    truncated: jax.Array  # bool: the game reached the frame (MuJoCo: step) limit, and no game over

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

    clip_rewards = True
    """a learner sees rewards clipped to their sign (the standard Atari learning view)"""

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


ENVPOOL_MUJOCO = (
    "Ant-v5",
    "HalfCheetah-v5",
    "Hopper-v5",
    "Humanoid-v5",
    "HumanoidStandup-v5",
    "InvertedDoublePendulum-v5",
    "InvertedPendulum-v5",
    "Pusher-v5",
    "Reacher-v5",
    "Swimmer-v5",
    "Walker2d-v5",
)
"""Gymnasium's MuJoCo v5 ids that EnvPool 1.2.5 makes with v5's settings (its registration.py)."""


def is_envpool_mujoco_id(env_id: str) -> bool:
    return env_id in ENVPOOL_MUJOCO


class XlaMujoco:
    """``num_envs`` copies of a MuJoCo v5 task in one EnvPool pool whose :meth:`step` runs inside ``jit``.

    ``task_kwargs`` go to ``envpool.make`` (the task's own settings, e.g. ``reset_noise_scale``). As
    :class:`XlaAtari`: seeded when made (env ``i`` with ``seed + i``), one pool per program, keep it
    alive while the program runs and :meth:`close` it afterwards.
    """

    clip_rewards = False
    """a learner sees the task's rewards as they are"""

    def __init__(self, env_id: str, num_envs: int, *, seed: int = 0, **task_kwargs: Any):
        if num_envs < 1:
            raise UsageError(f"num_envs must be at least 1, got {num_envs}")
        if not is_envpool_mujoco_id(env_id):
            raise UsageError(f"EnvPool's MuJoCo tasks are {', '.join(ENVPOOL_MUJOCO)}, not {env_id!r}")
        try:
            import envpool
        except ImportError:
            raise UsageError(
                f"{env_id} inside the program needs EnvPool (Linux only; the atari extra installs it: "
                "pip install 'agentax[atari]'), or train it with --runner host"
            ) from None
        self.pool = envpool.make(
            env_id,
            env_type="gymnasium",
            num_envs=num_envs,
            batch_size=num_envs,
            num_threads=min(num_envs, os.cpu_count() or 1),
            seed=seed,
            **task_kwargs,
        )
        self.id, self.num_envs, self.seed = env_id, num_envs, seed
        self.obs_shape = tuple(self.pool.observation_space.shape)
        space = self.pool.action_space
        self.action_low = np.asarray(space.low, np.float32)
        self.action_high = np.asarray(space.high, np.float32)
        self._xla_step = None

    def observation_space(self, params: Any = None) -> Box:
        return Box(-np.inf, np.inf, self.obs_shape, np.float32)

    def action_space(self, params: Any = None) -> Box:
        return Box(self.action_low, self.action_high, self.action_low.shape, np.float32)

    def reset(self) -> tuple[jax.Array, jax.Array]:
        """New episodes (a host call, outside ``jit``): ``(handle, obs float32 [num_envs, obs_dim])``."""
        obs, info = self.pool.reset()
        with jax.enable_x64(True):  # the pool's call is typed float64 only where x64 is on
            handle, _, _, self._xla_step = self.pool.xla()
        return jnp.asarray(handle), jnp.asarray(obs[np.argsort(info["env_id"])], jnp.float32)

    def step(self, handle: jax.Array, action: jax.Array) -> tuple[jax.Array, PoolStep]:
        """Step every env with ``action: float [num_envs, action_dim]`` (jittable): ``(handle, PoolStep)``."""
        if self._xla_step is None:
            raise RuntimeError("XlaMujoco.step before reset()")
        with jax.enable_x64(True):  # everything 64-bit is cast back before it leaves
            handle, (obs, reward, terminated, truncated, info) = self._xla_step(
                handle, action.astype(jnp.float64)
            )
            order = jnp.argsort(info["env_id"]).astype(jnp.int32)  # env-id order, as XlaAtari's
            obs, reward = obs[order].astype(jnp.float32), reward[order].astype(jnp.float32)
            terminated, truncated = terminated[order].astype(bool), truncated[order].astype(bool)
        truncated = truncated & ~terminated
        return handle, PoolStep(obs, reward, jnp.zeros_like(terminated), terminated, truncated)

    def close(self) -> None:
        self.pool.close()

    def __repr__(self) -> str:
        return f"XlaMujoco({self.id!r}, num_envs={self.num_envs}, seed={self.seed})"


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
