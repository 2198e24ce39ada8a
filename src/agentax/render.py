"""Episodes as animations: record one episode, draw its frames, write them as a GIF or an MP4.

A JAX env's episode is played by one jitted ``lax.scan`` that keeps every state; the frames are
drawn afterwards on the host with the env's ``render_frame`` (CartPole's cart and pole, the
vacuum's room with the dust it has left). A Gymnasium env draws itself with
``render_mode="rgb_array"``; a MuJoCo task off screen through ``MUJOCO_GL`` (``egl`` or ``osmesa``;
EGL where unset and there is no display), where no OpenGL works one line says what to install. A
thin bar along the bottom of each frame shows the time elapsed out of the episode's limit.

An Atari game (:func:`record_atari_game`) is filmed from the emulator's full-resolution RGB screen
(210x160, upscaled by an integer factor, nearest neighbour), one frame per agent step, written to
the file as it is played (an MP4 of a whole 108,000-frame game never sits in memory).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import gymnasium
import imageio.v3 as iio
import jax
import numpy as np

from agentax.envs import AtariEnv, Environment, GymnasiumEnv
from agentax.envs.core import EnvParams, rollout
from agentax.envs.gym import frames_per_second, is_mujoco_id, require_mujoco
from agentax.errors import UsageError
from agentax.evaluate import HostPolicy, host_actor
from agentax.policies import Policy

VIDEO_SUFFIXES = (".gif", ".mp4")


@dataclass(frozen=True)
class Episode:
    """One recorded episode."""

    frames: np.ndarray  # uint8 [num_frames, H, W, 3]: the reset state, then one per step (maybe subsampled)
    total_return: float
    length: int  # steps taken
    fps: float  # frames per second that play the episode in real time


def _frame_indices(length: int, max_frames: int) -> np.ndarray:
    """Indices of the frames to draw out of ``length + 1``: all of them, or ``max_frames`` spread evenly."""
    if length + 1 <= max_frames:
        return np.arange(length + 1)
    return np.unique(np.linspace(0, length, max_frames).round().astype(int))


def _with_time_bar(frame: np.ndarray, step: int, horizon: int) -> np.ndarray:
    """``frame`` with a grey bar along its bottom edge, ``step / horizon`` of its width long."""
    frame = np.array(frame, np.uint8)
    frame[-4:, : int(round(frame.shape[1] * min(step / max(horizon, 1), 1.0)))] = (120, 120, 120)
    return frame


def record_episode(
    env: Environment | GymnasiumEnv | str,
    policy: Policy | HostPolicy,
    seed: int = 0,
    env_params: EnvParams | None = None,
    max_steps: int = 1000,
    max_frames: int = 600,
) -> Episode:
    """Play one episode of ``policy`` and draw it.

    A JAX env plays up to its ``max_steps_in_episode`` (else ``max_steps``) steps; a Gymnasium env
    (a :class:`GymnasiumEnv` or an id) is made again with ``render_mode="rgb_array"``. Episodes of
    more than ``max_frames`` frames keep ``max_frames`` of them, evenly spread.
    """
    if isinstance(env, AtariEnv):
        raise UsageError(f"{env.id} is an Atari game: record it with record_atari_game (whole games)")
    if isinstance(env, str | GymnasiumEnv):
        return _record_gymnasium(env, policy, seed, max_steps, max_frames)
    if isinstance(policy, HostPolicy):
        raise UsageError(f"{env.id} is a JAX env: give a JAX policy (obs, key) -> action, not a HostPolicy")
    params = env.default_params() if env_params is None else env_params
    horizon = int(getattr(params, "max_steps_in_episode", max_steps))
    states, rewards, done = jax.device_get(rollout(env, policy, jax.random.key(seed), horizon, params))
    length = int(np.argmax(done)) + 1 if done.any() else horizon
    frames = [
        _with_time_bar(env.render_frame(jax.tree.map(lambda leaf, i=i: leaf[i], states), params), i, horizon)
        for i in _frame_indices(length, max_frames)
    ]
    return Episode(np.stack(frames), float(rewards[:length].sum()), length, frames_per_second(params))


MUJOCO_FRAME = {"width": 320, "height": 240}
"""the size of a MuJoCo frame: software OpenGL (Mesa's llvmpipe) draws ~10 a second on a busy core"""


def _mujoco_gl(env_id: str) -> str:
    """The OpenGL backend MuJoCo renders ``env_id`` with: ``MUJOCO_GL`` where set, else EGL (off
    screen) on a Linux machine without a display (MuJoCo's own default, GLFW, needs a window)."""
    require_mujoco(env_id)
    if "MUJOCO_GL" not in os.environ and sys.platform.startswith("linux"):
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            os.environ["MUJOCO_GL"] = "egl"
    return os.environ.get("MUJOCO_GL", "glfw")


def _stays_put(gym_env: gymnasium.Env, env_id: str) -> bool:
    """Whether a MuJoCo env's default camera stays put (HalfCheetah's and Ant's: they run out of
    the picture) while its model has a camera named "track" that follows the body."""
    env = gym_env.unwrapped
    config = env.mujoco_renderer.default_cam_config or {}
    mujoco = require_mujoco(env_id)
    return (
        "trackbodyid" not in config and mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_CAMERA, "track") >= 0
    )


