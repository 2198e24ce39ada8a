"""A CNN agent learns a tiny pixel task of our own making: the Nature CNN end to end, on the host."""

import dataclasses

import gymnasium
import numpy as np
import pytest

from agentax.agents import dqn, ppo, presets
from agentax.agents.protocol import EnvSpec
from agentax.envs import make_host_env
from agentax.runners import host
from agentax.runners.launch import agent_maker


class PixelSide(gymnasium.Env):
    """One-step episodes: a bright 12×12 square lies in the left or the right half of four stacked
    84×84 frames; action 0 says left, 1 says right; reward 1 when right, else 0."""

    observation_space = gymnasium.spaces.Box(0, 255, (4, 84, 84), np.uint8)
    action_space = gymnasium.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self._draw(), {}

    def _draw(self):
        self.side = int(self.np_random.integers(2))
        frames = np.zeros((4, 84, 84), np.uint8)
        row = int(self.np_random.integers(0, 72))
        col = int(self.np_random.integers(0, 30)) + 42 * self.side
        frames[:, row : row + 12, col : col + 12] = 255
        return frames

    def step(self, action):
        reward = float(int(action) == self.side)
        return self._draw(), reward, True, False, {}


gymnasium.register(id="PixelSide-v0", entry_point=PixelSide)


def spec():
    env = make_host_env("PixelSide-v0", 1)
    try:
        return EnvSpec.of(env)
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_ppo_with_the_nature_cnn_learns_where_the_square_is():
    cfg = dataclasses.replace(
        presets.preset("ppo", "atari").config,
        total_steps=2_048,
        num_envs=8,
        num_steps=16,
        num_minibatches=2,
        update_epochs=2,
        learning_rate=1e-3,
    )
    agent = agent_maker(ppo, spec(), cfg)()
    result = host.train(agent, "PixelSide-v0", host.HostRunnerConfig(log_every_steps=512, eval_episodes=64))
    assert result.rows[0]["mean_return"] < 0.7  # chance is 0.5
    assert result.eval["mean_return"] >= 0.9, [row["mean_return"] for row in result.rows]


@pytest.mark.long  # (make test-long: ~50 s alone, ~140 s beside another worker in make test)
@pytest.mark.timeout(240)
def test_dqn_with_the_nature_cnn_and_frame_replay_learns_where_the_square_is():
    cfg = dataclasses.replace(
        presets.NATURE,
        total_steps=1_536,
        num_envs=8,
        learning_starts=256,
        train_frequency=4,
        gradient_steps=4,
        batch_size=32,
        buffer_size=2_048,
        learning_rate=5e-4,
        exploration_duration=768,
        epsilon_end=0.05,
        target_update_period=64,
    )
    agent = dqn.make_agent(spec(), cfg)
    result = host.train(agent, "PixelSide-v0", host.HostRunnerConfig(log_every_steps=512, eval_episodes=64))
    # each frame stored once: ~7.5 KB a transition (float32 stacks of obs and next_obs: ~226 KB)
    assert result.rows[-1]["replay_bytes"] < 2_048 * 8_000
    assert result.eval["mean_return"] >= 0.9, [row["mean_return"] for row in result.rows]
