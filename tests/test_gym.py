"""Gymnasium both ways: agentax's JAX envs inside Gymnasium, and Gymnasium's envs through agentax."""

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import agentax  # noqa: F401  (registers agentax/ID in Gymnasium)
from agentax.envs import JAX_ENVS, Box, CartPole, Discrete, GymnasiumEnv, make
from agentax.envs.gym import from_gymnasium_space, to_gymnasium_space
from agentax.errors import UsageError


@pytest.mark.timeout(120)
@pytest.mark.parametrize("env_id", sorted(k for k in JAX_ENVS if "/" not in k))  # gymnax/ ids: gymnax's own
def test_registered_env_passes_gymnasiums_checker(env_id):
    env = gymnasium.make(f"agentax/{env_id}")
    with warnings.catch_warnings(record=True) as caught:  # check_env reports soft findings as warnings
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    # Soft findings that Gymnasium's own envs share: CartPole's unbounded velocities (-inf, inf), and
    # the advice to normalise Box action spaces (the vacuum's rotation angle is in [-pi, pi]).
    accepted = ("infinity", "we recommend using a symmetric and normalized space")
    assert [str(w.message) for w in caught if not any(text in str(w.message) for text in accepted)] == []
    obs, info = env.reset(seed=7)
    assert env.observation_space.contains(obs) and info == {}
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert env.observation_space.contains(obs)
    assert type(reward) is float and type(terminated) is bool and type(truncated) is bool


