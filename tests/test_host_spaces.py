"""Host envs of every space (issue 41) end to end: spaces agentax refuses are one line and exit code
2 with nothing written; PPO trains on packed observations (Taxi-v4's info mask, Blackjack-v1's
Tuple, a masked Dict, MultiDiscrete and MultiBinary actions, 48×48×3 uint8 images) on the host and
parallel runners, evaluates, plays a video, and exports a masked Dict policy whose ONNX file takes
the packed vector and acts as the policy does under onnxruntime.

The envs of one's own are ``scripts/own_envs.py``'s, named ``scripts.own_envs:ID`` so that Gymnasium
imports the module in every process (the parallel runner's actors too)."""

import json

import gymnasium
import jax
import numpy as np
import pytest

import agentax
from agentax import export
from agentax.cli import main
from agentax.envs import make
from agentax.envs.gym import GymnasiumEnv
from agentax.errors import UsageError
from agentax.evaluate import HostPolicy, host_episode_returns
from scripts import own_envs

OWN = "scripts.own_envs:"
SUPPORTED_OBS = "it takes Box, Discrete, MultiDiscrete, MultiBinary, and a Dict or Tuple of them (one level)"
REFUSED = {
    "Bad-Graph-v0": ("Graph(Box(0.0, 1.0, (2,), float32), Discrete(2)) is no space", SUPPORTED_OBS),
    "Bad-Text-v0": ("Text(1, 8, charset=", SUPPORTED_OBS),
    "Bad-Sequence-v0": ("Sequence(Box(0.0, 1.0, (2,), float32), stack=False) is no space", SUPPORTED_OBS),
    "Bad-Nested-v0": ("nests Dict spaces two levels deep (Dict(joints: ", "agentax takes Box, Discrete"),
    "Bad-Text-Actions-v0": (
        "its actions Text(1, 4, charset=",
        "it takes Discrete, Box, MultiDiscrete and MultiBinary actions",
    ),
    "Bad-No-Legal-v0": ("gave an action mask with no legal action", "every step needs one"),
}
"""Each refused env: what its one line says of the space, and of what agentax takes."""


def train(argv, tmp_path, name="run"):
    out = tmp_path / name
    argv = ["train", *argv, "--out", str(out), "--no-progress"]
    return main(argv), out


@pytest.mark.parametrize("env_id", list(REFUSED))
@pytest.mark.parametrize("algo", ["ppo", "dqn"])
def test_a_space_agentax_cannot_take_is_one_line_exit_2_and_nothing_written(env_id, algo, tmp_path, capsys):
    code, out = train([algo, "--env", OWN + env_id, "--total-steps", "256"], tmp_path)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    space, supported = REFUSED[env_id]
    assert f"{OWN}{env_id} cannot run in agentax: " in err and space in err and supported in err, err
    assert not out.exists()


def test_the_refused_spaces_are_refused_by_the_adapter_too():
    """``GymnasiumEnv`` (what ``agentax.envs.make`` gives) refuses them before any run, closing the env."""
    for env_id, (space, _) in REFUSED.items():
        with pytest.raises(UsageError, match="cannot run in agentax") as error:
            GymnasiumEnv(OWN + env_id)
        assert space in str(error.value)


def test_packed_host_observations_and_their_layouts():
    """What each space becomes, worked out from the spaces: Taxi's state (one number) and its
    6-action info mask; Blackjack's Tuple of three Discrete; the Dict's keys in Gymnasium's sorted
    order (action_mask 4, cue 4, position 1); MultiDiscrete [3, 4] two entries; a 48×48×3 image of bytes."""
    expected = {
        "Taxi-v4": ("float32", "obs: discrete [] [500]; action_mask: mask [6]", 7),
        "Blackjack-v1": ("float32", "0: discrete [] [32]; 1: discrete [] [11]; 2: discrete [] [2]", 3),
        OWN + "Masked-Dict-v0": (
            "float32",
            "action_mask: mask [4]; cue: vector [4]; position: vector [1]",
            9,
        ),
        OWN + "Match-MultiDiscrete-v0": ("float32", "multi_discrete [2] [3, 4]", 2),
        OWN + "Match-MultiBinary-v0": ("float32", "binary [4]", 4),
        OWN + "Picture48-v0": ("uint8", "image [48, 48, 3]", 48 * 48 * 3),
    }
    for env_id, (dtype, layout, size) in expected.items():
        env = make(env_id, 2)
        try:
            obs = env.reset(seed=0)
            assert str(env.layout) == layout and env.layout.dtype == dtype and env.layout.size == size
            assert obs.shape == (2, size) and obs.dtype == np.dtype(dtype)
        finally:
            env.close()
    taxi = make("Taxi-v4", 1)
    obs = taxi.reset(seed=0)
    raw, info = taxi.vector_env.reset(seed=0)
    np.testing.assert_array_equal(obs, np.concatenate([raw[:, None], info["action_mask"]], axis=1))
    taxi.close()


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize(
    "env_id, runner",
    [
        ("Taxi-v4", "host"),
        ("Blackjack-v1", "host"),
        (OWN + "Match-MultiDiscrete-v0", "host"),
        (OWN + "Match-MultiBinary-v0", "host"),
        pytest.param(OWN + "Picture48-v0", "host", marks=pytest.mark.long),  # test_spaces_learning trains it
        (OWN + "Masked-Dict-v0", "parallel"),
        pytest.param(OWN + "Picture48-v0", "parallel", marks=pytest.mark.long),  # as host's, in actors
        pytest.param("Taxi-v4", "parallel", marks=pytest.mark.long),  # the info mask, in actors
    ],
)
def test_ppo_trains_evaluates_and_plays_on_packed_host_observations(env_id, runner, tmp_path, capsys):
    """A few updates, then ``agentax evaluate`` and ``agentax play`` of the run folder: exit 0 each,
    the run's evaluation written, a GIF of one episode."""
    extra = ["--actors", "2"] if runner == "parallel" else []
    code, out = train(["ppo", "--env", env_id, "--runner", runner, "--total-steps", "1024", *extra], tmp_path)
    assert code == 0, capsys.readouterr().err
    stats = json.loads((out / "eval.json").read_text())
    assert stats["episodes"] > 0 and np.isfinite(stats["mean_return"])
    capsys.readouterr()
    assert main(["evaluate", "--policy", str(out), "--episodes", "3", "--json"]) == 0
    evaluated = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert evaluated["episodes"] == 3
    video = tmp_path / "episode.gif"
    assert main(["play", "--policy", str(out), "--video", str(video)]) == 0
    assert video.stat().st_size > 0 and "wrote" in capsys.readouterr().out


