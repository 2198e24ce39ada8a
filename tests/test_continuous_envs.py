"""JAX Pendulum-v1 and MountainCarContinuous-v0 against Gymnasium's own, step for step.

As for CartPole (tests/test_cartpole.py): **synced**, every transition of Gymnasium episodes
(random actions, out-of-bound ones included, so the clipping is checked) goes through agentax's
``step_env`` from Gymnasium's own start state in one vmapped call, and the next observation
(float32 tolerance), reward, ``terminated`` and ``truncated`` must equal Gymnasium's; and
**free-running**, agentax's whole episode from Gymnasium's reset state with the same actions.
Then the envs' reset distributions, spaces, and a short SAC run vmapped over seeds on the JAX
Pendulum.
"""

from __future__ import annotations

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agentax
from agentax.envs import JAX_ENVS, make
from agentax.envs.pendulum import MountainCarContinuous, MountainCarState, Pendulum, PendulumState

pytestmark = pytest.mark.timeout(180)


def state_of(env_id: str, raw, time):
    """agentax's state for Gymnasium's ``env.unwrapped.state`` (``[2]``, or ``[T, 2]`` with ``time [T]``)."""
    raw = jnp.asarray(raw, jnp.float32)
    cls = PendulumState if env_id == "Pendulum-v1" else MountainCarState
    return cls(raw[..., 0], raw[..., 1], jnp.asarray(time, jnp.int32))