@pytest.mark.parametrize("env_id", ["CartPole-v1", "Vacuum-v0"])
def test_rgb_array_rendering(env_id):
    env = gymnasium.make(f"agentax/{env_id}", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 1  # something is drawn


def test_seeded_reset_is_reproducible():
    env = gymnasium.make("agentax/CartPole-v1")
    first, _ = env.reset(seed=123)
    second, _ = env.reset(seed=123)
    other, _ = env.reset(seed=124)
    np.testing.assert_array_equal(first, second)
    assert not np.array_equal(first, other)
    assert np.all(np.abs(first) <= 0.05)  # Gymnasium's initial state: uniform(-0.05, 0.05)


def _sync(theirs, ours):
    """Put Gymnasium's CartPole into the state of our wrapped one (float64 copy of our float32 state)."""
    state = ours.unwrapped.state
    theirs.unwrapped.state = np.array([state.x, state.x_dot, state.theta, state.theta_dot], np.float64)


# Gymnasium integrates in float64, we in float32: the rounding difference grows through the unstable
# dynamics (about e^(4.4 t) for a falling pole), so Gymnasium is re-synchronised to our state before
# every step and each step's result compared; its TimeLimit counts steps on its own.


@pytest.mark.parametrize("version", ["v0", "v1"])
def test_episodes_follow_gymnasiums_cartpole(version):
    # Random actions: the same observations (to float32 rounding), rewards and terminations, step
    # for step, over 20 episodes.
    ours, theirs = gymnasium.make(f"agentax/CartPole-{version}"), gymnasium.make(f"CartPole-{version}")
    rng, lengths = np.random.default_rng(0), []
    for episode in range(20):
        ours.reset(seed=episode)
        theirs.reset(seed=episode)
        for t in range(1, 1000):
            action = int(rng.integers(2))
            _sync(theirs, ours)
            obs, reward, terminated, truncated, _ = ours.step(action)
            obs_ref, reward_ref, terminated_ref, truncated_ref, _ = theirs.step(action)
            np.testing.assert_allclose(obs, obs_ref, rtol=1e-5, atol=1e-6)
            assert (reward, terminated, truncated) == (reward_ref, terminated_ref, truncated_ref)
            if terminated or truncated:
                lengths.append(t)
                break
    assert len(lengths) == 20 and min(lengths) >= 8 and max(lengths) < 200  # random play topples the pole


@pytest.mark.parametrize(("version", "limit"), [("v0", 200), ("v1", 500)])
def test_time_limit_truncates_like_gymnasium(version, limit):
    # A balancing controller (push toward where the pole is falling) never drops the pole, so the
    # episode ends by the time limit alone: truncated, not terminated, at step 200 (v0) / 500 (v1),
    # exactly where Gymnasium's TimeLimit cuts.
    ours, theirs = gymnasium.make(f"agentax/CartPole-{version}"), gymnasium.make(f"CartPole-{version}")
    obs, _ = ours.reset(seed=3)
    theirs.reset(seed=3)
    for t in range(1, limit + 1):
        action = int(obs[2] + 0.5 * obs[3] > 0)
        _sync(theirs, ours)
        obs, _, terminated, truncated, _ = ours.step(action)
        obs_ref, _, terminated_ref, truncated_ref, _ = theirs.step(action)
        np.testing.assert_allclose(obs, obs_ref, rtol=1e-5, atol=1e-6)
        assert (terminated, truncated) == (terminated_ref, truncated_ref) == (False, t == limit)


def test_make_returns_jax_where_it_can_and_gymnasium_otherwise():
    assert isinstance(make("CartPole-v1"), CartPole)
    assert make("agentax/CartPole-v0").max_steps_in_episode == 200
    for env_id, obs_space, action_space in [
        ("MountainCar-v0", Box, Discrete(3)),
        ("Acrobot-v1", Box, Discrete(3)),
        ("FrozenLake-v1", Box, Discrete(4)),  # its Discrete(16) states packed into a vector [1]
    ]:
        env = make(env_id)
        assert isinstance(env, GymnasiumEnv) and env.id == env_id and env.num_envs == 1
        assert isinstance(env.observation_space(), obs_space) and env.action_space() == action_space
        env.close()


def test_unknown_env_id_names_close_matches_and_agentax_ids():
    with pytest.raises(UsageError, match="did you mean CartPole-v1") as error:
        make("CartPol-v1")
    assert "CartPole-v0" in str(error.value) and "\n" not in str(error.value)
    with pytest.raises(UsageError, match=r"choose from agentax's JAX envs \(CartPole-v0, CartPole-v1"):
        make("NoSuchEnv-v9")


def test_gymnasium_env_steps_like_a_plain_gymnasium_loop():
    # Sub-env i is seeded seed + i; when an episode ends, obs is the next episode's first
    # observation and final_obs the one really reached -- checked against single Gymnasium envs
    # stepped by hand (reset without a seed continues the env's random stream).
    env = GymnasiumEnv("CartPole-v1", num_envs=2)
    refs = [gymnasium.make("CartPole-v1") for _ in range(2)]
    obs = env.reset(seed=10)
    np.testing.assert_array_equal(obs, np.stack([ref.reset(seed=10 + i)[0] for i, ref in enumerate(refs)]))
    rng, episodes_ended = np.random.default_rng(1), 0
    for _ in range(150):
        actions = rng.integers(2, size=2)
        ts = env.step(actions)
        for i, ref in enumerate(refs):
            final, reward, terminated, truncated, _ = ref.step(int(actions[i]))
            np.testing.assert_array_equal(ts.final_obs[i], final)
            assert (ts.reward[i], ts.terminated[i], ts.truncated[i]) == (reward, terminated, truncated)
            expected_obs = ref.reset()[0] if terminated or truncated else final
            np.testing.assert_array_equal(ts.obs[i], expected_obs)
            episodes_ended += terminated or truncated
    assert episodes_ended >= 10 and ts.reward.dtype == np.float32
    env.close()


def test_gymnasium_env_wraps_a_single_env_and_checks_a_vector_envs_autoreset_mode():
    env = GymnasiumEnv(gymnasium.make("FrozenLake-v1"))
    assert env.id == "FrozenLake-v1" and env.num_envs == 1
    assert env.original_space == Discrete(16) and env.reset(seed=0).shape == (1, 1)
    next_step = gymnasium.make_vec("CartPole-v1", 2, vectorization_mode="sync")
    with pytest.raises(UsageError, match="SAME_STEP"):
        GymnasiumEnv(next_step)


def test_space_conversions_round_trip():
    box = gymnasium.spaces.Box(-1.0, 2.0, (3,), np.float32)
    ours = from_gymnasium_space(box)
    assert ours.shape == (3,) and np.all(ours.low == -1.0) and np.all(ours.high == 2.0)
    assert to_gymnasium_space(ours) == box
    assert from_gymnasium_space(gymnasium.spaces.Discrete(5)) == Discrete(5)
    assert to_gymnasium_space(Discrete(5)) == gymnasium.spaces.Discrete(5)
    multi = gymnasium.spaces.MultiDiscrete([2, 3])
    assert to_gymnasium_space(from_gymnasium_space(multi)) == multi
    blackjack = gymnasium.spaces.Tuple((gymnasium.spaces.Discrete(32), gymnasium.spaces.Discrete(11)))
    assert to_gymnasium_space(from_gymnasium_space(blackjack)) == blackjack
    with pytest.raises(
        UsageError, match=r"Text\(1, 4, .*\) is no space agentax takes; it takes Box, Discrete"
    ):
        from_gymnasium_space(gymnasium.spaces.Text(4))
