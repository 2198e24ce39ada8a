"""Encoders chosen per key (issue 41, item 2): ``Layout.with_encoders``, the feature width of each
choice, the parameters they give, ``--encoder KEY=CHOICE`` and a run file's ``encoders`` table,
refusals in one line, and a GridWorld-v0 run trained with an override that evaluates and resumes."""

import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.tree_util import keystr, tree_leaves_with_path

from agentax import api, runfile
from agentax.agents import ppo, presets_of
from agentax.agents.protocol import EnvSpec
from agentax.cli import main
from agentax.envs import make_jax
from agentax.envs.core import Box, Discrete
from agentax.envs.spaces import Dict, MultiBinary, MultiDiscrete, Tuple, layout_of
from agentax.errors import UsageError
from agentax.export import layout_card, layout_from_card
from agentax.nets import Encoder
from agentax.runners.compiled import compiled_program
from agentax.runs import read_metrics

LAYOUT = layout_of(
    Dict(
        (
            ("joints", Box(-1.0, 1.0, (3,))),
            ("camera", Box(0, 255, (12, 12, 3), jnp.uint8)),  # [H, W, C] under 36 px: 432 pixels
            ("frames", Box(0.0, 1.0, (3, 40, 40))),  # [C, H, W] from 36 px: 4,800 pixels
            ("cell", Discrete(5)),
            ("dice", MultiDiscrete((2, 3))),
            ("switches", MultiBinary(4)),
            ("action_mask", MultiBinary(4)),
        )
    )
)
AUTO_WIDTH = 3 + 256 + 512 + 5 + (2 + 3) + 4
"""joints 3, camera's small convs 256, frames' Nature CNN 512, cell one-hot 5, dice 2 + 3, switches 4"""


def feature_width(layout) -> int:
    obs = jax.ShapeDtypeStruct((2, layout.size), jnp.float32)
    features, _ = jax.eval_shape(lambda x: Encoder(layout).init_with_output(jax.random.key(0), x), obs)
    return features.shape[-1]


@pytest.mark.parametrize(
    ("overrides", "width"),
    [
        ({}, AUTO_WIDTH),
        ({"camera": "auto", "cell": "auto", "joints": "auto"}, AUTO_WIDTH),
        ({"camera": "flat"}, AUTO_WIDTH - 256 + 12 * 12 * 3),
        ({"frames": "small"}, AUTO_WIDTH - 512 + 256),
        ({"frames": "flat"}, AUTO_WIDTH - 512 + 3 * 40 * 40),
        ({"frames": "nature"}, AUTO_WIDTH),
        ({"camera": "small"}, AUTO_WIDTH),
        ({"cell": "scalar"}, AUTO_WIDTH - 5 + 1),
        ({"dice": "scalar"}, AUTO_WIDTH - 5 + 2),  # one float per entry
        ({"cell": "one_hot", "dice": "one_hot", "joints": "flat", "switches": "flat"}, AUTO_WIDTH),
    ],
)
def test_each_choice_gives_its_feature_width(overrides, width):
    assert feature_width(LAYOUT.with_encoders(overrides)) == width


def test_flat_and_scalar_are_the_numbers_scaled_and_packing_is_unchanged():
    layout = LAYOUT.with_encoders({"camera": "flat", "cell": "scalar", "dice": "scalar"})
    encoders = [leaf.encoder for leaf in layout.leaves]
    assert encoders == ["auto", "flat", "auto", "scalar", "scalar", "auto", "auto"]
    assert (layout.size, layout.dtype) == (LAYOUT.size, LAYOUT.dtype)
    leaves = {leaf.key: leaf for leaf in layout.leaves}
    packed = np.zeros((1, layout.size), np.float32)
    packed[0, leaves["camera"].start :][:2] = (255, 51)
    packed[0, leaves["cell"].start] = 3
    packed[0, leaves["dice"].start :][:2] = (1, 2)
    encoder = Encoder(layout)
    features = jax.jit(lambda x: encoder.apply(encoder.init(jax.random.key(0), x), x))(packed)[0]
    # in the leaves' order: joints 3, camera 432 pixels, frames 512, cell 1, dice 2, switches 4
    np.testing.assert_allclose(features[3:5], [1.0, 0.2])  # the pixels scaled: 255 / 255, 51 / 255
    assert features[3 + 432 + 512] == 3.0  # the integer as one float
    np.testing.assert_array_equal(features[3 + 432 + 512 + 1 :][:2], [1.0, 2.0])