def play_gymnasium(env_id: str, episodes: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every transition of ``episodes`` Gymnasium episodes under random actions in twice the bounds."""
    env = gymnasium.make(env_id)
    high = float(env.action_space.high[0])
    rows = {k: [] for k in ("state", "time", "action", "obs", "reward", "terminated", "truncated")}
    for episode in range(episodes):
        env.reset(seed=episode)
        time, done = 0, False
        while not done:
            action = rng.uniform(-2 * high, 2 * high, (1,)).astype(np.float32)
            rows["state"].append(np.array(env.unwrapped.state, np.float64))
            rows["time"].append(time)
            obs, reward, terminated, truncated, _ = env.step(action)
            for key, value in (("action", action), ("obs", obs), ("reward", reward)):
                rows[key].append(value)
            rows["terminated"].append(terminated)
            rows["truncated"].append(truncated)
            time, done = time + 1, terminated or truncated
    env.close()
    return {k: np.asarray(v) for k, v in rows.items()}


@pytest.mark.parametrize("env_id, episodes", [("Pendulum-v1", 20), ("MountainCarContinuous-v0", 4)])
def test_every_step_matches_gymnasium(env_id, episodes):
    env = JAX_ENVS[env_id]()
    seen = play_gymnasium(env_id, episodes, np.random.default_rng(0))
    states = state_of(env_id, seen["state"], seen["time"])

    def one(state, action):
        return env.step_env(jax.random.key(0), state, action, env.default_params())[0]

    steps = jax.jit(jax.vmap(one))(states, jnp.asarray(seen["action"]))
    np.testing.assert_allclose(np.asarray(steps.obs), seen["obs"], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(steps.reward), seen["reward"], rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(np.asarray(steps.terminated), seen["terminated"])
    np.testing.assert_array_equal(np.asarray(steps.truncated), seen["truncated"])
    assert seen["truncated"].sum() + seen["terminated"].sum() == episodes
    if env_id == "Pendulum-v1":
        assert len(seen["reward"]) == 200 * episodes  # no termination, the time limit only


def test_mountain_car_reaches_the_flag_as_gymnasium_does():
    """A bang-bang controller (push with the velocity) reaches the flag: agentax's episode from
    Gymnasium's start ends on the same step with the same +100 reward."""
    env, gym_env = MountainCarContinuous(), gymnasium.make("MountainCarContinuous-v0")
    obs, _ = gym_env.reset(seed=3)
    state = state_of("MountainCarContinuous-v0", gym_env.unwrapped.state, 0)
    step = jax.jit(lambda s, a: env.step_env(jax.random.key(0), s, a, env.default_params()))
    for _step in range(999):
        action = np.array([1.0 if obs[1] >= 0 else -1.0], np.float32)
        obs, reward, terminated, truncated, _ = gym_env.step(action)
        time_step, state = step(state, jnp.asarray(action))
        np.testing.assert_allclose(np.asarray(time_step.obs), obs, atol=1e-4)
        assert bool(time_step.terminated) == terminated
        if terminated:
            break
    assert (
        terminated
        and 50 < int(state.time) < 400
        and np.isclose(float(time_step.reward), 100 - 0.1, atol=1e-5)
    )


def test_free_running_pendulum_episode_matches_from_the_same_start():
    env, gym_env = Pendulum(), gymnasium.make("Pendulum-v1")
    gym_env.reset(seed=7)
    state = state_of("Pendulum-v1", gym_env.unwrapped.state, 0)
    actions = np.random.default_rng(1).uniform(-2, 2, (200, 1)).astype(np.float32)

    def body(state, action):
        time_step, state = env.step_env(jax.random.key(0), state, action, env.default_params())
        return state, (time_step.obs, time_step.reward, time_step.truncated)

    _, (obs, reward, truncated) = jax.jit(lambda s, a: jax.lax.scan(body, s, a))(state, jnp.asarray(actions))
    gym_rows = [gym_env.step(a)[:4] for a in actions]
    np.testing.assert_allclose(np.asarray(obs), np.stack([r[0] for r in gym_rows]), atol=1e-3)
    np.testing.assert_allclose(np.asarray(reward), [r[1] for r in gym_rows], rtol=1e-3, atol=1e-3)
    assert np.flatnonzero(np.asarray(truncated)).tolist() == [199] and gym_rows[-1][3]


@pytest.mark.slow
def test_resets_spaces_and_registration():
    pendulum, car = make("Pendulum-v1"), make("MountainCarContinuous-v0")
    keys = jax.random.split(jax.random.key(0), 4000)
    _, states = jax.vmap(pendulum.reset)(keys)
    theta, theta_dot = np.asarray(states.theta), np.asarray(states.theta_dot)
    assert -np.pi <= theta.min() < -3.0 and 3.0 < theta.max() <= np.pi
    assert -1 <= theta_dot.min() < -0.99 and 0.99 < theta_dot.max() <= 1
    _, states = jax.vmap(car.reset)(keys)
    position = np.asarray(states.position)
    assert -0.6 <= position.min() < -0.599 and -0.401 < position.max() <= -0.4
    assert not np.asarray(states.velocity).any()
    for env, gym_id in ((pendulum, "Pendulum-v1"), (car, "MountainCarContinuous-v0")):
        gym_env = gymnasium.make(gym_id)
        pairs = (
            (env.action_space(), gym_env.action_space),
            (env.observation_space(), gym_env.observation_space),
        )
        for ours, theirs in pairs:
            assert ours.shape == theirs.shape
            np.testing.assert_array_equal(ours.low, theirs.low)
            np.testing.assert_array_equal(ours.high, theirs.high)
        assert env.reward_threshold == gym_env.spec.reward_threshold


@pytest.mark.long  # make test-long; `make bench`'s sac rows show it on 8 seeds, tutorial 09 in make test
@pytest.mark.slow
def test_sac_trains_the_jax_pendulum_on_the_compiled_runner_over_seeds(tmp_path):
    """``agentax.train("sac", env="Pendulum-v1")`` picks the compiled runner and vmaps 2 seeds."""
    run = agentax.train(
        "sac", env="Pendulum-v1", seeds=2, total_steps=600, learning_starts=200, hidden=(16, 16),
        out=tmp_path / "run", progress=False,
    )  # fmt: skip
    per_seed = [seed["mean_return"] for seed in run.result.eval["per_seed"]]
    assert run.runner_kind == "compiled" and len(per_seed) == 2 and np.isfinite(per_seed).all()
