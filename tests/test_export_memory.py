"""Issue 42, item 4: a recurrent policy (PPO ``--core gru|lstm``) exported with its state: the ONNX
file and the StableHLO module take ``(obs, state)`` and return ``(action, next_state)``, and stepped
with their own state, zeros at each episode start, they act as the agent's greedy policy."""

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import OnDemand
from jax.flatten_util import ravel_pytree

import agentax
from agentax import export
from agentax.cli import main
from agentax.envs import make_jax
from agentax.envs.core import RecurrentPolicy, batched_policy

ENV = "CartPoleNoVel-v1"
ENVS, STEPS = 4, 250  # 1,000 steps of the agent's episode stream
TINY = {  # a high learning rate: in 1,024 steps the greedy policy turns both ways (at 3e-3 it pushes
    # one way only, episodes of ~9 steps)
    "core_size": 16,
    "hidden": (16,),
    "total_steps": 1024,
    "num_envs": 4,
    "num_steps": 32,
    "learning_rate": 3e-2,
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A tiny run on CartPoleNoVel by core (gru, lstm), trained through the API when first asked for."""
    root = tmp_path_factory.mktemp("export-memory")

    def train(core: str) -> Path:
        return agentax.train(
            "ppo", env=ENV, out=root / core, progress=False, stop_at_return=None, core=core, **TINY
        ).path

    return OnDemand(train)


def agent_stream(policy: RecurrentPolicy, key: int = 0) -> dict[str, np.ndarray]:
    """The agent's greedy policy played on ``ENVS`` envs for ``STEPS`` steps, each env's memory reset
    where an episode starts (as the agent's evaluation does): ``obs [T, E, 2]``, ``first [T, E]``,
    ``action [T, E]`` and the flat memory after each step ``memory [T, E, S]``."""
    env = make_jax(ENV)
    params = env.default_params()
    memory, act = batched_policy(policy, ENVS)

    def step(carry, t):
        memory, obs, state, first = carry
        keys = jax.random.split(jax.random.fold_in(jax.random.key(key), t), ENVS)
        memory, action = act(memory, obs, keys, first)
        ts, state = jax.vmap(env.step, in_axes=(0, 0, 0, None))(keys, state, action, params)
        flat = jax.vmap(lambda m: ravel_pytree(m)[0])(memory)
        return (memory, ts.obs, state, ts.done), {
            "obs": obs,
            "first": first,
            "action": action,
            "memory": flat,
        }

    def play():
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(
            jax.random.split(jax.random.key(key), ENVS), params
        )
        start = (memory, obs, state, jnp.ones(ENVS, bool))
        return jax.lax.scan(step, start, jnp.arange(STEPS))[1]

    return jax.tree.map(np.asarray, jax.jit(play)())


def file_stream(exported: export.Exported, stream: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The exported file stepped on the stream's observations with its own state, zeros where
    ``first``: its actions ``[T, E]`` and its state after each step ``[T, E, S]``."""
    state, actions, states = exported.initial_state(ENVS), [], []
    for obs, first in zip(stream["obs"], stream["first"], strict=True):
        state = np.where(first[:, None], 0.0, state).astype(np.float32)
        action, state = exported.run(obs, state)
        actions.append(action)
        states.append(state)
    return np.stack(actions), np.stack(states)


@pytest.mark.slow  # two tiny compiled trainings (~25 s on 2 idle cores) and four conversions
@pytest.mark.timeout(300)
@pytest.mark.parametrize("core", ["gru", "lstm"])
def test_the_exported_state_steps_as_the_agents_memory(runs, core, tmp_path):
    """Over 1,000 steps of the agent's own episodes (resets crossed), both formats give its greedy
    actions exactly and its memory within 1e-5 (or 2e-6 of its size); the card says the state's
    shape, parts and start."""
    run = agentax.load(runs[core])
    stream = agent_stream(run.policy)
    episodes = int(stream["first"].sum())
    assert episodes > ENVS and 0.1 < stream["action"].mean() < 0.9  # resets inside, both actions
    size = 2 * 16 if core == "lstm" else 16
    for format in export.FORMATS:
        path = run.export(tmp_path / f"policy{export.FORMATS[format]}", format)
        exported = export.load(path)
        actions, states = file_stream(exported, stream)
        np.testing.assert_array_equal(actions, stream["action"])
        # an LSTM's cell state is unbounded (|c| near 20 in some runs, where float32's spacing is 2e-6):
        # within 1e-5, or a few of float32's steps of its size
        np.testing.assert_allclose(states, stream["memory"], rtol=2e-6, atol=1e-5)
        card = exported.card
        assert [i["name"] for i in card["inputs"]] == ["obs", "state"]
        assert card["outputs"][1] == {"name": "next_state", "shape": ["N", size], "dtype": "float32"}
        assert card["state"]["shape"] == ["N", size] and card["state"]["initial"] == "zeros"
        parts = [(p["name"], p["start"], p["size"]) for p in card["state"]["parts"]]
        assert parts == ([("c", 0, 16), ("h", 16, 16)] if core == "lstm" else [("h", 0, 16)])
    # without its state fed back the file forgets: its memory strays from the agent's
    _, forgetful = file_stream(exported, {**stream, "first": np.ones_like(stream["first"])})
    assert np.abs(forgetful - stream["memory"]).max() > 0.05


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_evaluate_a_recurrent_file_gives_the_runs_evaluation(runs, tmp_path, capsys):
    """``agentax evaluate --policy FILE`` carries the file's state through each episode: the same
    returns as ``--policy RUN_DIR``; ``--stochastic`` of a recurrent run is one line, exit code 2."""
    path = tmp_path / "gru.onnx"
    assert main(["export", str(runs["gru"]), "--out", str(path)]) == 0
    capsys.readouterr()
    results = []
    for policy in (runs["gru"], path):
        assert main(["evaluate", "--policy", str(policy), "--episodes", "8", "--seed", "3", "--json"]) == 0
        results.append(json.loads(capsys.readouterr().out))
    assert results[1]["mean_return"] == results[0]["mean_return"]
    assert results[1]["std_return"] == results[0]["std_return"]
    stablehlo = ["export", str(runs["gru"]), "--format", "stablehlo", "--stochastic"]
    assert main([*stablehlo, "--out", str(tmp_path / "s.stablehlo")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "has a recurrent core" in err, err
