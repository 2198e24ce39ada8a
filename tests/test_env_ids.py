"""Env ids (issue 39): an id goes to agentax's JAX envs only where agentax registers it; an unknown,
misspelt or deprecated id is one line with the closest ids of both and Gymnasium's own message."""

import pytest

from agentax.cli import main
from agentax.envs import GymnasiumEnv, host_env_id, make
from agentax.envs.core import Environment
from agentax.runners import kind_for


@pytest.mark.parametrize(
    ("env_id", "pieces"),
    [
        (
            "Taxi-v3",
            [
                "did you mean Taxi-v4 (Gymnasium)?",
                "Gymnasium says: Environment version v3 for `Taxi` is deprecated",
            ],
        ),
        (
            "HalfCheetah-v9",
            ["HalfCheetah-v5", "Gymnasium says: Environment version `v9` for environment `HalfCheetah`"],
        ),
        (
            "CartPol-v1",
            ["did you mean CartPole-v1", "(agentax), CartPole-v1", "Environment `CartPol` doesn't exist"],
        ),
    ],
)
def test_an_unknown_id_names_the_closest_ids_and_gymnasiums_own_word(env_id, pieces, capsys, tmp_path):
    assert main(["train", "ppo", "--env", env_id, "--out", str(tmp_path / "run"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"agentax train: error: unknown env '{env_id}'; ") and err.count("\n") == 1, err
    assert all(piece in err for piece in pieces), err
    assert "agentax/" not in err and "namespace agentax" not in err
    assert not (tmp_path / "run").exists()


def test_ids_route_to_agentax_only_where_agentax_registers_them():
    assert isinstance(make("CartPole-v1"), Environment) and isinstance(make("Pendulum-v1"), Environment)
    assert kind_for("auto", "CartPole-v1") == kind_for("auto", "Pendulum-v1") == "compiled"
    assert kind_for("auto", "Acrobot-v1") == kind_for("auto", "MountainCar-v0") == "host"
    env = make("Acrobot-v1")
    assert isinstance(env, GymnasiumEnv) and env.id == "Acrobot-v1"
    env.close()
    assert host_env_id("MountainCar-v0") == "MountainCar-v0"
    assert host_env_id("CartPole-v1") == "CartPole-v1"  # Gymnasium's own, step-for-step equal
    assert host_env_id("Vacuum-v0") == "agentax/Vacuum-v0"  # only agentax has it


def test_a_jax_only_env_on_the_host_says_which_runner_takes_it(capsys):
    assert main(["train", "ppo", "--env", "gymnax/CartPole-v1", "--runner", "host"]) == 2
    err = capsys.readouterr().err
    assert "gymnax/CartPole-v1 steps only inside a compiled program: train it with --runner compiled" in err
