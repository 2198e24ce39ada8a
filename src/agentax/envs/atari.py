"""Atari games for the host runners, from EnvPool (C++ threads) or ale-py, with the same observations.

``make_atari("ALE/Breakout-v5", num_envs)`` (EnvPool's ``Breakout-v5`` too) returns an ``AtariEnv``
with ``GymnasiumEnv``'s interface: NumPy arrays with a leading ``num_envs`` axis, agentax's
``TimeStep`` fields, auto-reset on the same step. The preprocessing is the standard one (Mnih et al.
2015; Machado et al. 2018), identical in both backends:

- one agent step is 4 emulator frames with the action repeated; the observation is the pixel-wise
  max of the last two frames, in grayscale, resized to 84x84 (OpenCV's area interpolation), and the
  last 4 such frames stacked: uint8 ``[4, 84, 84]``;
- a game starts with up to ``noop_max`` no-op frames and, where the minimal action set has FIRE,
  one FIRE frame; after a lost life the game goes on with the same no-ops and FIRE (EnvPool's
  ``Reset`` with ``episodic_life``, whose counts the ale backend copies: a uniform number in
  ``1..noop_max`` of frames, the FIRE frame counting as one);
- sticky actions (``repeat_action_probability``) default to 0.25 (Gymnasium's v5, Machado et
  al.); 0 gives the setting of EnvPool's and CleanRL's published scores. State which with a score;
- a game is truncated after ``max_frames`` frames (``max_frames // 4`` agent steps).

``training=True`` is the learning view: rewards clipped to their sign, ``terminated`` on every lost
life (the emulator keeps playing the same game). ``training=False`` (evaluation): raw rewards,
``terminated`` only at game over. In both, the true score of each finished game (all lives,
unclipped) and its length in agent steps go to ``drain_scores()``: that is what to log and report.

Why agentax preprocesses ale-py's frames itself instead of stacking Gymnasium's
``AtariPreprocessing`` and ``FrameStackObservation``: EnvPool fires in one frame at a reset and,
after a lost life, pushes one frame onto the running stack; Gymnasium's wrappers can only refill
the stack or step 4 frames. Doing it here keeps the two backends frame-for-frame alike, and
``tests/test_atari.py`` checks this preprocessing against ``AtariPreprocessing`` frame by frame.

EnvPool resets an env on the step *after* the one that ended its episode (that step ignores its
action and returns the new first observation; sail-sg/envpool#194). The adapter hides it: the
envs whose episode (or, internally, life) just ended are stepped again at once, alone
(``step(actions, env_id=ended)``, whose action EnvPool ignores), so the step returns the next
first observation in ``obs`` and the real last one in ``final_obs``, as everywhere in agentax.
(Not ``reset(env_id=ended)``: in EnvPool 1.2.5 an explicit reset restarts the whole game, lives
and all, even with ``episodic_life``.)

:mod:`agentax.envs.envpool_xla` steps a pool made with the same arguments (:func:`envpool_kwargs`)
inside a jitted program, for the compiled Atari runner; there the reset step stays in the rollout,
marked so that learning leaves it out.
"""

from __future__ import annotations

import difflib
import functools
import os
import re
from typing import Any, Protocol

import numpy as np

from agentax.envs.core import Box, Discrete, TimeStep
from agentax.errors import UsageError

BACKENDS = ("auto", "envpool", "ale")
FRAME_SKIP = 4
STACK = 4
SCREEN = 84
_ID = re.compile(r"^(?:ALE/)?([A-Za-z0-9]+)-v5$")
_INSTALL = "pip install 'agentax[atari]'"


def _rom_to_name(rom: str) -> str:
    return "".join(part.capitalize() for part in rom.split("_"))


@functools.cache
def atari_games() -> dict[str, str]:
    """Game name (``Breakout``) -> ROM id (``breakout``) for every ROM an installed backend ships."""
    roms: list[str] = []
    try:
        import ale_py.roms

        roms = list(ale_py.roms.get_all_rom_ids())
    except ImportError:
        try:
            from envpool.atari.registration import atari_game_list

            roms = list(atari_game_list)
        except ImportError:
            pass
    return {_rom_to_name(rom): rom for rom in roms}


def is_atari_id(env_id: str) -> bool:
    """``ALE/<Game>-v5`` (Gymnasium's form, any game name) or ``<Game>-v5`` for a known ALE game."""
    if env_id.startswith("ALE/"):
        return True
    match = _ID.match(env_id)
    return match is not None and match.group(1) in atari_games()


