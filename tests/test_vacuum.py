"""The robot vacuum: mechanics worked out by hand, dust conservation, auto-reset, drawings, packed cells."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.envs import JAX_ENVS, make_jax
from agentax.envs.core import episode_returns
from agentax.envs.vacuum import Vacuum, VacuumState, pack_cells, render_path, unpack_cells
from agentax.search.settings import vacuum_policy

ENV = Vacuum()
PARAMS = ENV.default_params()
FORWARD = jnp.array([1.0, 0.0])


def state_at(x, y, heading, dirty=None):
    dirty = pack_cells(jnp.ones((20, 20), bool) if dirty is None else dirty)
    position = jnp.float32(x), jnp.float32(y), jnp.float32(heading)
    return VacuumState(*position, dirty, jnp.bool_(False), jnp.int32(0))


def cells(state):
    """The dirty cells of ``state`` (stacked or not) as bool ``[..., 20, 20]``."""
    return unpack_cells(np.asarray(state.dirty), 20)


def test_registered_and_episode_is_thirty_minutes():
    assert isinstance(make_jax("Vacuum-v0"), Vacuum) and "Vacuum-v0" in JAX_ENVS
    # 30 simulated minutes / 2 s per step = 1800 / 2 = 900 steps.
    assert int(PARAMS.max_steps_in_episode) == 900
    _, lengths = jax.jit(lambda key: episode_returns(ENV, vacuum_policy(0.5, 1.0), key, 3))(jax.random.key(0))
    np.testing.assert_array_equal(lengths, [900, 900, 900])
    assert int(PARAMS.replace(step_seconds=3.0).max_steps_in_episode) == 600  # 1800 / 3


def test_forward_move_by_hand():
    # Heading 0 (east) from (1.1, 1.1): 0.25 m/s * 2 s = 0.5 m -> (1.6, 1.1). Cells are 5 m / 20 = 0.25 m;
    # the path's middle (1.35, 1.1) is cell (row 4, col 5), its end (1.6, 1.1) cell (row 4, col 6): 2 dust.
    ts, state = ENV.step_env(jax.random.key(0), state_at(1.1, 1.1, 0.0), FORWARD, PARAMS)
    assert float(state.x) == pytest.approx(1.6) and float(state.y) == pytest.approx(1.1)
    assert float(ts.reward) == 2.0
    cleaned = np.argwhere(~cells(state))
    np.testing.assert_array_equal(cleaned, [[4, 5], [4, 6]])
    assert not bool(state.bumped) and not bool(ts.terminated)


def test_wall_stops_the_robot():
    # Heading north from y = 4.6: the centre may reach 5 - 0.17 = 4.83, i.e. 0.23 of the 0.5 m move.
    ts, state = ENV.step_env(jax.random.key(0), state_at(2.0, 4.6, math.pi / 2), FORWARD, PARAMS)
    assert float(state.y) == pytest.approx(4.83, abs=1e-5) and float(state.x) == pytest.approx(2.0, abs=1e-5)
    assert bool(state.bumped) and float(ts.obs[4]) == 1.0
    # Pressed against the wall it stays put: another forward step moves nothing and picks up nothing.
    ts, again = ENV.step_env(jax.random.key(1), state, FORWARD, PARAMS)
    assert float(again.y) == pytest.approx(4.83, abs=1e-5) and float(ts.reward) == 0.0 and bool(again.bumped)


def test_rotation_turns_in_place_and_cleans_its_cell():
    # A turn of +1 rad from heading 3: 3 + 1 = 4 > pi wraps to 4 - 2 pi = -2.283; the position stays.
    ts, state = ENV.step_env(jax.random.key(0), state_at(1.1, 1.1, 3.0), jnp.array([0.0, 1.0]), PARAMS)
    assert float(state.heading) == pytest.approx(4.0 - 2 * math.pi, abs=1e-5)
    assert (float(state.x), float(state.y)) == pytest.approx((1.1, 1.1))
    assert float(ts.reward) == 1.0  # the cell it turns in: (row 4, col 4)
    assert not cells(state)[4, 4]


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_dust_conserved_and_robot_stays_in_room():
    settings = [(0.9, 3.0), (0.5, 0.5), (1.0, 0.0)]
    for key, (p, r) in zip(jax.random.split(jax.random.key(3), 3), settings, strict=True):
        states, rewards = ENV.trajectory(vacuum_policy(p, r), key)
        remaining = cells(states).sum(axis=(1, 2)) * float(PARAMS.dust_per_cell)  # [T + 1]
        picked_so_far = np.concatenate([[0.0], np.cumsum(np.asarray(rewards))])
        np.testing.assert_allclose(picked_so_far + remaining, 400.0)  # 20 * 20 cells, 1 unit each
        low, high = 0.17, 5.0 - 0.17
        for coordinate in (np.asarray(states.x), np.asarray(states.y)):
            assert coordinate.min() >= low - 1e-6 and coordinate.max() <= high + 1e-6


def test_p_one_never_turns_and_p_zero_never_moves():
    states, _ = ENV.trajectory(vacuum_policy(1.0, math.pi), jax.random.key(5))
    assert np.ptp(np.asarray(states.heading)) == 0.0  # one heading all episode
    states, rewards = ENV.trajectory(vacuum_policy(0.0, math.pi), jax.random.key(6))
    assert np.ptp(np.asarray(states.x)) == 0.0 and np.ptp(np.asarray(states.y)) == 0.0
    assert float(np.asarray(rewards).sum()) == 1.0  # only the cell it started on


def test_render_frame_and_path():
    _, state = ENV.reset(jax.random.key(0))
    frame = ENV.render_frame(state, PARAMS)
    assert frame.dtype == np.uint8 and frame.shape == (240, 240, 3)
    states, _ = ENV.trajectory(vacuum_policy(0.8, 2.0), jax.random.key(1))
    image = render_path(states, PARAMS)
    assert image.shape == (240, 240, 3) and image.dtype == np.uint8
    assert (image == [40, 110, 220]).all(axis=-1).sum() > 500  # the blue path is drawn
    assert not np.array_equal(image, frame)


def test_step_auto_resets_after_thirty_minutes():
    # The 900th step (time 899 -> 900) truncates; step returns the next episode's first state: a clean slate.
    dirty = jnp.zeros((20, 20), bool)  # everything vacuumed
    state = state_at(2.0, 2.0, 0.0, dirty).replace(time=jnp.int32(899))
    ts, after = ENV.step(jax.random.key(4), state, FORWARD, PARAMS)
    assert bool(ts.truncated) and not bool(ts.terminated) and float(ts.reward) == 0.0
    assert int(after.time) == 0 and cells(after).all()
    assert float(ts.final_obs[0]) == pytest.approx(2.5 / 5.0)  # moved 0.5 m east before the reset
    np.testing.assert_allclose(ts.obs, ENV.get_obs(after, PARAMS))
    # One step earlier nothing resets.
    ts, after = ENV.step(jax.random.key(4), state.replace(time=jnp.int32(898)), FORWARD, PARAMS)
    assert not bool(ts.truncated) and int(after.time) == 899 and float(after.x) == pytest.approx(2.5)


def test_cells_pack_into_bits():
    # 20 * 20 = 400 cells -> ceil(400 / 32) = 13 words; cell (row 1, column 3) is index 23: bit 23 of word 0,
    # cell (19, 19) is index 399 = 12 * 32 + 15: bit 15 of word 12.
    grid = np.zeros((20, 20), bool)
    grid[1, 3] = grid[19, 19] = True
    words = np.asarray(pack_cells(grid))
    assert words.shape == (13,) and words.dtype == np.uint32
    assert words[0] == 1 << 23 and words[12] == 1 << 15 and words[1:12].sum() == 0
    random = np.random.default_rng(0).random((3, 20, 20)) < 0.5
    np.testing.assert_array_equal(unpack_cells(np.asarray(pack_cells(random)), 20), random)
    assert np.asarray(pack_cells(np.ones((20, 20), bool)))[12] == (1 << 16) - 1  # only 400 - 384 = 16 bits
