"""JAX CartPole against Gymnasium's own ``CartPole-v0`` / ``CartPole-v1``, step for step.

How the trajectories are compared, and why. Gymnasium integrates in float64 and returns float32
observations; agentax integrates in float32. A falling pole is unstable (rounding differences grow
about e^(4.4 t), t in seconds), so two long episodes from the same start drift apart however
faithful the physics. Hence two checks:

* **synced, every transition** (``test_every_step_matches_gymnasium``): Gymnasium plays 100
  episodes per version with a mix of controllers (some balance until the time limit, some drift off
  the track, some topple the pole); each transition's start state (float64, cast to float32), step
  count and action go through agentax's ``step_env`` in one vmapped call, and the next observation
  (float32 tolerance), reward, ``terminated`` and ``truncated`` must equal Gymnasium's.
* **free-running, whole episodes** (``test_random_episodes_match_from_the_same_start``): from the
  same start and with the same random actions, short episodes stay within 1e-4 of Gymnasium's and
  end on the same step, without any re-synchronisation.
"""

from __future__ import annotations

import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.extend.random import threefry_2x32

from agentax.envs.cartpole import CartPole, CartPoleState, cartpole_v0, cartpole_v1
from agentax.envs.core import threefry2x32, uniform4

pytestmark = pytest.mark.timeout(120)
VERSIONS = {"v0": (cartpole_v0, 200), "v1": (cartpole_v1, 500)}


def gymnasium_cartpole(version: str) -> gymnasium.Env:
    with warnings.catch_warnings():  # "CartPole-v0 is out of date"
        warnings.simplefilter("ignore")
        return gymnasium.make(f"CartPole-{version}")


def controller(kind: int, obs: np.ndarray, rng: np.random.Generator) -> int:
    """Five ways to play: 0-1 balance until the time limit, 2 drifts off the track, 3-4 topple."""
    x, x_dot, theta, theta_dot = obs
    if kind == 0:  # the basic policy plus a PD term and a pull back to the centre
        return int(theta + 0.5 * theta_dot + 0.01 * x + 0.05 * x_dot > 0)
    if kind == 1:  # the basic policy plus a PD term, with 10 % random actions
        return int(theta + 0.5 * theta_dot > 0) if rng.random() > 0.1 else int(rng.integers(2))
    if kind == 2:  # holds the pole tilted, so the cart accelerates until it leaves the track
        return int(theta + 0.5 * theta_dot > 0.08)
    if kind == 3:  # the lecture's basic policy
        return int(theta > 0)
    return int(rng.integers(2))


def play_gymnasium(version: str, num_episodes: int = 100) -> dict[str, np.ndarray]:
    """Every transition of ``num_episodes`` Gymnasium episodes, as arrays over transitions."""
    env, limit = gymnasium_cartpole(version), VERSIONS[version][1]
    rng = np.random.default_rng(0)
    rows = {key: [] for key in ("state", "time", "action", "obs", "reward", "terminated", "truncated")}
    for episode in range(num_episodes):
        obs, _ = env.reset(seed=episode)
        for t in range(limit):
            if episode == 0 and t == limit - 1:  # about to fall on the very last step: both flags at once
                obs = np.array([0.0, 0.0, 0.2, 1.0])
                env.unwrapped.state = obs
            state = np.array(env.unwrapped.state, np.float64)
            action = controller(episode % 5, obs, rng)
            obs, reward, terminated, truncated, _ = env.step(action)
            for key, value in zip(rows, (state, t, action, obs, reward, terminated, truncated), strict=True):
                rows[key].append(value)
            if terminated or truncated:
                break
    env.close()
    return {key: np.array(value) for key, value in rows.items()}


