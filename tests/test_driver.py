"""The Driver and its observers against Gymnasium itself."""

import gymnasium
import jax
import numpy as np
import pytest

from agentax.envs.gym import GymnasiumEnv
from agentax.replay import example_transition, host
from agentax.runners.driver import (
    AverageEpisodeLength,
    AverageReturn,
    Driver,
    EnvironmentSteps,
    NumberOfEpisodes,
    ReplayObserver,
    first_time_step,
)


def push_left(obs, policy_state):
    """Always action 0; the policy state counts the calls (it must come back out of ``run``)."""
    return np.zeros(len(obs), np.int64), policy_state + 1


def gymnasium_lengths(num_episodes, seed):
    """Episode lengths of always-left CartPole-v1 in plain Gymnasium, reset with seed, then unseeded."""
    env, lengths = gymnasium.make("CartPole-v1"), []
    env.reset(seed=seed)
    for _ in range(num_episodes):
        length, done = 0, False
        while not done:
            _, _, terminated, truncated, _ = env.step(0)
            length, done = length + 1, terminated or truncated
        lengths.append(length)
        env.reset()
    return lengths


def test_driver_metrics_match_gymnasium():
    env = GymnasiumEnv("CartPole-v1", 1)
    steps, episodes, returns, lengths = (
        EnvironmentSteps(),
        NumberOfEpisodes(),
        AverageReturn(),
        AverageEpisodeLength(),
    )
    seen = []
    driver = Driver(env, push_left, [steps, episodes, returns, lengths, seen.append], max_episodes=3)
    time_step, calls = driver.run(first_time_step(env, seed=5), 0)
    expected = gymnasium_lengths(3, seed=5)  # pushing left topples the pole in ~8-10 steps
    assert episodes.result() == 3 and steps.result() == sum(expected) == calls == len(seen)
    assert returns.result() == pytest.approx(np.mean(expected))  # reward 1 per step
    assert lengths.result() == pytest.approx(np.mean(expected))
    # The step that ends an episode hands over the observation really reached, not the next reset one.
    end = expected[0] - 1
    assert seen[end].terminated[0] and not seen[end].truncated[0]
    assert abs(seen[end].next_obs[0][2]) > 0.2  # the pole angle past the 12° (0.21 rad) limit
    assert np.all(np.abs(seen[end + 1].obs[0]) <= 0.05)  # the next episode starts near upright
    env.close()


def test_truncation_is_kept_apart_and_max_steps_stops():
    env = GymnasiumEnv("CartPole-v1", 2, max_episode_steps=4)  # time limit 4: truncation before toppling
    seen, steps = [], EnvironmentSteps()
    driver = Driver(env, push_left, [seen.append, steps], max_steps=10)
    time_step, _ = driver.run(first_time_step(env, seed=0), 0)
    assert steps.result() == 10  # 5 vector steps of 2 envs
    flags = [(bool(t.terminated[0]), bool(t.truncated[0])) for t in seen]
    assert flags == [(False, False)] * 3 + [(False, True)] + [(False, False)]
    time_step, _ = driver.run(time_step, 0)  # continues where it stopped
    assert steps.result() == 20
    env.close()


def test_replay_observer_adds_n_step_transitions():
    env = GymnasiumEnv("CartPole-v1", 1)
    seen = []
    Driver(env, push_left, [seen.append], max_steps=6).run(first_time_step(env, seed=1), 0)
    one = jax.device_get(example_transition(np.zeros(4, np.float32), np.int32(0)))
    buffer = host.ReplayBuffer(100, one)
    observer = ReplayObserver(buffer, n_step=3, discount_factor=0.5)
    for transition in seen:
        observer(transition)
    assert buffer.size == 4  # 6 steps, the first 2 pushes only fill the 3-step window
    storage = buffer.state.storage
    np.testing.assert_allclose(storage.reward[:4], 1.75)  # 1 + 0.5 + 0.25, no episode ended
    np.testing.assert_array_equal(storage.num_steps[:4], 3)
    np.testing.assert_array_equal(storage.next_obs[0], seen[2].next_obs[0])
    env.close()


def test_a_driver_needs_a_limit():
    with pytest.raises(ValueError, match="max_steps or max_episodes"):
        Driver(None, push_left, [])