def game_of(env_id: str) -> tuple[str, str]:
    """(game name, ROM id) for an Atari id; a ``UsageError`` naming the closest ids otherwise."""
    games = atari_games()
    match = _ID.match(env_id)
    if match is not None and match.group(1) in games:
        return match.group(1), games[match.group(1)]
    if not games:
        raise UsageError(f"Atari envs need ale-py or EnvPool, neither is installed: {_INSTALL}")
    name = env_id.removeprefix("ALE/").split("-")[0]
    by_lower = {g.lower(): g for g in games}
    close = difflib.get_close_matches(name.lower(), list(by_lower), n=3, cutoff=0.6)
    hint = ", ".join(f"ALE/{by_lower[g]}-v5" for g in close) or "none"
    raise UsageError(
        f"unknown Atari id {env_id!r}; closest: {hint} (ids look like ALE/Breakout-v5 or Breakout-v5)"
    )


class _Backend(Protocol):
    num_actions: int

    def reset(self, seed: int | None) -> np.ndarray: ...

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, ...]:
        """(obs, final_obs, raw reward, life lost, game over, truncated), every end reset already."""
        ...

    def render_rgb(self) -> np.ndarray: ...

    def close(self) -> None: ...


def _preprocess(frame: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.resize(frame, (SCREEN, SCREEN), interpolation=cv2.INTER_AREA)


class _AleGame:
    """One ale-py emulator with the standard preprocessing, done as EnvPool's ``AtariEnv`` does it.

    The emulator comes from ``gymnasium.make("ALE/<Game>-v5", frameskip=1, ...)`` so that a seed
    means what it means in Gymnasium (``reset(seed=s)`` seeds the emulator the same way); the
    frames are then taken from its ``ale`` directly (``AtariPreprocessing``'s grayscale screens).
    """

    def __init__(self, game: str, sticky_actions: float, noop_max: int, max_steps: int):
        import ale_py
        import gymnasium

        gymnasium.register_envs(ale_py)
        self.env = gymnasium.make(
            f"ALE/{game}-v5",
            frameskip=1,
            repeat_action_probability=sticky_actions,
            full_action_space=False,
            obs_type="ram",  # its own observations go unused: the cheapest to make
        )
        self.ale = self.env.unwrapped.ale
        self.action_set = list(self.env.unwrapped._action_set)
        self.noop_action, self.fire_action = ale_py.Action.NOOP, ale_py.Action.FIRE
        self.fire = self.fire_action in self.action_set
        self.noop_max, self.max_steps = max(noop_max, 1), max_steps
        self.rng = np.random.default_rng()
        self.pool = np.zeros((2, 210, 160), np.uint8)  # the last two frames of a step
        self.stack = np.zeros((STACK, SCREEN, SCREEN), np.uint8)
        self.lives = 0
        self.steps = 0

    def reset(self, seed: int | None) -> None:
        self.env.reset(seed=seed)
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self._start(new_game=True)

    def _start(self, new_game: bool) -> None:
        """No-ops and FIRE after ``reset_game`` (``new_game``) or a lost life; one frame pushed."""
        noops = int(self.rng.integers(self.noop_max)) + 1 - int(self.fire)
        for _ in range(noops):
            self.ale.act(self.noop_action)
            if self.ale.game_over():
                self.ale.reset_game()
                new_game = True
        if self.fire:
            self.ale.act(self.fire_action)
        self.ale.getScreenGrayscale(self.pool[0])
        self._push(_preprocess(self.pool[0]), all_frames=new_game)
        if new_game:
            self.steps = 0
        self.lives = self.ale.lives()

    def _push(self, frame: np.ndarray, all_frames: bool) -> None:
        if all_frames:
            self.stack[:] = frame
        else:
            self.stack[:-1] = self.stack[1:]
            self.stack[-1] = frame

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, bool]:
        """(last stack, raw reward, life lost, game over, truncated); ends are restarted at once."""
        reward, over = 0.0, False
        act = self.action_set[action]
        for frame in range(FRAME_SKIP):
            reward += self.ale.act(act)
            over = self.ale.game_over()
            if frame >= FRAME_SKIP - 2 or over:
                self.ale.getScreenGrayscale(self.pool[FRAME_SKIP - 1 - frame if not over else 0])
            if over:
                break
        screen = self.pool[0] if over else np.maximum(self.pool[0], self.pool[1])
        self._push(_preprocess(screen), all_frames=False)
        self.steps += 1
        lives = self.ale.lives()
        life_lost = not over and 0 < lives < self.lives
        truncated = not over and self.steps >= self.max_steps
        self.lives = lives
        final = self.stack.copy()
        if over or truncated:
            self.ale.reset_game()
            self._start(new_game=True)
        elif life_lost:
            self._start(new_game=False)
        return final, reward, life_lost, over, truncated