def parameters(layout, init=jax.eval_shape):
    """The encoder's parameters for ``layout`` (their shapes only, with ``jax.eval_shape``)."""
    obs = jnp.zeros((1, layout.size))
    return init(lambda: Encoder(layout).init(jax.random.key(0), obs))


def test_no_override_is_the_same_layout_and_parameters():
    """No choice, or each kind's "auto" spelled out, gives today's parameters: names, shapes, values."""
    assert LAYOUT.with_encoders({}) == LAYOUT
    explicit = LAYOUT.with_encoders({"camera": "small", "frames": "nature", "cell": "one_hot"})
    assert parameters(explicit) == parameters(LAYOUT)
    small = layout_of(Dict((("camera", Box(0, 255, (8, 8, 3), jnp.uint8)), ("cell", Discrete(3)))))
    chosen = parameters(small.with_encoders({"camera": "small", "cell": "one_hot"}), lambda f: jax.jit(f)())
    auto = parameters(small, lambda f: jax.jit(f)())
    for got, want in zip(jax.tree.leaves(chosen), jax.tree.leaves(auto), strict=True):
        np.testing.assert_array_equal(got, want)


def gridworld_params(encoders):
    spec = EnvSpec.of(make_jax("GridWorld-v0")).with_encoders(encoders, "GridWorld-v0")
    agent = ppo.make_agent(spec, presets_of("ppo")["small-games"].config)
    return jax.tree.map(lambda x: x.shape, jax.eval_shape(agent.init, jax.random.key(0)).params["params"])


def test_overriding_changes_the_parameters_shapes():
    """GridWorld-v0: image [8, 8, 3] (small convs → 256) and vector [3]; flat: 192 pixels, no convs."""
    auto = gridworld_params({})
    assert auto["Encoder_0"]["ImageEncoder_0"]["MatmulConv_0"]["conv_kernel"] == (3, 3, 3, 16)
    assert auto["net"]["Dense_0"]["kernel"] == (256 + 3, 64)
    flat = gridworld_params({"image": "flat"})
    assert "Encoder_0" not in flat  # nothing left to learn before the torso
    assert flat["net"]["Dense_0"]["kernel"] == (8 * 8 * 3 + 3, 64)


def test_tuple_positions_and_a_single_leaf_are_named_as_strings():
    pair = layout_of(Tuple((Discrete(3), Box(0, 255, (8, 8), jnp.uint8))))
    assert feature_width(pair.with_encoders({"0": "scalar", "1": "flat"})) == 1 + 64
    single = layout_of(Discrete(7))
    assert feature_width(single.with_encoders({"obs": "scalar"})) == 1
    assert str(single.with_encoders({"obs": "scalar"})) == "discrete [] [7] (scalar)"


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            {"velocity": "flat"},
            "--encoder velocity: no such key; the observation's keys are joints, camera, frames, cell, dice,",
        ),
        ({"action_mask": "flat"}, "(action_mask masks the actions: it has no encoder)"),
        (
            {"cell": "flat"},
            "--encoder cell=flat: not an encoder of a discrete leaf; choose from auto, one_hot, scalar",
        ),
        ({"joints": "nature"}, "not an encoder of a vector leaf; choose from auto, flat"),
        (
            {"camera": "nature"},
            "takes images of at least 36×36 pixels, this one is 12×12; choose small or flat",
        ),
    ],
)
def test_an_unknown_key_or_a_choice_that_does_not_fit_is_one_line(overrides, message):
    with pytest.raises(UsageError) as error:
        LAYOUT.with_encoders(overrides)
    assert message in str(error.value) and "\n" not in str(error.value)