def test_play_of_an_env_that_cannot_draw_is_one_line(tmp_path, capsys):
    """An env of one's own without ``render_mode`` (Bad-Graph's Spaces class takes none)."""
    code = main(["play", "--env", "CartPole-v1", "--policy", "random", "--video", str(tmp_path / "a.gif")])
    assert code == 0
    capsys.readouterr()
    gymnasium_id = "Plain-No-Render-v0"
    if gymnasium_id not in gymnasium.registry:
        gymnasium.register(gymnasium_id, entry_point=own_envs.Spaces, max_episode_steps=4)
    code = main(["play", "--env", gymnasium_id, "--policy", "random", "--video", str(tmp_path / "b.gif")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "cannot draw 'Plain-No-Render-v0'" in err, err


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_an_exported_masked_dict_policy_takes_the_packed_vector_and_acts_as_the_policy(tmp_path):
    """PPO on the masked Dict env, exported to ONNX: on 512 observations packed with the card's
    layout (Dict observations drawn from the space, masks included) onnxruntime's actions are the
    agentax policy's, every one legal; the layout is in the card and in the ONNX metadata."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("jax2onnx")
    env_id = OWN + "Masked-Dict-v0"
    run = agentax.train("ppo", env=env_id, total_steps=1024, out=tmp_path / "run", progress=False)
    path = run.export(format="onnx")
    exported = export.load(path)
    layout = exported.layout
    assert [(leaf.key, leaf.kind, leaf.start, leaf.size) for leaf in layout.leaves] == [
        ("action_mask", "mask", 0, 4),
        ("cue", "vector", 4, 4),
        ("position", "vector", 8, 1),
    ]
    card = json.loads(export.card_path(path).read_text())
    metadata = {p.key: p.value for p in onnx.load(path).metadata_props}
    assert json.loads(metadata[export.LAYOUT_METADATA]) == card["layout"] == export.layout_card(layout)
    assert card["inputs"] == [{"name": "obs", "shape": ["N", 9], "dtype": "float32"}]

    space = own_envs.MaskedDict.observation_space
    space.seed(0)
    rng = np.random.default_rng(0)
    samples = [space.sample() for _ in range(512)]
    for sample in samples:  # at least one legal action, as the env always gives
        if not sample["action_mask"].any():
            sample["action_mask"][rng.integers(4)] = 1
    batch = {key: np.stack([s[key] for s in samples]) for key in samples[0]}
    packed = layout.pack(batch)
    assert packed.shape == (512, 9) and packed.dtype == np.float32
    np.testing.assert_array_equal(packed[:, 4:8], batch["cue"])

    actions = exported.run(packed)
    expected = np.asarray(jax.jit(jax.vmap(lambda o: run.policy(o, jax.random.key(0))))(packed))
    np.testing.assert_array_equal(actions, expected)
    assert np.all(batch["action_mask"][np.arange(512), actions] == 1)  # every action legal
    assert len(np.unique(actions)) > 1


def test_evaluation_cuts_an_episode_that_never_ends():
    """An env without a time limit (as CliffWalking-v1) under a policy that never finishes: each of
    the 2 sub-envs plays one episode, cut at ``max_steps`` = 5, and plays no more."""
    if "Endless-v0" not in gymnasium.registry:
        gymnasium.register("Endless-v0", entry_point=own_envs.Spaces)
    env = GymnasiumEnv("Endless-v0", num_envs=2)
    try:
        policy = HostPolicy(lambda obs, rng: np.zeros(len(obs), np.int64))
        returns, lengths = host_episode_returns(env, policy, num_episodes=4, max_steps=5)
    finally:
        env.close()
    np.testing.assert_array_equal(lengths, [5, 5])
    np.testing.assert_array_equal(returns, [0.0, 0.0])
