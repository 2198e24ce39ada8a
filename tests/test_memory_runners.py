"""A recurrent agent on the runners that step envs on the host: the host actor carries each env's
memory across rollouts and records it as the compiled runner does, a resumed host run continues its
episodes from the checkpoint, the parallel runner carries memory too, and the refusal elsewhere."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.agents import ppo, presets
from agentax.agents.protocol import EnvSpec
from agentax.cli import main
from agentax.envs import make_host_env
from agentax.envs.core import RecurrentPolicy
from agentax.errors import UsageError
from agentax.policies import with_random_actions
from agentax.runners import RUNNERS, Runner, host, launch, parallel
from agentax.runners.host import Actor, HostRunnerConfig
from agentax.runners.host_memory import ACTORS_PREFIX
from agentax.runners.parallel import ParallelRunnerConfig
from agentax.runs import Run

NOVEL = "CartPoleNoVel-v1"  # an agentax JAX env: on the host through Gymnasium, its state can be saved


def spec_of(env_id: str) -> EnvSpec:
    env = make_host_env(env_id, 1)
    spec = EnvSpec.of(env)
    env.close()
    return spec


def small(core: str = "lstm", **changes) -> ppo.PPOConfig:
    base = ppo.PPOConfig(
        num_envs=2,
        num_steps=16,
        core=core,
        core_size=8,
        hidden=(8,),
        total_steps=128,
        bptt=8,
        num_minibatches=2,
    )
    return dataclasses.replace(base, **changes)


@pytest.fixture(scope="module")
def agent():
    return ppo.make_agent(spec_of(NOVEL), small())


def assert_same_trees(a, b):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_the_actor_carries_each_envs_memory_across_rollouts_and_marks_episode_starts(agent):
    """As the compiled runner's ``RecurrentCarry``: ``info["first"]`` is true at the start and after
    every step that ended an episode, ``info["memory"]`` is the memory the previous step made (zeros
    at the start), from one rollout to the next; where ``first``, the core starts from fresh memory."""
    state = jax.jit(agent.init)(jax.random.key(0))
    actor = Actor(agent, make_host_env(NOVEL, 2), seed=5, key=jax.random.key(1))
    try:
        rollouts = [actor.rollout(state, 16) for _ in range(3)]
    finally:
        actor.close()
    first = np.concatenate([r.info["first"] for r in rollouts])  # (48, 2)
    ended = np.concatenate([r.terminated | r.truncated for r in rollouts])
    memory = jax.tree.map(lambda *m: np.concatenate(m), *[r.info["memory"] for r in rollouts])
    obs = np.concatenate([r.obs for r in rollouts])
    assert first[0].all() and (first[1:] == ended[:-1]).all()
    assert 2 <= ended.sum() and first[1:].any()  # episodes of random play end within 48 steps
    assert all((leaf[0] == 0).all() for leaf in jax.tree.leaves(memory))
    act = jax.jit(agent.recurrent.act)
    fresh = agent.recurrent.initial(2)
    for t in range(len(first) - 1):  # the memory each step received is the one the step before made
        stored = jax.tree.map(lambda m, t=t: m[t], memory)
        made, _, _ = act(state, stored, obs[t], first[t], jax.random.key(t), 0)
        assert_same_trees(made, jax.tree.map(lambda m, t=t: m[t + 1], memory))
        from_fresh, _, _ = act(state, fresh, obs[t], first[t], jax.random.key(t), 0)
        for leaf_made, leaf_fresh in zip(jax.tree.leaves(made), jax.tree.leaves(from_fresh), strict=True):
            np.testing.assert_array_equal(np.asarray(leaf_made)[first[t]], np.asarray(leaf_fresh)[first[t]])


@pytest.mark.slow
def test_ppo_with_a_core_trains_on_the_host_runner_from_the_command_line(tmp_path):
    out = tmp_path / "run"
    argv = ["train", "ppo", "--env", NOVEL, "--core", "gru", "--core-size", "8", "--runner", "host"]
    argv += [
        "--num-envs",
        "2",
        "--num-steps",
        "16",
        "--total-steps",
        "64",
        "--out",
        str(out),
        "--no-progress",
    ]
    command = [sys.executable, "-m", "agentax.cli", *argv]
    done = subprocess.run(command, capture_output=True, text=True, timeout=200)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "jax's CPU client already exists" not in done.stderr  # the host runner's client came first
    assert (out / "eval.json").is_file() and (out / "metrics.csv").is_file()
    assert {p.name for p in (out / "checkpoints").iterdir()} == {
        "ckpt-2.msgpack",
        f"{ACTORS_PREFIX}2.msgpack",
    }


@pytest.mark.slow
@pytest.mark.parametrize(
    "algo_args",
    [
        ["pqn", "--num-envs", "2", "--num-steps", "16", "--num-minibatches", "2"],
        ["reinforce", "--episodes-per-update", "2", "--max-steps", "32"],
    ],
    ids=["pqn", "reinforce"],
)
def test_pqn_and_reinforce_with_a_core_train_on_the_host_runner(algo_args, tmp_path):
    out = tmp_path / "run"
    argv = ["train", *algo_args, "--env", NOVEL, "--core", "gru", "--core-size", "8", "--runner", "host"]
    assert main([*argv, "--total-steps", "64", "--out", str(out), "--no-progress"]) == 0
    assert (out / "eval.json").is_file() and (out / "metrics.csv").is_file()


class Cut(Exception):
    """Stops a run right after a checkpoint, as a killed process would."""


def cut_after(monkeypatch, checkpoints: int) -> None:
    save = Run.save_checkpoint
    saved = []

    def save_then_cut(self, updates, tree, meta, keep=3):
        path = save(self, updates, tree, meta, keep)
        saved.append(path)
        if len(saved) == checkpoints:
            raise Cut
        return path

    monkeypatch.setattr(Run, "save_checkpoint", save_then_cut)


@pytest.mark.slow
@pytest.mark.parametrize(("env_id", "continued"), [(NOVEL, True), ("CartPole-v1", False)])
def test_a_resumed_host_run_continues_its_episodes_with_their_memory(
    env_id, continued, tmp_path, monkeypatch
):
    """Cut after its second checkpoint and resumed, a run on an env whose state can be saved ends with
    the numbers of the run never cut: its envs, their memory and ``first`` flags and the actor's key
    came back with the checkpoint. A Gymnasium env's state cannot be saved: the resumed run restarts
    its envs and their memory (and still finishes)."""
    agent = ppo.make_agent(spec_of(env_id), small())
    runner = HostRunnerConfig(seed=1, log_every_steps=32, checkpoint_every_seconds=0.0, eval_episodes=2)
    config = {"algo": "ppo", "env": env_id}
    whole = host.train(agent, env_id, runner, Run.create(tmp_path / "whole", config))
    run = Run.create(tmp_path / "cut", config)
    with monkeypatch.context() as patch:
        cut_after(patch, 2)
        with pytest.raises(Cut):
            host.train(agent, env_id, runner, run)
    saved = sorted(p.name for p in (run.path / "checkpoints").glob(f"{ACTORS_PREFIX}*"))
    assert saved == ([f"{ACTORS_PREFIX}1.msgpack", f"{ACTORS_PREFIX}2.msgpack"] if continued else [])
    resumed = host.train(agent, env_id, runner, run, resume=True)
    assert resumed.updates == whole.updates == 4
    if continued:
        assert_same_trees(resumed.state, whole.state)
        assert [r["mean_return"] for r in resumed.rows] == [r["mean_return"] for r in whole.rows[2:]]
    else:
        assert not all(
            np.array_equal(a, b)
            for a, b in zip(jax.tree.leaves(resumed.state), jax.tree.leaves(whole.state), strict=True)
        )


@pytest.mark.slow
def test_the_parallel_runner_carries_memory_and_gives_the_host_runners_numbers_at_lag_0(agent):
    """Each actor thread carries its envs' memory (its rollouts' ``info["memory"]`` are what its own
    parameters made); with one actor and lag 0 that is the host run, number for number; at lag 1
    with two actors it runs its two updates."""
    settings = {"seed": 2, "eval_episodes": 2}
    on_host = host.train(agent, NOVEL, HostRunnerConfig(**settings))
    in_thread = parallel.train(agent, NOVEL, ParallelRunnerConfig(**settings, actors=1, policy_lag=0))
    assert on_host.updates == in_thread.updates == 4
    assert_same_trees(on_host.state, in_thread.state)
    two_updates = ppo.make_agent(spec_of(NOVEL), small(total_steps=64))
    lagged = parallel.train(two_updates, NOVEL, ParallelRunnerConfig(**settings, actors=2, policy_lag=1))
    assert lagged.updates == 2 and np.isfinite(lagged.rows[-1]["policy_loss"])


def test_a_runner_that_does_not_carry_memory_refuses_a_core_in_one_line(agent, monkeypatch):
    """Every runner carries memory today; one that did not (``carries_memory`` False, the default
    of a new row) would refuse a core in one line, naming those that do on any env."""
    for kind in RUNNERS:
        launch.check_memory_carried(agent, kind)
    monkeypatch.setitem(RUNNERS, "elsewhere", Runner("agentax.runners.host", "any", "host"))
    with pytest.raises(UsageError) as refused:
        launch.check_memory_carried(agent, "elsewhere")
    message = str(refused.value)
    assert "\n" not in message and "not on the elsewhere runner" in message
    assert "--runner host or parallel or ray" in message


@pytest.mark.slow
def test_an_actor_file_that_does_not_load_restarts_the_envs_with_a_note(tmp_path, monkeypatch, capsys):
    agent = ppo.make_agent(spec_of(NOVEL), small())
    runner = HostRunnerConfig(seed=1, log_every_steps=32, checkpoint_every_seconds=0.0, eval_episodes=2)
    run = Run.create(tmp_path / "cut", {"algo": "ppo", "env": NOVEL})
    with monkeypatch.context() as patch:
        cut_after(patch, 2)
        with pytest.raises(Cut):
            host.train(agent, NOVEL, runner, run)
    (run.path / "checkpoints" / f"{ACTORS_PREFIX}2.msgpack").write_bytes(b"cut short")
    resumed = host.train(agent, NOVEL, runner, run, resume=True)
    assert resumed.updates == 4
    err = capsys.readouterr().err
    assert "actors-2.msgpack is corrupt" in err and "the envs restart, and their memory with them" in err


@pytest.mark.long  # ~55 s on 2 shared cores: make test-long
@pytest.mark.timeout(600)
def test_an_lstm_learns_cartpole_novel_on_the_host_runner():
    """Preset ``memory`` on the host runner at its former lr 3e-3, 61,440 steps (seed 0 measured: 23
    at the first row, 500 from 47,104 steps on, 20 evaluation episodes 475): far above what no memory
    reaches (44, its preset's note)."""
    cfg = dataclasses.replace(presets.preset("ppo", "memory").config, total_steps=61_440, learning_rate=3e-3)
    result = host.train(ppo.make_agent(spec_of(NOVEL), cfg), NOVEL, HostRunnerConfig(seed=0))
    assert result.rows[0]["mean_return"] < 40 and result.eval["mean_return"] >= 300, (
        result.rows[0]["mean_return"],
        result.eval["mean_return"],
    )


def test_atari_evaluations_random_actions_keep_a_policy_with_memory(agent):
    """The host runners evaluate Atari games with ε of random actions (``with_random_actions``): a
    recurrent policy stays one, its memory taking in every observation whichever action is played."""
    policy = agent.greedy_policy(jax.jit(agent.init)(jax.random.key(0)))
    obs, key = jnp.array([0.1, -0.2]), jax.random.key(3)
    memory, action = policy.step(policy.initial(), obs, jax.random.split(key, 3)[2])
    for epsilon in (0.0, 1.0):
        mixed = with_random_actions(policy, epsilon, 2)
        assert isinstance(mixed, RecurrentPolicy)
        mixed_memory, mixed_action = jax.jit(mixed.step)(mixed.initial(), obs, key)
        assert_same_trees(mixed_memory, memory)
        if epsilon == 0.0:
            assert mixed_action == action
    actions = {int(jax.jit(mixed.step)(mixed.initial(), obs, jax.random.key(k))[1]) for k in range(20)}
    assert actions == {0, 1}  # ε = 1: uniformly random