def test_the_card_of_an_export_keeps_the_choices():
    layout = LAYOUT.with_encoders({"cell": "scalar"})
    assert layout_from_card(json.loads(json.dumps(layout_card(layout)))) == layout
    assert "encoder" not in json.dumps(layout_card(LAYOUT))  # cards of runs without overrides unchanged


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--encoder", "wall=flat"], "--encoder wall: no such key; the observation's keys are image, vector"),
        (
            ["--encoder", "image=one_hot"],
            "not an encoder of a image leaf; choose from auto, nature, small, flat",
        ),
        (["--encoder", "image"], "--encoder image=: not an encoder of a image leaf"),
        (["--env", "CartPole-v1", "--encoder", "obs=flat"], "CartPole-v1's observations are plain [4]"),
    ],
)
def test_bad_overrides_through_the_cli_are_one_line_exit_2_and_nothing_written(
    argv, message, tmp_path, capsys
):
    out = tmp_path / "run"
    env = [] if "--env" in argv else ["--env", "GridWorld-v0"]
    assert main(["train", "ppo", *env, *argv, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not out.exists()


def test_a_run_file_table_must_hold_strings(tmp_path):
    path = tmp_path / "run.toml"
    path.write_text('algo = "ppo"\nenv = "GridWorld-v0"\nencoders = {image = 1}\n')
    with pytest.raises(UsageError, match=r"encoders must be a table of strings \(\{grid = \"flat\"\}\), got"):
        runfile.load(path)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_run_trained_with_overrides_evaluates_resumes_and_repeats_from_its_folder(tmp_path, capsys):
    """A run file's table plus a flag, on GridWorld-v0: the choices are saved (config.json, run.toml),
    the folder's checkpoint loads only into that network, evaluate and resume use it."""
    path = tmp_path / "grid.toml"
    path.write_text(
        'algo = "ppo"\nenv = "GridWorld-v0"\nencoders = {image = "flat"}\n\n'
        "[config]\ntotal_steps = 1024\nanneal_lr = false\n"  # resumed longer: the same program
    )
    out = tmp_path / "run"
    assert (
        main(["train", "--config", str(path), "--encoder", "vector=flat", "--out", str(out), "--no-progress"])
        == 0
    )
    chosen = {"image": "flat", "vector": "flat"}
    config = json.loads((out / "config.json").read_text())
    assert config["encoders"] == chosen
    assert runfile.load(out / "run.toml").run_args.encoders == chosen  # run.toml repeats the run
    capsys.readouterr()

    assert main(["evaluate", "--policy", str(out), "--episodes", "3"]) == 0
    assert "3 episodes" in capsys.readouterr().out

    plain = tmp_path / "without"  # the same folder without its choices: the checkpoint does not load
    shutil.copytree(out, plain)
    (plain / "config.json").write_text(json.dumps({k: v for k, v in config.items() if k != "encoders"}))
    with pytest.raises(UsageError, match="Encoder_0"):
        api.restore_policy(plain)

    steps = read_metrics(out)[-1]["env_steps"]
    config["config"]["total_steps"] += 1024
    (out / "config.json").write_text(json.dumps(config))
    resumed = api.resume(out, progress=False, quiet=True)
    assert resumed.metrics[-1]["env_steps"] > steps
    assert json.loads((out / "config.json").read_text())["encoders"] == chosen


def test_the_compiled_program_of_sweeps_and_workers_takes_the_choices():
    """``compiled_program(..., encoders=)`` (what a sweep builds its programs with) has the flat
    network: no encoder parameters, the torso on 192 pixels and 3 numbers."""
    env = make_jax("GridWorld-v0")
    program = compiled_program(ppo, env, presets_of("ppo")["small-games"].config, encoders={"image": "flat"})
    carry = jax.eval_shape(program.init, jax.random.key(0))
    shapes = {keystr(path): leaf.shape for path, leaf in tree_leaves_with_path(carry)}
    assert not [name for name in shapes if "Encoder_0" in name]
    torso = {shape for name, shape in shapes.items() if "['net']['Dense_0']['kernel']" in name}
    assert torso == {(8 * 8 * 3 + 3, 64)}  # the parameters and the optimizer's moments of them


def test_a_sweep_with_an_unknown_key_is_one_line_before_anything_is_traced(tmp_path, capsys):
    argv = ["sweep", "ppo", "--env", "GridWorld-v0", "--grid", "learning_rate=0.001,0.003"]
    assert main([*argv, "--encoder", "wall=flat", "--out", str(tmp_path / "sweep"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--encoder wall: no such key; the observation's keys are image, vector" in err
    assert err.count("\n") == 1
    assert not (tmp_path / "sweep").exists()
