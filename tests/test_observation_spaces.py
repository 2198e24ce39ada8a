"""Observation spaces agents take since issue 41: Discrete observations (FrozenLake, CliffWalking, the
lecture's MDP) and images laid out ``[H, W, C]`` are packed (:mod:`agentax.envs.spaces`) and train,
flat vectors and stacked frames still go in as they are, and an env that hands composite
observations to an agent unpacked is one line saying how to pack them."""

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
        return np.full((48, 48, 3), 7, np.uint8), {}

    def step(self, action):
        return np.full((48, 48, 3), 9, np.uint8), 1.0, False, False, {}


if "Bytes48-v0" not in gymnasium.registry:
    gymnasium.register(id="Bytes48-v0", entry_point=Picture, max_episode_steps=20)

PACKED = {
    # env id: (the layout's one line, packed size, dtype, the first observation packed, worked by hand)
    "FrozenLake-v1": ("discrete [] [16]", 1, "float32", [0.0]),  # the start, state 0
    "CliffWalking-v1": ("discrete [] [48]", 1, "float32", [36.0]),  # bottom-left: row 3 x 12 columns
    "Bytes48-v0": ("image [48, 48, 3]", 6912, "uint8", [7] * 6912),  # kept as bytes, 48*48*3
}


@pytest.mark.parametrize("env_id", list(PACKED))
def test_discrete_and_image_observations_are_packed_into_a_spec(env_id):
    layout, size, dtype, first = PACKED[env_id]
    env = make_host_env(env_id, 1)
    try:
        spec = EnvSpec.of(env)
        assert str(spec.layout) == layout and spec.obs_shape == (size,) and spec.obs_dtype == np.dtype(dtype)
        assert spec.legal(np.zeros(size)) is None  # no mask: every action legal
        np.testing.assert_array_equal(env.reset(seed=0), np.asarray([first], dtype))
    finally:
        env.close()


def test_the_lecture_mdp_states_are_packed_one_hot_for_agents():
    spec = EnvSpec.of(make_jax("LectureMDP-v0"))
    assert str(spec.layout) == "discrete [] [3]" and spec.obs_shape == (1,)


def test_plain_observations_keep_no_layout():
    assert EnvSpec.of(make_jax("CartPole-v1")).layout is None
    minatar = EnvSpec.of(make_jax("gymnax/Breakout-MinAtar"))  # a flat image, its shape kept beside
    assert len(minatar.obs_shape) == 1 and minatar.image_shape == (10, 10, 4) and minatar.layout is None
    frames = Box(np.zeros((4, 84, 84), np.uint8), np.full((4, 84, 84), 255, np.uint8), (4, 84, 84), np.uint8)
    check_observations(frames, "Breakout-v5")  # Atari's stacked frames
    check_observations(Box(np.zeros((3, 36, 36)), np.ones((3, 36, 36)), (3, 36, 36)))  # the least frame


def test_composite_observations_handed_over_unpacked_are_one_line_saying_how_to_pack():
    image = Box(np.zeros((3, 35, 36)), np.ones((3, 35, 36)), (3, 35, 36))  # smaller than a Nature CNN frame
    with pytest.raises(UsageError, match=r"gives observations Box\(shape=\(3, 35, 36\).* unpacked; make it"):
        check_observations(image, "Mine-v0")
    with pytest.raises(UsageError, match=r"Discrete\(5\) unpacked; make it with agentax.envs.make"):
        check_observations(Discrete(5), "Mine-v0")


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("env_id", ["FrozenLake-v1", "CliffWalking-v1"])
def test_discrete_observations_train_ppo_from_the_command_line(env_id, tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "ppo", "--env", env_id, "--total-steps", "1024", "--out", str(out), "--no-progress"]
    assert main(argv) == 0, capsys.readouterr().err
    assert (out / "eval.json").is_file()


@pytest.mark.parametrize("algo", ["sac", "td3", "reinforce"])
def test_frames_given_to_an_agent_without_a_conv_torso_are_one_line(algo):
    """Stacked frames [3, 48, 48] make a spec (ppo, dqn and pqn train on them), but the agents whose
    networks are MLPs refuse them by name instead of a shape error deep in a trace."""
    frames = EnvSpec((3, 48, 48), Box(np.full(1, -1.0, np.float32), np.ones(1, np.float32), (1,)), np.uint8)
    if algo == "reinforce":
        frames = EnvSpec((3, 48, 48), Discrete(3), np.uint8)
    with pytest.raises(UsageError, match=rf"{algo} takes flat observations \[n\], not frames \[3, 48, 48\]"):
        algorithm(algo).make_agent(frames, algorithm_config(algo)())
