"""``agentax export``: a trained policy as an ONNX file and a StableHLO module, checked by the runtimes
that run them (onnxruntime, ``jax.export.deserialize``) against the agentax policy on observations of
the env; ``agentax evaluate --policy FILE`` against the run's own evaluation; the bad inputs."""

import json
import sys
import time
from pathlib import Path

import jax
import numpy as np
import onnx
import pytest
from conftest import OnDemand

import agentax
from agentax import export
from agentax.api import _restore_learned
from agentax.cli import main
from agentax.envs import make

TINY = {  # a few thousand steps each: the policies need not be good, only trained and varied
    "ppo-cartpole": ("ppo", "CartPole-v1", {"total_steps": 2048, "learning_rate": 2e-3}),
    "dqn-cartpole": (
        "dqn",
        "CartPole-v1",
        {
            "total_steps": 1024,
            "num_envs": 2,
            "train_frequency": 8,
            "gradient_steps": 3,
            "learning_starts": 96,
            "batch_size": 16,
            "hidden": (16,),
            "stop_at_return": None,
            "freeze_at_return": "none",
        },
    ),
    "ppo-pendulum": ("ppo", "Pendulum-v1", {"preset": "pendulum", "total_steps": 1024}),  # Gaussian, host
    "sac-pendulum": (
        "sac",
        "Pendulum-v1",
        {"runner": "host", "total_steps": 400, "learning_starts": 200, "hidden": (16, 16)},
    ),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Each run of :data:`TINY` by name, trained through the API when a test first asks for it."""
    root = tmp_path_factory.mktemp("export")

    def train(name: str) -> Path:
        algo, env_id, settings = TINY[name]
        return agentax.train(algo, env=env_id, out=root / name, progress=False, **settings).path

    return OnDemand(train)


def env_observations(env_id: str, count: int = 1_000, seed: int = 0) -> np.ndarray:
    """``count`` observations ``[count, *obs_shape]`` that ``env_id``'s envs give under random actions."""
    env = make(env_id, 8)
    space, rng = env.action_space(), np.random.default_rng(seed)

    def random_actions():
        if hasattr(space, "n"):
            return rng.integers(0, space.n, 8)
        return rng.uniform(space.low, space.high, (8, *space.shape)).astype(np.float32)

    if hasattr(env, "default_params"):  # a JAX env: 8 of them vmapped
        params = env.default_params()
        keys = jax.random.split(jax.random.key(seed), 8)
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
        step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
        seen = [obs]
        while len(seen) * 8 < count:
            keys = jax.vmap(lambda k: jax.random.fold_in(k, len(seen)))(keys)
            ts, state = step(keys, state, random_actions(), params)
            seen.append(ts.obs)
    else:
        seen = [env.reset(seed=seed)]
        while len(seen) * 8 < count:
            seen.append(env.step(random_actions()).obs)
        env.close()
    return np.concatenate([np.asarray(o) for o in seen])[:count]


def agentax_actions(policy, obs: np.ndarray) -> np.ndarray:
    return np.asarray(jax.jit(jax.vmap(lambda o: policy(o, jax.random.key(0))))(obs))


def check_same_actions(path, policy, obs: np.ndarray, continuous: bool) -> np.ndarray:
    """The file's actions on ``obs`` (a batch) are the agentax policy's: equal, or within 1e-5."""
    actions, expected = export.load(path).run(obs), agentax_actions(policy, obs)
    assert actions.shape == expected.shape and actions.dtype == expected.dtype
    if continuous:
        np.testing.assert_allclose(actions, expected, rtol=0, atol=1e-5)
    else:
        np.testing.assert_array_equal(actions, expected)
    return actions


@pytest.mark.xdist_group("export")  # one worker trains the shared runs once
@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("name", list(TINY))
def test_both_formats_act_as_the_agentax_policy(runs, name, capsys):
    """On 1,000 observations of the env (and, for CartPole, 1,000 wider ones, where the greedy DQN
    of a short run turns too), under onnxruntime and ``jax.export.deserialize``."""
    run = agentax.load(runs[name])
    continuous = run.env == "Pendulum-v1"
    obs = env_observations(run.env)
    if not continuous:
        obs = np.concatenate([obs, np.random.default_rng(1).normal(0, 1, obs.shape).astype(np.float32)])
    start = time.perf_counter()
    onnx_file = run.export(format="onnx")
    seconds = time.perf_counter() - start
    hlo_file = run.export(runs[name] / "policy.stablehlo", "stablehlo")
    with capsys.disabled():
        sizes = ", ".join(f"{p.name} {p.stat().st_size:,} bytes" for p in (onnx_file, hlo_file))
        print(f"\n{name}: ONNX export {seconds:.2f} s; {sizes}")
    onnx.checker.check_model(onnx.load(onnx_file), full_check=True)
    for path in (onnx_file, hlo_file):
        actions = check_same_actions(path, run.policy, obs, continuous)
    if continuous:
        assert actions.shape == (len(obs), 1) and np.abs(actions).max() <= 2.0  # Pendulum's bounds
        assert actions.std() > 0
    else:
        assert actions.shape == (len(obs),) and set(np.unique(actions)) == {0, 1}

    card = json.loads(export.card_path(onnx_file).read_text())
    obs_shape, action_shape = ([4], ["N"]) if not continuous else ([3], ["N", 1])
    assert card["inputs"] == [{"name": "obs", "shape": ["N", *obs_shape], "dtype": "float32"}]
    assert card["outputs"] == [
        {"name": "action", "shape": action_shape, "dtype": "float32" if continuous else "int32"}
    ]
    assert card["env"] == run.env and card["format"] == "onnx" and card["policy"] == "greedy"
    assert card["final_evaluation"]["mean_return"] == run.final_eval["mean_return"]
    assert card["versions"]["agentax"] == agentax.__version__ and card["versions"]["jax2onnx"] == "0.17.1"
    expected_action_space = (
        {"type": "Box", "shape": [1], "dtype": "float32", "low": -2.0, "high": 2.0}
        if continuous
        else {"type": "Discrete", "n": 2, "shape": [], "dtype": "int32"}
    )
    assert card["action_space"] == expected_action_space
    assert json.loads(export.card_path(hlo_file).read_text())["platforms"] == ["cpu", "cuda"]


@pytest.mark.xdist_group("export")  # one worker trains the shared runs once
@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize("name", ["ppo-cartpole", "sac-pendulum"])
def test_the_stochastic_module_samples_as_the_agent_with_its_key(runs, name, tmp_path):
    """``--stochastic``: row ``i`` of ``f(obs, key)`` is the sampling policy's action with the ``i``-th
    key of ``split(key, N)``; another key gives other samples; ONNX refuses it in one line."""
    path = tmp_path / "sampling.stablehlo"
    assert main(["export", str(runs[name]), "--format", "stablehlo", "--stochastic", "--out", str(path)]) == 0
    exported = export.load(path)
    card = exported.card
    assert card["policy"] == "stochastic" and card["inputs"][1] == {
        "name": "key",
        "shape": [2],
        "dtype": "uint32",
    }
    run = agentax.load(runs[name])
    sampling = _restore_learned(run.path, run.config, stochastic=True)
    obs = env_observations(run.env, 200)
    key = jax.random.key(7)
    expected = jax.jit(jax.vmap(sampling))(obs, jax.random.split(key, len(obs)))
    actions = exported.run(obs, np.asarray(jax.random.key_data(key)))
    np.testing.assert_allclose(actions, np.asarray(expected), rtol=0, atol=1e-5)
    other = exported.run(obs, np.asarray(jax.random.key_data(jax.random.key(8))))
    assert (other != actions).mean() > 0.1
    assert not np.array_equal(actions, agentax_actions(run.policy, obs))  # not the greedy actions


@pytest.mark.xdist_group("export")  # one worker trains the shared runs once
@pytest.mark.slow
@pytest.mark.timeout(180)
def test_evaluate_policy_file_gives_the_runs_evaluation(runs, capsys):
    """``agentax evaluate --policy FILE`` plays the same episodes as ``--policy RUN_DIR``: the same
    returns on the JAX CartPole (discrete, equal) and on Gymnasium's Pendulum (within 1e-6)."""
    for name, format in (("ppo-cartpole", "onnx"), ("ppo-cartpole", "stablehlo"), ("ppo-pendulum", "onnx")):
        run_dir = runs[name]
        path = run_dir / f"eval-check.{format}"
        assert main(["export", str(run_dir), "--format", format, "--out", str(path)]) == 0
        capsys.readouterr()
        results = []
        for policy, env in ((run_dir, []), (path, []), (path, ["--env", agentax.load(run_dir).env])):
            assert (
                main(["evaluate", "--policy", str(policy), *env, "--episodes", "20", "--seed", "3", "--json"])
                == 0
            )
            results.append(json.loads(capsys.readouterr().out))
        of_run, of_file, with_env = results
        assert of_file["env"] == of_run["env"] and of_file == with_env
        if name == "ppo-cartpole":
            assert (
                of_file["mean_return"] == of_run["mean_return"]
                and of_file["std_return"] == of_run["std_return"]
            )
            assert of_file["min_return"] < of_file["max_return"]  # episodes of different lengths
        else:
            for stat in ("mean_return", "min_return", "max_return"):
                assert of_file[stat] == pytest.approx(of_run[stat], rel=1e-6)


@pytest.mark.xdist_group("export")  # one worker trains the shared runs once
@pytest.mark.slow
def test_export_of_a_cartpole_policy_through_the_cli(runs, tmp_path, capsys):
    """The command line's one line names the file, its size, the card and the time (measured, not
    asserted: the docs state it)."""
    out = tmp_path / "cartpole.onnx"
    assert main(["export", str(runs["ppo-cartpole"]), "--out", str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith(f"wrote {out} ({out.stat().st_size:,} bytes) and {out}.json in ")
    with capsys.disabled():
        print(f"\n{line}")


def no_checkpoint_run(runs, tmp_path):
    folder = tmp_path / "untrained"
    (folder / "checkpoints").mkdir(parents=True)
    (folder / "config.json").write_text((runs["ppo-cartpole"] / "config.json").read_text())
    return folder


@pytest.mark.slow
@pytest.mark.parametrize(
    "argv, message",
    [
        (["export", "{untrained}"], "untrained has no checkpoint in"),
        (["export", "{untrained}", "--format", "stablehlo"], "untrained has no checkpoint in"),
        (
            ["export", "{run}", "--format", "tflite"],
            "unknown export format 'tflite'; choose from onnx, stablehlo",
        ),
        (
            ["export", "{run}", "--stochastic"],
            "--stochastic needs a key input, which ONNX's random operators",
        ),
        (["export", "{tmp}"], "holds no run (no config.json)"),
        (["export", "{tmp}/nowhere", "--format", "stablehlo"], "no run folder at"),
        (["export", "{run}", "--out", "{tmp}/no/such/folder.onnx"], "give a file in an existing folder"),
        (["evaluate", "--policy", "{tmp}/orphan.onnx"], "has no model card beside it"),
        (["evaluate", "--policy", "{tmp}/missing.stablehlo"], "no exported policy at"),
        (["evaluate", "--policy", "{run}/policy.onnx", "--env", "Pendulum-v1"], "cannot read Pendulum-v1's"),
    ],
)
@pytest.mark.slow  # its run comes from the module's trainings
@pytest.mark.xdist_group("export")  # one worker trains the shared runs once
def test_bad_input_is_one_line_and_exit_code_2(runs, tmp_path, argv, message, capsys):
    (tmp_path / "orphan.onnx").write_bytes(b"not a model")
    if not (runs["ppo-cartpole"] / "policy.onnx").is_file():
        agentax.load(runs["ppo-cartpole"]).export()
    names = {"untrained": no_checkpoint_run(runs, tmp_path), "run": runs["ppo-cartpole"], "tmp": tmp_path}
    capsys.readouterr()
    assert main([arg.format(**names) for arg in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"agentax {argv[0]}: error: ") and message in err, err


@pytest.mark.slow  # its run comes from the module's trainings
@pytest.mark.xdist_group("export")  # one worker trains the shared runs once
def test_a_missing_export_extra_names_the_install_command(runs, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "jax2onnx", None)  # import jax2onnx raises ImportError
    assert main(["export", str(runs["ppo-cartpole"]), "--out", str(tmp_path / "p.onnx")]) == 2
    err = capsys.readouterr().err
    assert (
        err.count("\n") == 1
        and "ONNX export needs jax2onnx" in err
        and "pip install 'agentax[export]'" in err
    )
    assert not (tmp_path / "p.onnx").exists()
    assert (
        main(["export", str(runs["ppo-cartpole"]), "--format", "stablehlo", "--out", str(tmp_path / "p")])
        == 0
    )


BREAKOUT = "Breakout-v5"


@pytest.mark.long
@pytest.mark.timeout(600)
def test_a_breakout_cnn_exports_with_its_uint8_frames(tmp_path):
    """A DQN Nature CNN on Breakout (a few hundred steps): the files read uint8 ``[N, 4, 84, 84]``
    stacks and act as agentax's policy on 1,000 observations of the env and 1,000 noise frames
    (where the untrained network picks every action)."""
    run = agentax.train(
        "dqn",
        env=BREAKOUT,
        runner="host",
        out=tmp_path / "breakout",
        progress=False,
        total_steps=256,
        num_envs=4,
        learning_starts=128,
        train_frequency=32,
        gradient_steps=1,
        batch_size=32,
        buffer_size=1_000,
        sticky_actions=0.0,
    )
    frames = env_observations(BREAKOUT)
    noise = np.random.default_rng(1).integers(0, 256, frames.shape, dtype=np.uint8)
    for format in export.FORMATS:
        path = run.export(format=format)
        card = json.loads(export.card_path(path).read_text())
        assert card["inputs"][0] == {"name": "obs", "shape": ["N", 4, 84, 84], "dtype": "uint8"}
        assert card["env_settings"] == {"env_backend": "auto", "sticky_actions": 0.0}
        check_same_actions(path, run.policy, frames, continuous=False)
        assert len(np.unique(check_same_actions(path, run.policy, noise, continuous=False))) > 1