class _AleBackend:
    """``num_envs`` ale-py games stepped one after another in this thread."""

    def __init__(self, game: str, num_envs: int, sticky_actions: float, noop_max: int, max_steps: int):
        try:
            import ale_py  # noqa: F401
            import cv2  # noqa: F401
        except ImportError as error:
            raise UsageError(
                f"the ale backend needs ale-py and opencv ({error.name} is missing): {_INSTALL}"
            ) from None
        self.games = [_AleGame(game, sticky_actions, noop_max, max_steps) for _ in range(num_envs)]
        self.num_actions = len(self.games[0].action_set)

    def reset(self, seed: int | None) -> np.ndarray:
        for i, game in enumerate(self.games):
            game.reset(None if seed is None else seed + i)
        return np.stack([game.stack for game in self.games])

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, ...]:
        final, reward, life_lost, over, truncated = zip(
            *(game.step(int(a)) for game, a in zip(self.games, actions, strict=True)), strict=True
        )
        obs = np.stack([game.stack for game in self.games])
        return (
            obs,
            np.stack(final),
            np.asarray(reward, np.float32),
            np.asarray(life_lost),
            np.asarray(over),
            np.asarray(truncated),
        )

    def render_rgb(self) -> np.ndarray:
        return self.games[0].ale.getScreenRGB()

    def close(self) -> None:
        for game in self.games:
            game.env.close()


def envpool_kwargs(
    game: str, num_envs: int, sticky_actions: float, noop_max: int, max_steps: int, seed: int
) -> dict[str, Any]:
    """``envpool.make``'s arguments for ``num_envs`` games of ``game`` with agentax's preprocessing
    (module docstring), shared by the host backend and the in-program pool
    (:mod:`agentax.envs.envpool_xla`). Always ``episodic_life`` (EnvPool then does the no-ops and
    FIRE after a lost life; whether a life ends an episode is the caller's choice) and raw rewards
    (the caller clips them for learning)."""
    return dict(
        task_id=f"{game}-v5",
        env_type="gymnasium",
        num_envs=num_envs,
        batch_size=num_envs,
        num_threads=min(num_envs, os.cpu_count() or 1),
        seed=seed,
        episodic_life=True,
        reward_clip=False,
        use_fire_reset=True,
        repeat_action_probability=sticky_actions,
        noop_max=max(noop_max, 1),  # EnvPool draws 1..noop_max frames, FIRE counting as one
        max_episode_steps=max_steps,
        stack_num=STACK,
        frame_skip=FRAME_SKIP,
        img_height=SCREEN,
        img_width=SCREEN,
        gray_scale=True,
        full_action_space=False,
    )


def envpool_ends(terminated: Any, truncated: Any, game_over: Any) -> tuple[Any, Any, Any]:
    """``(life lost, game over, truncated)``, disjoint, from an ``episodic_life`` pool's step: its
    ``terminated`` (a lost life or a game over), ``truncated`` (the frame limit) and
    ``info["terminated"]`` (the emulator's game over). A game over wins over the frame limit,
    the frame limit over a lost life. NumPy or JAX boolean arrays ``[num_envs]``."""
    ended = terminated | truncated
    return ended & ~game_over & ~truncated, game_over, truncated & ~game_over


def import_envpool() -> Any:
    """The ``envpool`` module, or a ``UsageError`` saying how to install it."""
    try:
        import envpool
    except ImportError:
        raise UsageError(f"the envpool backend needs EnvPool (Linux only): {_INSTALL}") from None
    return envpool


class _EnvPoolBackend:
    """EnvPool's Atari pool made with :func:`envpool_kwargs` (raw rewards, ``episodic_life``)."""

    def __init__(self, game: str, num_envs: int, sticky_actions: float, noop_max: int, max_steps: int):
        envpool = import_envpool()
        self._make = lambda seed: envpool.make(
            **envpool_kwargs(game, num_envs, sticky_actions, noop_max, max_steps, seed),
            render_mode="rgb_array",
        )
        self.pool = self._make(0)
        self.num_actions = int(self.pool.action_space.n)

    def reset(self, seed: int | None) -> np.ndarray:
        if seed is not None:  # EnvPool takes its seed when made: a seeded reset makes the pool anew
            self.pool.close()
            self.pool = self._make(seed)
        obs, info = self.pool.reset()
        return obs[np.argsort(info["env_id"])]

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, ...]:
        obs, _, terminated, truncated, info = self.pool.step(np.asarray(actions, np.int32))
        order = np.argsort(info["env_id"])
        obs, terminated, truncated = obs[order], terminated[order], truncated[order]
        reward = info["reward"][order].astype(np.float32)  # raw, whatever reward_clip says
        over = info["terminated"][order].astype(bool)  # the emulator's game over
        life_lost, over, truncated = envpool_ends(terminated, truncated, over)
        final = obs.copy()
        ids = np.flatnonzero(life_lost | over | truncated)
        if ids.size:  # step now the ended envs alone: EnvPool's auto-reset, which ignores the action
            ids = ids.astype(np.int32)
            first, *_, info_reset = self.pool.step(np.zeros_like(ids), env_id=ids)
            obs[info_reset["env_id"]] = first
        return obs, final, reward, life_lost, over, truncated

    def render_rgb(self) -> np.ndarray:
        return self.pool.render(env_ids=0)[0]

    def close(self) -> None:
        self.pool.close()


