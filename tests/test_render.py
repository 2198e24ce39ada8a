"""Animations: an episode recorded, drawn and written as GIF or MP4."""

import gymnasium
import imageio.v3 as iio
import jax
import numpy as np
import pytest

from agentax.envs import make
from agentax.envs.vacuum import Vacuum, unpack_cells
from agentax.errors import UsageError
from agentax.policies import basic_policy, random_policy
from agentax.render import record_episode, rollout, save_episode, write_video
from agentax.search.settings import vacuum_policy


def _cart_column(frame):
    """The centre column of the black cart (rows 286-313: the cart's band, minus the track line at 300)."""
    band = np.all(frame[286:299] < 50, axis=-1)
    return np.flatnonzero(band.any(axis=0)).mean()


@pytest.mark.timeout(120)
def test_cartpole_gif_has_a_frame_per_state_and_the_cart_moves(tmp_path):
    env, seed = make("CartPole-v1"), 4
    path, episode = save_episode(env, basic_policy, tmp_path / "episode.gif", seed=seed)
    frames = iio.imread(path, index=None)
    assert frames.shape == (episode.length + 1, 400, 600, 3)  # the reset state, then one per step

    # The same episode in Gymnasium's CartPole, from the recorded first state, with the basic
    # policy on Gymnasium's observations: as long, with reward 1 per step.
    states, _, _ = rollout(env, basic_policy, jax.random.key(seed), 500, env.default_params())
    gym_env = gymnasium.make("CartPole-v1")
    gym_env.reset(seed=0)
    first = np.array([states.x[0], states.x_dot[0], states.theta[0], states.theta_dot[0]], np.float64)
    gym_env.unwrapped.state, obs, length, done = first, first, 0, False
    while not done:
        obs, _, terminated, truncated, _ = gym_env.step(int(obs[2] >= 0))
        length, done = length + 1, terminated or truncated
    assert episode.length == length and episode.total_return == float(length)

    # The cart is drawn where the state puts it: column = 300 + 125 px/m * x (600 px for 4.8 m).
    for i in (0, length // 2, length):
        assert _cart_column(frames[i]) == pytest.approx(300 + 125 * float(states.x[i]), abs=1.0)
    assert abs(_cart_column(frames[-1]) - _cart_column(frames[0])) > 3  # it moved


def test_pole_leans_the_way_of_its_angle():
    env = make("CartPole-v1")
    params = env.default_params()
    _, state = env.reset(jax.random.key(0), params)
    right = env.render_frame(state.replace(x=0.0, theta=0.2), params)
    left = env.render_frame(state.replace(x=0.0, theta=-0.2), params)
    pole = lambda frame: np.all(frame == (202, 152, 101), axis=-1)  # noqa: E731
    columns_right, columns_left = np.nonzero(pole(right))[1], np.nonzero(pole(left))[1]
    # the tip sits 125 px * sin(0.2) = 24.8 px right (left) of the axle at column 300
    assert columns_right.max() == pytest.approx(300 + 24.8 + 5, abs=2)
    assert columns_left.min() == pytest.approx(300 - 24.8 - 5, abs=2)


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # imageio-ffmpeg forks, then execs
def test_mp4_round_trip(tmp_path):
    frames = np.zeros((12, 41, 63, 3), np.uint8)  # odd sides: padded to even for H.264
    frames[:, :, :, 0] = np.arange(12)[:, None, None] * 20
    path = write_video(frames, tmp_path / "clip.mp4", fps=10)
    back = iio.imread(path, index=None)
    assert back.shape == (12, 42, 64, 3)
    np.testing.assert_allclose(back[:, :41, :63, 0].mean(axis=(1, 2)), np.arange(12) * 20, atol=8)


def test_vacuum_animation_shows_the_floor_being_cleaned(tmp_path):
    episode = record_episode(Vacuum(), vacuum_policy(0.8, 1.0), seed=1, max_frames=5)
    assert episode.length == 900 and episode.frames.shape[0] == 5
    dust = lambda frame: np.all(np.abs(frame.astype(int) - (150, 115, 75)) < 8, axis=-1).sum()  # noqa: E731
    amounts = [dust(frame) for frame in episode.frames]
    assert amounts[0] > amounts[-1] and amounts == sorted(amounts, reverse=True)  # dust only goes away
    # The return is the dust picked up: 400 cells less those still dirty at the end of the same episode.
    states, _ = Vacuum().trajectory(vacuum_policy(0.8, 1.0), jax.random.key(1))
    assert episode.total_return == 400 - unpack_cells(np.asarray(states.dirty[-1]), 20).sum()  # measured 111


def test_gymnasium_env_is_drawn_by_gymnasium(tmp_path):
    env = make("FrozenLake-v1")
    path, episode = save_episode(env, random_policy(env.action_space()), tmp_path / "lake.gif", seed=2)
    frames = iio.imread(path, index=None)
    assert episode.frames.shape[1:] == (256, 256, 3) and frames.shape[0] <= episode.length + 1
    assert episode.length >= 1


@pytest.mark.parametrize(
    ("name", "message"), [("clip.avi", "must end in .gif or .mp4"), ("a/b", "must end in")]
)
def test_bad_video_paths_are_rejected_before_playing(tmp_path, name, message):
    with pytest.raises(UsageError, match=message):
        save_episode(make("CartPole-v1"), basic_policy, tmp_path / name)
    (tmp_path / "file").write_text("")
    with pytest.raises(UsageError, match="cannot write video"):
        write_video(np.zeros((2, 4, 4, 3), np.uint8), tmp_path / "file" / "x.gif")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]  # nothing half-written left behind


def test_gif_of_few_colours_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    colours = rng.integers(0, 256, (6, 3), dtype=np.uint8)
    frames = colours[rng.integers(0, 6, (40, 12, 10))]  # (T, H, W, 3), 6 colours in all
    frames[-1] = colours[5]  # a colour-poor last frame still maps exactly
    back = iio.imread(write_video(frames, tmp_path / "few.gif"), index=None)
    np.testing.assert_array_equal(back[..., :3], frames)
