"""Episodes as animations: record one episode, draw its frames, write them as a GIF or an MP4.

A JAX env's episode is played by one jitted ``lax.scan`` that keeps every state; the frames are
drawn afterwards on the host with the env's ``render_frame`` (CartPole's cart and pole, the
vacuum's room with the dust it has left). A Gymnasium env draws itself with
``render_mode="rgb_array"``. A thin bar along the bottom of each frame shows the time elapsed
out of the episode's limit.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import gymnasium
import imageio.v3 as iio
import jax
import numpy as np

from agentax.envs import Environment, GymnasiumEnv
from agentax.envs.core import EnvParams, rollout
from agentax.envs.gym import frames_per_second
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


def _record_gymnasium(
    env: GymnasiumEnv | str, policy: Policy | HostPolicy, seed: int, max_steps: int, max_frames: int
) -> Episode:
    env_id, kwargs = (env, {}) if isinstance(env, str) else (env.id, env.make_kwargs)
    try:
        gym_env = gymnasium.make(env_id, render_mode="rgb_array", **kwargs)
    except gymnasium.error.Error as error:
        raise UsageError(f"cannot draw {env_id!r}: {error}") from error
    horizon = gym_env.spec.max_episode_steps if gym_env.spec and gym_env.spec.max_episode_steps else max_steps
    act = host_actor(policy, seed)
    obs, _ = gym_env.reset(seed=seed)
    frames, total_return, length = [_with_time_bar(gym_env.render(), 0, horizon)], 0.0, 0
    while length < max_steps:
        obs, reward, terminated, truncated, _ = gym_env.step(act(np.asarray(obs)[None])[0])
        total_return, length = total_return + float(reward), length + 1
        frames.append(_with_time_bar(gym_env.render(), length, horizon))
        if terminated or truncated:
            break
    fps = float(gym_env.metadata.get("render_fps") or 30)
    gym_env.close()
    return Episode(
        np.stack([frames[i] for i in _frame_indices(length, max_frames)]), total_return, length, fps
    )


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