def _envpool_available() -> bool:
    try:
        import envpool  # noqa: F401
    except ImportError:
        return False
    return True


class AtariEnv:
    """``num_envs`` Atari games behind ``GymnasiumEnv``'s interface (see the module docstring).

    ``step`` returns the learning view (``training=True``) or the evaluation view; either way
    ``drain_scores()`` returns the true score and length of every game finished since the last call.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int = 1,
        *,
        backend: str = "auto",
        sticky_actions: float = 0.25,
        noop_max: int = 30,
        training: bool = True,
        max_frames: int = 108_000,
    ):
        if backend not in BACKENDS:
            raise UsageError(f"unknown env backend {backend!r}; choose from {', '.join(BACKENDS)}")
        if num_envs < 1:
            raise UsageError(f"num_envs must be at least 1, got {num_envs}")
        if not 0.0 <= sticky_actions <= 1.0:
            raise UsageError(f"sticky actions is a probability in [0, 1], got {sticky_actions}")
        if noop_max < 0 or max_frames < FRAME_SKIP:
            raise UsageError(f"need noop_max >= 0 and max_frames >= {FRAME_SKIP}")
        game, _ = game_of(env_id)
        if backend == "auto":
            backend = "envpool" if _envpool_available() else "ale"
        make_backend = _EnvPoolBackend if backend == "envpool" else _AleBackend
        self.backend: _Backend = make_backend(
            game, num_envs, sticky_actions, noop_max, max_frames // FRAME_SKIP
        )
        self.id, self.game, self.backend_name = f"ALE/{game}-v5", game, backend
        self.num_envs, self.training = num_envs, training
        self.sticky_actions, self.noop_max, self.max_frames = sticky_actions, noop_max, max_frames
        self._score = np.zeros(num_envs, np.float64)
        self._length = np.zeros(num_envs, np.int64)
        self._finished: list[tuple[float, int]] = []

    def observation_space(self, params: Any = None) -> Box:
        return Box(0, 255, (STACK, SCREEN, SCREEN), np.uint8)

    def action_space(self, params: Any = None) -> Discrete:
        return Discrete(self.backend.num_actions)

    def reset(self, seed: int | None = None) -> np.ndarray:
        """First observations ``uint8 [num_envs, 4, 84, 84]`` of new games; env ``i`` seeded ``seed + i``."""
        self._score[:] = 0.0
        self._length[:] = 0
        return self.backend.reset(seed)

    def step(self, actions: Any) -> TimeStep:
        """One agent step (4 frames) of every game; ``actions: int [num_envs]``. Ends auto-reset."""
        obs, final_obs, reward, life_lost, over, truncated = self.backend.step(np.asarray(actions))
        self._score += reward
        self._length += 1
        for i in np.flatnonzero(over | truncated):
            self._finished.append((float(self._score[i]), int(self._length[i])))
            self._score[i], self._length[i] = 0.0, 0
        if self.training:
            terminated = over | life_lost
            reward = np.sign(reward).astype(np.float32)
        else:
            terminated = over
            final_obs[life_lost] = obs[life_lost]  # a lost life ends nothing here
        return TimeStep(obs, reward, terminated, truncated, final_obs)

    def drain_scores(self) -> list[tuple[float, int]]:
        """``(true score, length in agent steps)`` of each game finished since the last call."""
        finished, self._finished = self._finished, []
        return finished

    def render_rgb(self) -> np.ndarray:
        """Env 0's current screen, full resolution: ``uint8 [210, 160, 3]``."""
        return self.backend.render_rgb()

    def close(self) -> None:
        self.backend.close()

    def __repr__(self) -> str:
        return (
            f"AtariEnv({self.id!r}, num_envs={self.num_envs}, backend={self.backend_name!r}, "
            f"sticky_actions={self.sticky_actions}, training={self.training})"
        )


def make_atari(
    env_id: str,
    num_envs: int = 1,
    *,
    backend: str = "auto",
    sticky_actions: float = 0.25,
    noop_max: int = 30,
    training: bool = True,
    max_frames: int = 108_000,
) -> AtariEnv:
    """``num_envs`` copies of an ALE game with the standard preprocessing (module docstring).

    ``backend``: ``"envpool"``, ``"ale"``, or ``"auto"`` (EnvPool where it imports). Bad ids and
    missing backends raise ``UsageError`` with the fix.
    """
    return AtariEnv(
        env_id,
        num_envs,
        backend=backend,
        sticky_actions=sticky_actions,
        noop_max=noop_max,
        training=training,
        max_frames=max_frames,
    )