@pytest.mark.parametrize("version", VERSIONS)
def test_every_step_matches_gymnasium(version):
    env, limit = VERSIONS[version][0](), VERSIONS[version][1]
    ref = play_gymnasium(version)
    state = jnp.asarray(ref["state"], jnp.float32)  # [transitions, 4]
    batch = CartPoleState(
        state[:, 0], state[:, 1], state[:, 2], state[:, 3], jnp.asarray(ref["time"], jnp.int32)
    )
    step = jax.jit(jax.vmap(env.step_env, in_axes=(None, 0, 0, None)))
    ts, _ = step(jax.random.key(0), batch, jnp.asarray(ref["action"]), env.default_params())

    np.testing.assert_allclose(ts.obs, ref["obs"], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(ts.reward, ref["reward"])
    np.testing.assert_array_equal(ts.terminated, ref["terminated"])
    np.testing.assert_array_equal(ts.truncated, ref["truncated"])

    # The data covers every way an episode ends, and the flags differ where they should.
    ends = ref["terminated"] | ref["truncated"]
    assert ends.sum() == 100  # every episode ended within the time limit
    off_track = ref["terminated"] & (np.abs(ref["obs"][:, 0]) > 2.4)
    assert off_track.sum() >= 15 and (ref["terminated"] & ~off_track).sum() >= 40
    time_limit = ref["truncated"] & ~ref["terminated"]
    assert time_limit.sum() >= 30
    assert np.all(ref["time"][ref["truncated"]] == limit - 1)  # truncated exactly on step 200 / 500 ...
    assert not ref["truncated"][ref["time"] < limit - 1].any()  # ... and never before
    assert (ref["terminated"] & ref["truncated"]).sum() == 1  # the constructed fall on the last step


@pytest.mark.slow
@pytest.mark.parametrize("version", VERSIONS)
def test_random_episodes_match_from_the_same_start(version):
    env, num_episodes, horizon = VERSIONS[version][0](), 100, 120
    params = env.default_params()
    _, starts = jax.vmap(env.reset, in_axes=(0, None))(
        jax.random.split(jax.random.key(1), num_episodes), params
    )
    actions = np.random.default_rng(1).integers(0, 2, (num_episodes, horizon))

    def episode(start, actions):
        def body(state, action):
            ts, state = env.step_env(jax.random.key(0), state, action, params)
            return state, (ts.obs, ts.terminated, ts.truncated)

        return jax.lax.scan(body, start, actions)[1]

    obs, terminated, truncated = jax.jit(jax.vmap(episode))(starts, jnp.asarray(actions))
    gym_env, lengths = gymnasium_cartpole(version), []
    for i in range(num_episodes):
        gym_env.reset(seed=i)
        start = np.array([starts.x[i], starts.x_dot[i], starts.theta[i], starts.theta_dot[i]], np.float64)
        gym_env.unwrapped.state = start  # the very same start: float32 values are exact in float64
        for t in range(horizon):
            obs_ref, reward, terminated_ref, truncated_ref, _ = gym_env.step(int(actions[i, t]))
            np.testing.assert_allclose(obs[i, t], obs_ref, atol=1e-4)
            assert (bool(terminated[i, t]), bool(truncated[i, t]), reward) == (
                terminated_ref,
                truncated_ref,
                1.0,
            )
            if terminated_ref:
                lengths.append(t + 1)
                break
    assert len(lengths) == num_episodes and 8 <= min(lengths) and max(lengths) < horizon


def test_initial_states_are_distributed_as_gymnasiums():
    # Uniform on [-0.05, 0.05]^4: against 20,000 of Gymnasium's own starts, per component, the
    # two-sample Kolmogorov-Smirnov distance stays below its 0.1 % critical value
    # 1.95 * sqrt(2 / 20000) = 0.0195; mean 0 and variance 0.1^2 / 12 = 8.33e-4.
    n = 20_000
    obs, state = jax.jit(jax.vmap(cartpole_v1().reset))(jax.random.split(jax.random.key(2), n))
    obs = np.asarray(obs, np.float64)
    gym_vec = gymnasium.make_vec("CartPole-v1", num_envs=n, vectorization_mode="vector_entry_point")
    theirs, _ = gym_vec.reset(seed=2)
    gym_vec.close()
    assert np.all(np.abs(obs) <= 0.05) and np.all(state.time == 0)
    np.testing.assert_array_equal(obs[:, 2], state.theta)
    grid = np.linspace(-0.05, 0.05, 201)
    for component in range(4):
        ours_cdf = np.searchsorted(np.sort(obs[:, component]), grid, side="right") / n
        theirs_cdf = np.searchsorted(np.sort(theirs[:, component]), grid, side="right") / n
        assert np.max(np.abs(ours_cdf - theirs_cdf)) < 0.0195
    np.testing.assert_allclose(obs.mean(0), 0.0, atol=1e-3)  # 5 standard errors: 0.0289 / sqrt(n) = 2e-4
    np.testing.assert_allclose(obs.var(0), 0.01 / 12, rtol=0.03)
    assert len(np.unique(obs[:, 0])) > 0.99 * n  # full float resolution, no coarse grid


@pytest.mark.slow
def test_start_values_are_jaxs_own_threefry_draws():
    # The unrolled hash is bit for bit jax's Threefry-2x32, on 1,000 random keys and counters ...
    words = jax.random.bits(jax.random.key(6), (4, 1000))
    expected = jax.vmap(lambda k0, k1, x0, x1: threefry_2x32((k0, k1), jnp.stack([x0, x1])))(*words)
    np.testing.assert_array_equal(jnp.stack(jax.jit(threefry2x32)(*words), axis=1), expected)
    # ... so uniform4 draws what jax.random.uniform draws with non-partitionable Threefry, and other
    # key implementations fall back to jax.random.uniform itself.
    for key in jax.random.split(jax.random.key(7), 5):
        with jax.threefry_partitionable(False):
            expected = jax.random.uniform(key, (4,), jnp.float32, -0.05, 0.05)
        np.testing.assert_array_equal(jax.jit(uniform4, static_argnums=(1, 2))(key, -0.05, 0.05), expected)
    rbg = jax.random.key(8, impl="rbg")
    np.testing.assert_array_equal(
        uniform4(rbg, 0.0, 1.0), jax.random.uniform(rbg, (4,), jnp.float32, 0.0, 1.0)
    )


def test_spaces_and_limits_match_gymnasium():
    for version, (make, limit) in VERSIONS.items():
        ours, theirs = make(), gymnasium_cartpole(version)
        obs_space = ours.observation_space()
        assert obs_space.shape == theirs.observation_space.shape == (4,)
        np.testing.assert_array_equal(obs_space.low, theirs.observation_space.low)
        np.testing.assert_array_equal(obs_space.high, theirs.observation_space.high)
        assert np.dtype(obs_space.dtype) == theirs.observation_space.dtype == np.float32
        assert ours.action_space().n == theirs.action_space.n == 2
        assert ours.max_steps_in_episode == theirs.spec.max_episode_steps == limit
        assert ours.reward_threshold == theirs.spec.reward_threshold
        assert ours.id == f"CartPole-{version}"


def _state(x, x_dot, theta, theta_dot, time):
    return CartPoleState(*(jnp.float32(v) for v in (x, x_dot, theta, theta_dot)), jnp.int32(time))


def test_auto_reset_after_termination_and_truncation():
    env = cartpole_v0()
    key = jax.random.key(3)
    step = jax.jit(env.step)
    # Falling: theta 0.2 + 0.02 * 1.0 = 0.22 > 0.2094 terminates.
    ts, state = step(key, _state(0.1, 0.0, 0.2, 1.0, 7), 1)
    assert bool(ts.terminated) and not bool(ts.truncated) and bool(ts.done) and float(ts.reward) == 1.0
    reached, _ = env.step_env(key, _state(0.1, 0.0, 0.2, 1.0, 7), jnp.int32(1), env.default_params())
    np.testing.assert_allclose(ts.final_obs, reached.obs, rtol=1e-6)  # jit vs op-by-op: 1 ulp
    assert float(ts.final_obs[2]) == pytest.approx(0.22)
    assert np.all(np.abs(np.asarray(ts.obs)) <= 0.05) and int(state.time) == 0  # a fresh start ...
    np.testing.assert_array_equal(ts.obs, env.get_obs(state))  # ... that the returned state holds
    # Balanced on step 199 of 200: truncated, not terminated; the cart moved 0.02 * 0.5 = 0.01.
    ts, state = step(key, _state(0.3, 0.5, 0.0, 0.0, 199), 1)
    assert bool(ts.truncated) and not bool(ts.terminated)
    assert float(ts.final_obs[0]) == pytest.approx(0.31)
    assert np.all(np.abs(np.asarray(ts.obs)) <= 0.05) and int(state.time) == 0
    # Not done: the observation is the reached one and the clock runs on.
    ts, state = step(key, _state(0.3, 0.5, 0.0, 0.0, 10), 1)
    assert not bool(ts.done) and int(state.time) == 11
    np.testing.assert_array_equal(ts.obs, ts.final_obs)
    assert float(ts.obs[0]) == pytest.approx(0.31)
    # Different keys, different fresh starts.
    starts = {
        tuple(np.asarray(step(k, _state(0, 0, 0.25, 0, 0), 0)[0].obs)) for k in jax.random.split(key, 8)
    }
    assert len(starts) == 8


def _random_batch(n: int, seed: int):
    env = cartpole_v1()
    key_reset, key_step, key_action, key_time = jax.random.split(jax.random.key(seed), 4)
    _, state = jax.vmap(env.reset)(jax.random.split(key_reset, n))
    state = state.replace(  # spread so that some terminate, some truncate, most go on
        theta=state.theta * 5.0, time=jax.random.randint(key_time, (n,), 0, env.max_steps_in_episode)
    )
    state = state.replace(time=state.time.at[:4].set(env.max_steps_in_episode - 1))
    actions = jax.random.bernoulli(key_action, 0.5, (n,)).astype(jnp.int32)
    return env, jax.random.split(key_step, n), state, actions


@pytest.mark.slow
def test_vmapped_batch_equals_single_envs():
    env, keys, state, actions = _random_batch(64, seed=4)
    ts, next_state = jax.jit(jax.vmap(env.step))(keys, state, actions)
    assert ts.done.any() and not ts.done.all()
    single = jax.jit(env.step)
    for i in range(0, 64, 9):
        ts_i, state_i = single(keys[i], jax.tree.map(lambda a, i=i: a[i], state), actions[i])
        for field in ("obs", "reward", "terminated", "truncated", "final_obs"):
            np.testing.assert_allclose(getattr(ts, field)[i], getattr(ts_i, field), rtol=1e-6, atol=1e-7)
        for a, b in zip(jax.tree.leaves(next_state), jax.tree.leaves(state_i), strict=True):
            np.testing.assert_allclose(a[i], b, rtol=1e-6, atol=1e-7)


@pytest.mark.slow
def test_jit_equals_no_jit():
    env, keys, state, actions = _random_batch(8, seed=5)
    compiled_step = jax.jit(env.step)
    for i in range(8):
        state_i = jax.tree.map(lambda a, i=i: a[i], state)
        plain = env.step(keys[i], state_i, actions[i])
        compiled = compiled_step(keys[i], state_i, actions[i])
        for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(compiled), strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    obs_plain, _ = env.reset(keys[0])
    np.testing.assert_allclose(obs_plain, jax.jit(env.reset)(keys[0])[0], rtol=1e-6)


def test_params_change_the_physics():
    # Stronger gravity makes the pole fall faster: theta_acc = g sin(theta) / ... with the push off.
    env = CartPole()
    state = _state(0.0, 0.0, 0.1, 0.0, 0)
    params = env.default_params()
    ts_earth, _ = env.step_env(jax.random.key(0), state, jnp.int32(1), params)
    ts_heavy, _ = env.step_env(jax.random.key(0), state, jnp.int32(1), params.replace(gravity=20.0))
    assert float(ts_heavy.obs[3]) > float(ts_earth.obs[3])