def _first_frame(gym_env: gymnasium.Env, env_id: str, gl: str | None) -> np.ndarray:
    """``gym_env.render()`` of the reset state; for MuJoCo (``gl`` its backend) a failing OpenGL
    becomes one line that says what to install."""
    if gl is None:
        frame = gym_env.render()
        if np.ndim(frame) != 3:
            gym_env.close()
            raise UsageError(
                f"cannot draw {env_id!r}: its render() gave no RGB frame with render_mode='rgb_array'"
            )
        return frame
    try:
        return gym_env.render()
    except Exception as error:  # GLFW, EGL, OSMesa and PyOpenGL each fail with errors of their own
        with contextlib.suppress(Exception):  # a renderer that never started cannot close cleanly
            gym_env.close()
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise UsageError(
            f"cannot render {env_id} off screen with MUJOCO_GL={gl} ({reason}); MuJoCo videos need EGL "
            "(libegl1) or OSMesa (libosmesa6): set MUJOCO_GL=egl or MUJOCO_GL=osmesa"
        ) from None


MAX_FPS = 50.0
"""the most frames per second a video of a Gymnasium env is written at: a GIF's delays are whole
hundredths of a second and browsers play delays under 2/100 s at 1/10 s"""


def _record_gymnasium(
    env: GymnasiumEnv | str, policy: Policy | HostPolicy, seed: int, max_steps: int, max_frames: int
) -> Episode:
    """One episode of a Gymnasium env, drawing only the frames kept: every ``stride``-th step (and
    the last), the stride the smallest that keeps at most ``max_frames`` over the env's time limit
    and at most :data:`MAX_FPS` in real time (a MuJoCo frame costs ~0.1 s in software OpenGL)."""
    if isinstance(env, str):  # made once to learn how its observations are packed for the policy
        env = GymnasiumEnv(env, 1)
        env.close()
    env_id, kwargs = env.id, env.make_kwargs
    gl = _mujoco_gl(env_id) if is_mujoco_id(env_id) else None
    try:
        gym_env = gymnasium.make(env_id, render_mode="rgb_array", **(MUJOCO_FRAME if gl else {}), **kwargs)
        if gl and _stays_put(gym_env, env_id):
            gym_env.close()  # the model's "track" camera follows the body instead
            gym_env = gymnasium.make(
                env_id, render_mode="rgb_array", camera_name="track", **MUJOCO_FRAME, **kwargs
            )
    except (gymnasium.error.Error, TypeError) as error:  # TypeError: an env that takes no render_mode
        reason = " ".join(str(error).split())
        raise UsageError(f"cannot draw {env_id!r} (it needs render_mode='rgb_array'): {reason}") from None
    horizon = gym_env.spec.max_episode_steps if gym_env.spec and gym_env.spec.max_episode_steps else max_steps
    fps = float(gym_env.metadata.get("render_fps") or 30)
    stride = max(math.ceil((min(horizon, max_steps) + 1) / max_frames), math.ceil(fps / MAX_FPS))
    act = host_actor(policy, seed)
    obs, info = gym_env.reset(seed=seed)
    frames, total_return, length = [_with_time_bar(_first_frame(gym_env, env_id, gl), 0, horizon)], 0.0, 0
    while length < max_steps:
        obs, reward, terminated, truncated, info = gym_env.step(act(env.observe(obs, info)[None])[0])
        total_return, length = total_return + float(reward), length + 1
        done = terminated or truncated or length == max_steps
        if length % stride == 0 or done:
            frames.append(_with_time_bar(gym_env.render(), length, horizon))
        if done:
            break
    gym_env.close()
    return Episode(np.stack(frames), total_return, length, fps / stride)


