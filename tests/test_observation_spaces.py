"""Observation spaces no agent takes yet (issue 39): Discrete observations (FrozenLake, CliffWalking)
and an image laid out ``[H, W, C]`` are one line and exit code 2 before anything is written, while
the observations agentax takes (flat vectors, Atari's stacked frames, MinAtar's flat images) still
make a spec."""

import gymnasium
import numpy as np
import pytest

from agentax.agents import algorithm, algorithm_config
from agentax.agents.protocol import EnvSpec, check_observations
from agentax.cli import main
from agentax.envs import make_host_env, make_jax
from agentax.envs.core import Box, Discrete
from agentax.errors import UsageError


class Picture(gymnasium.Env):
    """An env of one's own with 48×48 RGB pictures ``[H, W, C]`` uint8 as observations."""

    observation_space = gymnasium.spaces.Box(0, 255, (48, 48, 3), np.uint8)
    action_space = gymnasium.spaces.Discrete(3)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros((48, 48, 3), np.uint8), {}

    def step(self, action):
        return np.zeros((48, 48, 3), np.uint8), 1.0, False, False, {}


gymnasium.register(id="Picture48-v0", entry_point=Picture, max_episode_steps=20)

REFUSED = {
    "FrozenLake-v1": "FrozenLake-v1 has observations Discrete(16), which agentax's agents do not take yet",
    "CliffWalking-v1": "CliffWalking-v1 has observations Discrete(48), which agentax's agents do not",
    "Picture48-v0": "Picture48-v0 has observations Box(shape=(48, 48, 3), low=0, high=255), which",
}


@pytest.mark.parametrize("algo", ["ppo", "dqn"])
@pytest.mark.parametrize("env_id", list(REFUSED))
def test_an_observation_space_no_agent_takes_is_one_line_and_nothing_written(algo, env_id, capsys, tmp_path):
    out = tmp_path / "run"
    assert (
        main(["train", algo, "--env", env_id, "--total-steps", "500", "--out", str(out), "--no-progress"])
        == 2
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and REFUSED[env_id] in err, err
    assert "stacked frames [C, H, W] (channels first, at least 36x36, such as Atari's [4, 84, 84])" in err
    assert not out.exists()


def test_the_spaces_agentax_takes_still_make_a_spec():
    assert EnvSpec.of(make_jax("CartPole-v1")).obs_shape == (4,)
    minatar = EnvSpec.of(make_jax("gymnax/Breakout-MinAtar"))  # a flat image, its shape kept beside
    assert len(minatar.obs_shape) == 1 and minatar.image_shape == (10, 10, 4)
    frames = Box(np.zeros((4, 84, 84), np.uint8), np.full((4, 84, 84), 255, np.uint8), (4, 84, 84), np.uint8)
    check_observations(frames, "Breakout-v5")  # Atari's stacked frames
    check_observations(Box(np.zeros((3, 36, 36)), np.ones((3, 36, 36)), (3, 36, 36)))  # the least frame
    with pytest.raises(UsageError, match=r"observations Box\(shape=\(3, 35, 36\)"):
        check_observations(Box(np.zeros((3, 35, 36)), np.ones((3, 35, 36)), (3, 35, 36)))
    with pytest.raises(UsageError, match=r"LectureMDP-v0 has observations Discrete\(3\)"):
        EnvSpec.of(make_jax("LectureMDP-v0"))
    env = make_host_env("Picture48-v0", 1)
    try:
        with pytest.raises(UsageError, match="Picture48-v0 has observations"):
            EnvSpec.of(env)
    finally:
        env.close()


@pytest.mark.parametrize("algo", ["sac", "td3", "reinforce"])
def test_frames_given_to_an_agent_without_a_conv_torso_are_one_line(algo):
    """Stacked frames [3, 48, 48] make a spec (ppo, dqn and pqn train on them), but the agents whose
    networks are MLPs refuse them by name instead of a shape error deep in a trace."""
    frames = EnvSpec((3, 48, 48), Box(np.full(1, -1.0, np.float32), np.ones(1, np.float32), (1,)), np.uint8)
    if algo == "reinforce":
        frames = EnvSpec((3, 48, 48), Discrete(3), np.uint8)
    with pytest.raises(UsageError, match=rf"{algo} takes flat observations \[n\], not frames \[3, 48, 48\]"):
        algorithm(algo).make_agent(frames, algorithm_config(algo)())
