"""The program cache (agentax.runners.programs): a stored program computes what tracing computes."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax import _xla
from agentax.agents import config_to_dict, ppo, presets
from agentax.envs import make_jax
from agentax.runners import programs
from agentax.runners.compiled import RunnerConfig, compiled_program, train_program

pytestmark = pytest.mark.timeout(240)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("AGENTAX_JAX_CACHE", str(tmp_path / "jax"))
    return tmp_path / "jax" / "agentax-programs"


def make_counted():
    traces = []

    def fn(xs, scale):
        traces.append(1)  # runs only while jax traces fn
        return [x * scale for x in xs], {"total": sum(x.sum() for x in xs)}

    return fn, traces


ARGS = ([jnp.arange(3.0), jnp.ones((2, 2))], 2.0)


def test_second_program_loads_without_tracing(cache):
    fn, traces = make_counted()
    first = programs.jit(fn, ARGS, {"name": "double"})(*ARGS)
    assert len(traces) == 1 and len(list(cache.glob("double-*.jaxexport"))) == 1
    fn, traces = make_counted()
    second = programs.jit(fn, ARGS, {"name": "double"})(*ARGS)
    assert traces == []  # loaded from disk, never traced
    expected = jax.jit(fn)(*ARGS)
    for a, b, c in zip(
        jax.tree.leaves(first), jax.tree.leaves(second), jax.tree.leaves(expected), strict=True
    ):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, c)


def test_fingerprint_follows_description_and_shapes():
    base = programs.fingerprint({"algo": "ppo"}, ARGS)
    assert base == programs.fingerprint({"algo": "ppo"}, ARGS)
    assert base != programs.fingerprint({"algo": "dqn"}, ARGS)
    assert base != programs.fingerprint({"algo": "ppo"}, ([jnp.arange(4.0), jnp.ones((2, 2))], 2.0))
    assert base != programs.fingerprint({"algo": "ppo"}, ([jnp.arange(3), jnp.ones((2, 2))], 2.0))


def test_damaged_program_is_traced_again(cache):
    fn, _ = make_counted()
    programs.jit(fn, ARGS, {"name": "double"})(*ARGS)
    (path,) = cache.glob("double-*.jaxexport")
    path.write_bytes(b"not a program")
    fn, traces = make_counted()
    out, _ = programs.jit(fn, ARGS, {"name": "double"})(*ARGS)
    assert len(traces) == 1
    np.testing.assert_array_equal(out[0], [0.0, 2.0, 4.0])
    assert path.read_bytes() != b"not a program"  # replaced by a good one


def test_no_description_or_no_cache_means_plain_jit(cache, monkeypatch):
    fn, traces = make_counted()
    programs.jit(fn, ARGS, None)(*ARGS)
    monkeypatch.setenv("AGENTAX_JAX_CACHE", "none")
    other_fn, other_traces = make_counted()
    programs.jit(other_fn, ARGS, {"name": "double"})(*ARGS)
    assert len(traces) == 1 and len(other_traces) == 1 and not cache.exists()


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
def test_runner_gives_the_same_training_from_stored_programs(cache):
    """Traced, exported then loaded: three trainings of two PPO seeds, metric for metric identical."""
    env = make_jax("CartPole-v1")
    cfg = dataclasses.replace(presets.preset("ppo", "cartpole-fast").config, total_steps=4 * 256)
    runner = RunnerConfig(seed=3, num_seeds=2, updates_per_chunk=2, eval_episodes=3)
    description = {"algo": "ppo", "env": "CartPole-v1", "config": config_to_dict(cfg)}
    traced = train_program(compiled_program(ppo, env, cfg), env, runner)
    exported = train_program(compiled_program(ppo, env, cfg), env, runner, program_description=description)
    assert sorted(p.name.split("-")[0] for p in cache.glob("*.jaxexport")) == ["chunk", "init"]
    loaded = train_program(compiled_program(ppo, env, cfg), env, runner, program_description=description)
    for other in (exported, loaded):
        assert [row["mean_return"] for row in other.rows] == [row["mean_return"] for row in traced.rows]
        assert [row["policy_loss"] for row in other.rows] == [row["policy_loss"] for row in traced.rows]
        untimed = lambda evaluation: {k: v for k, v in evaluation.items() if not k.endswith("_seconds")}
        assert untimed(other.eval) == untimed(traced.eval)


def test_only_the_newest_programs_are_kept(cache, monkeypatch):
    monkeypatch.setattr(programs, "KEEP", 2)
    for n in range(3):
        fn, _ = make_counted()
        programs.jit(fn, ARGS, {"name": "double", "n": n})(*ARGS)
    assert len(list(cache.glob("*.jaxexport"))) == 2


def test_a_cache_folder_that_cannot_be_made_only_costs_the_cache(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("AGENTAX_JAX_CACHE", str(blocker / "cache"))  # mkdir fails under a file
    assert _xla.enable_compilation_cache() is None
    fn, traces = make_counted()
    out, totals = programs.jit(fn, ARGS, {"name": "double"})(*ARGS)
    np.testing.assert_array_equal(out[0], [0.0, 2.0, 4.0])
    assert float(totals["total"]) == 7.0 and len(traces) == 1
