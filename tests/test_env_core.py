"""The env protocol itself (auto-reset, ``TimeStep.done``, spaces) on a tiny hand-made env.

``Countdown``: the state is a counter started uniformly in {1, 2, 3}; action 1 counts down by one
(reward 1), action 0 waits (reward 0); the episode terminates at 0 and is truncated after
``max_steps_in_episode`` steps. Every expected value below follows from those three lines.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from agentax.envs.core import Box, Discrete, Environment, TimeStep

pytestmark = pytest.mark.timeout(60)


@struct.dataclass
class CountdownParams:
    max_steps_in_episode: int = 5


@struct.dataclass
class CountdownState:
    remaining: jax.Array
    time: jax.Array


class Countdown(Environment):
    id = "Countdown-v0"

    def default_params(self) -> CountdownParams:
        return CountdownParams()

    def reset_env(self, key, params):
        state = CountdownState(jax.random.randint(key, (), 1, 4), jnp.int32(0))
        return self.get_obs(state), state

    def step_env(self, key, state, action, params):
        state = CountdownState(state.remaining - action, state.time + 1)
        obs = self.get_obs(state)
        terminated, truncated = state.remaining == 0, state.time >= params.max_steps_in_episode
        return TimeStep(obs, action.astype(jnp.float32), terminated, truncated, obs), state

    @staticmethod
    def get_obs(state):
        return jnp.array([state.remaining], jnp.float32)

    def observation_space(self, params=None):
        return Box(0.0, 3.0, (1,))

    def action_space(self, params=None):
        return Discrete(2)


def _state(remaining, time):
    return CountdownState(jnp.int32(remaining), jnp.int32(time))


ENV = Countdown()
STEP = jax.jit(ENV.step)


@pytest.mark.parametrize(
    ("terminated", "truncated", "done"),
    [(False, False, False), (True, False, True), (False, True, True), (True, True, True)],
)
def test_done_is_terminated_or_truncated(terminated, truncated, done):
    ts = TimeStep(jnp.zeros(1), jnp.float32(0), jnp.bool_(terminated), jnp.bool_(truncated), jnp.zeros(1))
    assert bool(ts.done) is done


def test_step_that_goes_on_returns_the_reached_observation():
    ts, state = STEP(jax.random.key(0), _state(3, 1), jnp.int32(1))  # 3 - 1 = 2, time 1 + 1 = 2
    assert (int(state.remaining), int(state.time)) == (2, 2)
    assert ts.obs.tolist() == ts.final_obs.tolist() == [2.0]
    assert (float(ts.reward), bool(ts.terminated), bool(ts.truncated), bool(ts.done)) == (
        1.0,
        False,
        False,
        False,
    )


def test_termination_auto_resets_and_keeps_the_final_observation():
    ts, state = STEP(jax.random.key(1), _state(1, 2), jnp.int32(1))  # 1 - 1 = 0: terminated on step 3 of 5
    assert bool(ts.terminated) and not bool(ts.truncated)
    assert ts.final_obs.tolist() == [0.0] and float(ts.reward) == 1.0
    assert int(state.time) == 0 and 1 <= int(state.remaining) <= 3  # a fresh start ...
    assert ts.obs.tolist() == [float(state.remaining)]  # ... which the observation shows


def test_truncation_auto_resets_and_keeps_the_final_observation():
    ts, state = STEP(jax.random.key(2), _state(3, 4), jnp.int32(0))  # waits: time 5 = the limit
    assert bool(ts.truncated) and not bool(ts.terminated)
    assert ts.final_obs.tolist() == [3.0] and float(ts.reward) == 0.0
    assert int(state.time) == 0 and 1 <= int(state.remaining) <= 3


def test_terminated_and_truncated_on_the_same_step():
    ts, state = STEP(jax.random.key(3), _state(1, 4), jnp.int32(1))
    assert bool(ts.terminated) and bool(ts.truncated) and bool(ts.done)
    assert ts.final_obs.tolist() == [0.0] and int(state.time) == 0


def test_fresh_starts_depend_on_the_key_and_cover_the_start_distribution():
    keys = jax.random.split(jax.random.key(4), 300)
    ts, state = jax.vmap(STEP, in_axes=(0, None, None))(keys, _state(1, 0), jnp.int32(1))
    assert bool(ts.terminated.all()) and np.all(np.asarray(ts.final_obs) == 0.0)
    counts = np.bincount(np.asarray(state.remaining), minlength=4)
    assert counts[0] == 0 and np.all(np.abs(counts[1:] - 100) < 40)  # uniform on {1, 2, 3}: 100 each, sd 8


def test_params_default_to_default_params():
    key, state = jax.random.key(5), _state(2, 4)
    implicit, _ = ENV.step(key, state, jnp.int32(0))
    explicit, _ = ENV.step(key, state, jnp.int32(0), CountdownParams(max_steps_in_episode=5))
    longer, _ = ENV.step(key, state, jnp.int32(0), CountdownParams(max_steps_in_episode=6))
    assert bool(implicit.truncated) and bool(explicit.truncated) and not bool(longer.truncated)


def test_vmapped_batch_resets_only_the_envs_that_ended():
    state = CountdownState(jnp.array([3, 1, 2, 1], jnp.int32), jnp.array([0, 0, 4, 4], jnp.int32))
    actions = jnp.array([1, 1, 0, 1], jnp.int32)
    ts, state = jax.vmap(STEP)(jax.random.split(jax.random.key(6), 4), state, actions)
    assert ts.terminated.tolist() == [False, True, False, True]
    assert ts.truncated.tolist() == [False, False, True, True]
    assert ts.final_obs[:, 0].tolist() == [2.0, 0.0, 2.0, 0.0]
    assert state.time.tolist() == [1, 0, 0, 0]
    assert int(state.remaining[0]) == 2 and ts.obs[:, 0].tolist() == state.remaining.astype(float).tolist()


def test_a_scanned_rollout_counts_episodes():
    # Always counting down: each episode lasts as many steps as its start (1-3), well within 5 steps;
    # so over 60 steps the episodes that ended sum their lengths to the steps taken in them.
    def body(carry, key):
        state, length = carry
        ts, state = ENV.step(key, state, jnp.int32(1))
        return (state, jnp.where(ts.done, 0, length + 1)), (ts.done, length + 1, ts.truncated, ts.obs[0])

    first_obs, state = ENV.reset(jax.random.key(7))
    _, (done, lengths, truncated, obs) = jax.lax.scan(
        body, (state, jnp.int32(0)), jax.random.split(jax.random.key(8), 60)
    )
    done = np.asarray(done)
    finished = np.asarray(lengths)[done]
    # Episode k starts from the reset observation: the first from reset, each later one from the
    # auto-reset of the step that ended episode k - 1; it then lasts exactly that many steps.
    starts = np.concatenate([np.asarray(first_obs), np.asarray(obs)[done]])
    np.testing.assert_array_equal(finished, starts[: finished.size])
    assert set(finished.tolist()) == {1, 2, 3} and not truncated.any()  # every start occurs
    assert finished.sum() == np.argwhere(done)[-1, 0] + 1


def test_environment_must_implement_the_protocol_and_has_no_default_renderer():
    with pytest.raises(TypeError):
        Environment()
    with pytest.raises(TypeError, match="Countdown-v0 has no renderer"):
        ENV.render_frame(_state(1, 0))
    assert repr(ENV) == "Countdown('Countdown-v0')"


def test_discrete_sample_and_contains():
    space = Discrete(5)
    samples = np.asarray(jax.vmap(space.sample)(jax.random.split(jax.random.key(9), 5000)))
    assert samples.dtype == np.int32 and samples.shape == (5000,)
    counts = np.bincount(samples, minlength=6)
    assert counts[5] == 0 and np.all(
        np.abs(counts[:5] - 1000) < 150
    )  # 1000 each, sd sqrt(5000 * .2 * .8) = 28
    assert all(space.contains(a) for a in (0, 4, np.int64(2), jnp.int32(3)))
    assert not any(space.contains(a) for a in (5, -1, 1.0, True, np.array([1]), jnp.array([0, 1])))
    assert str(space) == "Discrete(5)"


def test_box_sample_and_contains():
    space = Box(np.array([-1.0, 0.0], np.float32), np.array([1.0, 10.0], np.float32), (2,))
    samples = np.asarray(jax.vmap(space.sample)(jax.random.split(jax.random.key(10), 4000)))
    assert samples.shape == (4000, 2) and samples.dtype == np.float32
    assert np.all(samples >= [-1.0, 0.0]) and np.all(samples <= [1.0, 10.0])
    # Uniform: means 0 and 5, standard errors 2 / sqrt(12 * 4000) = 0.009 and 0.046.
    assert abs(samples[:, 0].mean()) < 0.05 and abs(samples[:, 1].mean() - 5.0) < 0.25
    assert space.contains(np.array([-1.0, 10.0])) and space.contains(np.array([0.5, 3.0], np.float32))
    assert not space.contains(np.array([1.5, 3.0])) and not space.contains(np.array([0.0, -0.1]))
    assert not space.contains(np.array([0.0, 1.0, 2.0])) and not space.contains(np.array([np.nan, 1.0]))


def test_box_with_scalar_and_infinite_bounds():
    scalar = Box(-2.0, 3.0, (2, 3))
    sample = np.asarray(scalar.sample(jax.random.key(11)))
    assert sample.shape == (2, 3) and np.all((sample >= -2.0) & (sample <= 3.0))
    assert scalar.contains(np.zeros((2, 3))) and not scalar.contains(np.full((2, 3), 3.5))
    unbounded = Box(-np.inf, np.inf, (3,))
    samples = np.asarray(jax.vmap(unbounded.sample)(jax.random.split(jax.random.key(12), 100)))
    assert np.all(np.isfinite(samples)) and np.all(np.abs(samples) <= 1e6)
    assert unbounded.contains(np.array([1e30, -1e30, 0.0]))


def test_box_names_its_bounds():
    assert str(Box(0, 255, (84, 84, 4))) == "Box(shape=(84, 84, 4), low=0, high=255)"
    cartpole_like = Box(-np.array([4.8, np.inf]), np.array([4.8, np.inf]), (2,))
    assert str(cartpole_like) == "Box(shape=(2,), low=[-4.8, -inf], high=[4.8, inf])"
    assert str(Box(np.arange(20.0), 30.0, (20,))) == "Box(shape=(20,), low=0..19, high=30)"