def check_video_path(path: str | os.PathLike) -> Path:
    """``path`` as a ``Path`` if it ends in .gif or .mp4 and its folder can be made and written.

    Anything else raises ``UsageError`` before an episode is played.
    """
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise UsageError(
            f"cannot write video {str(path)!r}: its name must end in {' or '.join(VIDEO_SUFFIXES)}"
        )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UsageError(f"cannot write video {str(path)!r}: {error.strerror}") from error
    if not os.access(path.parent, os.W_OK) or path.is_dir():
        raise UsageError(f"cannot write video {str(path)!r}: not a writable file location")
    return path


def gif_frames(frames: np.ndarray) -> list:
    """``frames [T, H, W, 3]`` as palette images sharing one palette of at most 256 colours.

    The palette is the median cut of frames spread over the whole episode, and every frame maps to
    it without dithering: exact for drawings of few colours (CartPole has 5), and ~8x faster than
    quantizing every frame on its own (500 CartPole frames: 0.5 s instead of 3.9 s).
    """
    from PIL import Image

    sample = frames[:: max(1, len(frames) // 16)]
    palette = Image.fromarray(np.concatenate(list(sample), axis=0)).quantize(
        256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
    )
    return [Image.fromarray(frame).quantize(palette=palette, dither=Image.Dither.NONE) for frame in frames]


def write_video(frames: np.ndarray, path: str | os.PathLike, fps: float = 30.0) -> Path:
    """Write ``frames [T, H, W, 3]`` uint8 to a .gif or .mp4 file: whole or not at all (temp file, rename)."""
    path = check_video_path(path)
    partial_path = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        if path.suffix.lower() == ".gif":
            first, *rest = gif_frames(frames)
            first.save(partial_path, save_all=True, append_images=rest, duration=1000.0 / fps, loop=0)
        else:
            height, width = frames.shape[1:3]  # H.264 in yuv420p needs even sides
            frames = np.pad(frames, ((0, 0), (0, height % 2), (0, width % 2), (0, 0)), mode="edge")
            with warnings.catch_warnings():  # ffmpeg runs in a subprocess; its fork is followed by exec
                warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
                iio.imwrite(partial_path, frames, fps=fps, macro_block_size=1)
        os.replace(partial_path, path)
    except OSError as error:
        raise UsageError(f"cannot write video {str(path)!r}: {error}") from error
    finally:
        partial_path.unlink(missing_ok=True)
    return path


def save_episode(
    env: Environment | GymnasiumEnv | str,
    policy: Policy | HostPolicy,
    path: str | os.PathLike,
    seed: int = 0,
    env_params: EnvParams | None = None,
) -> tuple[Path, Episode]:
    """Record one episode and write it to ``path`` (.gif or .mp4); the path is checked first."""
    check_video_path(path)
    episode = record_episode(env, policy, seed, env_params)
    return write_video(episode.frames, path, episode.fps), episode


ATARI_FPS = 15.0
"""frames per second of an Atari video: one per agent step, 4 of the emulator's 60 a second (real time)"""


@dataclass(frozen=True)
class Game:
    """One recorded Atari game."""

    score: float  # the true score: every life, raw rewards
    length: int  # agent steps (4 emulator frames each)
    video_frames: int  # frames written: ``length``, fewer in a GIF of a game longer than its cap
    truncated: bool  # ended by the frame cap (108,000 frames), not by game over


def _upscaled(frame: np.ndarray, scale: int) -> np.ndarray:
    """``frame [H, W, 3]`` ``scale`` times larger (nearest neighbour), padded to even sides for H.264."""
    if scale > 1:
        frame = np.repeat(np.repeat(frame, scale, axis=0), scale, axis=1)
    height, width = frame.shape[:2]
    if height % 2 or width % 2:
        frame = np.pad(frame, ((0, height % 2), (0, width % 2), (0, 0)), mode="edge")
    return np.ascontiguousarray(frame, np.uint8)


class _Mp4Writer:
    """Frames streamed to ffmpeg (H.264) as they come."""

    def __init__(self, path: Path, fps: float, scale: int):
        self.path, self.fps, self.scale, self.frames, self.writer = path, fps, scale, 0, None

    def append(self, frame: np.ndarray) -> None:
        frame = _upscaled(frame, self.scale)
        if self.writer is None:
            import imageio_ffmpeg

            height, width = frame.shape[:2]
            self.writer = imageio_ffmpeg.write_frames(
                str(self.path), (width, height), fps=self.fps, macro_block_size=1, ffmpeg_log_level="error"
            )
            self.writer.send(None)
        self.writer.send(frame)
        self.frames += 1

    def close(self) -> int:
        if self.writer is not None:
            self.writer.close()
        return self.frames


class _GifWriter:
    """At most ``max_frames`` frames, evenly spaced over the game: every frame while they fit, then
    every second one, every fourth..., so memory stays bounded however long the game runs."""

    def __init__(self, path: Path, fps: float, scale: int, max_frames: int):
        self.path, self.fps, self.scale, self.max_frames = path, fps, scale, max(max_frames, 2)
        self.kept: list[np.ndarray] = []
        self.stride, self.seen = 1, 0

    def append(self, frame: np.ndarray) -> None:
        if self.seen % self.stride == 0:
            self.kept.append(np.array(frame, np.uint8))
            if len(self.kept) > self.max_frames:
                self.kept, self.stride = self.kept[::2], self.stride * 2
        self.seen += 1

    def close(self) -> int:
        from PIL import Image

        first, *rest = (
            image.resize((image.width * self.scale, image.height * self.scale), Image.Resampling.NEAREST)
            for image in gif_frames(np.stack(self.kept))
        )
        # GIF counts in hundredths of a second: durations rounded so that their running sum keeps time
        ends = np.round(np.arange(len(self.kept) + 1) * (100.0 * self.stride / self.fps)) * 10
        durations = np.diff(ends).astype(int).tolist()
        first.save(self.path, save_all=True, append_images=rest, duration=durations, loop=0)
        return len(self.kept)


def record_atari_game(
    env: AtariEnv,
    policy: Policy | HostPolicy,
    path: str | os.PathLike,
    seed: int = 0,
    scale: int = 3,
    max_gif_frames: int = 1500,
) -> tuple[Path, Game]:
    """Play one whole game of ``policy`` (every life, until game over or the env's frame cap) and
    write it to ``path`` (.mp4 or .gif) from the full-resolution RGB screens, ``scale`` times larger.

    ``env`` is an :class:`~agentax.envs.AtariEnv` of one env in the evaluation view
    (``training=False``), so the policy plays on after a lost life as it was evaluated. Frame ``t``
    is the screen the policy acted on at step ``t``: an MP4 has exactly the game's ``length`` frames
    at :data:`ATARI_FPS` (real time); a GIF keeps at most ``max_gif_frames`` of them, evenly spaced
    and each shown as long as the frames it stands for. The file is written whole or not at all.
    """
    if env.num_envs != 1 or env.training:
        raise ValueError(
            f"record an Atari game in one env of the evaluation view (training=False), not {env}"
        )
    if scale < 1:
        raise UsageError(f"the video's scale must be at least 1, not {scale}")
    path = check_video_path(path)
    partial_path = path.with_name(f".{path.stem}.partial{path.suffix}")
    gif = path.suffix.lower() == ".gif"
    writer = (
        _GifWriter(partial_path, ATARI_FPS, scale, max_gif_frames)
        if gif
        else _Mp4Writer(partial_path, ATARI_FPS, scale)
    )
    act = host_actor(policy, seed)
    try:
        with warnings.catch_warnings():  # ffmpeg runs in a subprocess; its fork is followed by exec
            warnings.filterwarnings("ignore", message="os.fork", category=RuntimeWarning)
            obs = env.reset(seed=seed)
            env.drain_scores()
            finished: list[tuple[float, int]] = []
            truncated = False
            while not finished:
                writer.append(env.render_rgb())  # before the step: it shows the new game once it ends
                time_step = env.step(act(obs))
                finished, obs = env.drain_scores(), time_step.obs
                truncated = bool(time_step.truncated[0] and not time_step.terminated[0])
            video_frames = writer.close()
        os.replace(partial_path, path)
    except OSError as error:
        raise UsageError(f"cannot write video {str(path)!r}: {error}") from error
    finally:
        if isinstance(writer, _Mp4Writer) and writer.writer is not None:
            writer.writer.close()
        partial_path.unlink(missing_ok=True)
    score, length = finished[0]
    return path, Game(score, length, video_frames, truncated)
