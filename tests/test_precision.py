"""Mixed precision (``--precision``): bfloat16 operands with float32 sums inside the networks'
products, float32 everywhere else; every agent takes it, the float32 path traces as before, ``auto``
chooses by measurement (never by a CPU flag), the CLI refuses a bad value, the run folder records
the precision, and a bf16 SAC learns Pendulum."""

from __future__ import annotations

import json
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax import kernel_choice, kernels
from agentax.agents import ALGORITHMS, algorithm, presets
from agentax.agents.protocol import EnvSpec
from agentax.api import train
from agentax.cli import main
from agentax.envs import make_jax
from agentax.errors import UsageError
from agentax.nets import MLP, dense_layer
from agentax.runners.compiled import RunnerConfig, program_of, train_program
from agentax.runners.launch import agent_maker, network_width, precision_of
from agentax.runs import read_config

BF16 = jnp.bfloat16


def rounded(x: jax.Array) -> jax.Array:
    """``x`` rounded to bfloat16 and back to float32."""
    return x.astype(BF16).astype(jnp.float32)


def test_a_bf16_product_rounds_its_operands_sums_in_float32_and_returns_float32():
    kx, kw, kg = jax.random.split(jax.random.key(0), 3)
    x, w = jax.random.normal(kx, (4, 5, 64)), jax.random.normal(kw, (64, 32))
    got = kernels.matmul(x, w, "bf16")
    assert got.dtype == jnp.float32 and got.shape == (4, 5, 32)
    # the product of the rounded operands, summed in float32: equal up to the order of the sums
    np.testing.assert_allclose(got, rounded(x) @ rounded(w), rtol=1e-5, atol=1e-5)
    assert not np.array_equal(got, x @ w)  # the rounding happened
    assert np.array_equal(kernels.matmul(x, w, "f32"), x @ w)  # f32: XLA's product exactly
    # the gradients are float32 and are the rounded operands' (the incoming gradient rounded too)
    g = jax.random.normal(kg, (4, 5, 32))
    dx, dw = jax.grad(lambda x, w: (kernels.matmul(x, w, "bf16") * g).sum(), argnums=(0, 1))(x, w)
    assert dx.dtype == dw.dtype == jnp.float32
    np.testing.assert_allclose(dx, rounded(g) @ rounded(w).T, rtol=1e-5, atol=1e-5)
    expected_dw = rounded(x).reshape(-1, 64).T @ rounded(g).reshape(-1, 32)
    np.testing.assert_allclose(dw, expected_dw, rtol=1e-5, atol=1e-4)


@pytest.mark.skipif(not kernels.available(), reason="the oneDNN kernel is not built here")
def test_onednns_bf16_product_and_gradients_are_the_float32_ones_to_bf16s_precision_also_per_seed():
    """``bf16-onednn``: oneDNN's matmul with bfloat16 arithmetic allowed (it keeps float32 where its
    bf16 kernels do not pay, e.g. a few rows), under vmap (a seed's own weights) too, and
    differentiable. XLA's export precision for it is ``bf16``."""
    kx, kw, kg = jax.random.split(jax.random.key(3), 3)
    x, w, g = (
        jax.random.normal(kx, (3, 5, 64)),
        jax.random.normal(kw, (3, 64, 32)),
        jax.random.normal(kg, (3, 5, 32)),
    )

    def loss(precision):
        product = jax.vmap(lambda x, w: kernels.matmul(x, w, precision))
        return jax.jit(jax.value_and_grad(lambda x, w: (product(x, w) * g).sum(), argnums=(0, 1)))

    (value, (dx, dw)), (want, (want_dx, want_dw)) = loss("bf16-onednn")(x, w), loss("f32")(x, w)
    assert "agentax_matmul" in loss("bf16-onednn").lower(x, w).as_text()  # oneDNN's call, not XLA's dot
    for got, expected in ((value, want), (dx, want_dx), (dw, want_dw)):  # bf16 keeps 8 bits of mantissa
        np.testing.assert_allclose(got, expected, rtol=2e-2, atol=0.1)
    assert kernels.exportable("bf16-onednn") == "bf16" and kernels.exportable("f32") == "f32"


def test_a_kept_choice_is_measured_again_once_a_new_candidate_can_run(tmp_path):
    amx = ("Intel(R) Xeon(R) Processor", frozenset({"amx_bf16"}))
    question, path, calls = kernel_choice.precision_question(64), tmp_path / "kernels.json", []

    def timer(runnable, batch):  # the last candidate the fastest
        calls.append(list(runnable))
        return {name: 1.0 + i for i, name in enumerate(reversed(runnable))}, {}

    def choose(runnable):
        return kernel_choice.resolve(runnable, {}, path=path, cpu=amx, timer=timer, question=question)

    three = ["f32", "bf16", "bf16-onednn"]
    first, kept, again = choose(["f32", "bf16"]), choose(["f32", "bf16"]), choose(three)
    assert (first["source"], kept["source"], again["source"]) == ("measured", "kept", "measured")
    assert calls == [["f32", "bf16"], three] and again["backend"] == "bf16-onednn"


def test_a_bf16_dense_layer_keeps_float32_parameters_and_outputs():
    x = jax.random.normal(jax.random.key(1), (8, 17))
    for precision in ("f32", "bf16"):
        layer = dense_layer(6, precision)
        params = layer.init(jax.random.key(0), x)
        assert all(leaf.dtype == jnp.float32 for leaf in jax.tree.leaves(params))
        assert layer.apply(params, x).dtype == jnp.float32
    with pytest.raises(UsageError, match="unknown precision 'f16'; choose from f32, bf16"):
        kernels.matmul(x, x.T, "f16")


def test_f32_networks_trace_exactly_as_flax_dense_layers():
    """The f32 path hands flax no ``dot_general`` of its own: the same program, bit for bit."""
    import flax.linen as nn

    class Plain(nn.Module):
        @nn.compact
        def __call__(self, x):
            hidden = nn.elu(nn.Dense(16)(x))
            return nn.Dense(3)(hidden)

    x = jax.random.normal(jax.random.key(2), (5, 7))
    params = Plain().init(jax.random.key(0), x)
    ours = MLP((16,), out=3, precision="f32")
    assert str(jax.make_jaxpr(ours.apply)(params, x)) == str(jax.make_jaxpr(Plain().apply)(params, x))
    assert np.array_equal(ours.apply(params, x), Plain().apply(params, x))


SPECS = {
    "cartpole": EnvSpec.of(make_jax("CartPole-v1")),
    "pendulum": EnvSpec.of(make_jax("Pendulum-v1")),
}
ENV_OF = {"sac": "pendulum", "td3": "pendulum"}


@pytest.mark.parametrize("algo", sorted(ALGORITHMS))
def test_every_agent_acts_in_its_precision_with_float32_parameters(algo):
    spec = SPECS[ENV_OF.get(algo, "cartpole")]
    cfg = presets.preset(algo, "default").config
    obs = jnp.zeros((2, *spec.obs_shape), spec.obs_dtype)
    programs = {}
    for precision in ("f32", "bf16"):
        agent = algorithm(algo).make_agent(spec, cfg, precision=precision)
        state = jax.eval_shape(agent.init, jax.random.key(0))  # traced, not run
        assert all(leaf.dtype != BF16 for leaf in jax.tree.leaves(state))
        programs[precision] = str(jax.make_jaxpr(agent.act)(state, obs, jax.random.key(1), jnp.int32(0)))
    assert "bf16" not in programs["f32"]
    assert "bf16" in programs["bf16"] and "preferred_element_type=float32" in programs["bf16"]


def test_auto_measures_and_never_guesses_from_cpu_flags(tmp_path):
    amx = ("Intel(R) Xeon(R) Processor", frozenset({"amx_bf16", "avx512_bf16"}))
    question = kernel_choice.precision_question(64)
    path = tmp_path / "kernels.json"
    unmeasured = kernel_choice.resolve(
        ["f32", "bf16"], {}, path=path, cpu=amx, measuring=False, question=question
    )
    assert unmeasured["backend"] == "f32" and unmeasured["source"] == "unmeasured"

    def timer(runnable, batch):
        assert batch == kernel_choice.PRECISION_BATCH
        return {"f32": 2.0, "bf16": 1.5}, {}

    measured = kernel_choice.resolve(["f32", "bf16"], {}, path=path, cpu=amx, timer=timer, question=question)
    assert measured["backend"] == "bf16" and measured["source"] == "measured"
    assert "2 hidden layers of 64" in measured["fields"]["shape"]
    slower = kernel_choice.resolve(
        ["f32", "bf16"],
        {},
        path=path,
        cpu=amx,
        timer=lambda r, b: ({"f32": 1.0, "bf16": 1.5}, {}),
        question=kernel_choice.precision_question(32),
    )
    assert slower["backend"] == "f32"  # another width is another measurement, its own choice
    kept = kernel_choice.resolve(["f32", "bf16"], {}, path=path, cpu=amx, measuring=False, question=question)
    assert kept["backend"] == "bf16" and kept["source"] == "kept"
    assert kernel_choice.precision_choice("bf16")["precision"] == "bf16"


def test_the_measured_width_is_the_configs_widest_hidden_layer():
    assert network_width(presets.preset("sac", "default").config) == 256
    assert network_width(presets.preset("reinforce", "default").config) == 32  # baseline_hidden (32,)


@pytest.mark.parametrize("value", ["f16", "BF16", "fp32"])
def test_a_bad_precision_is_one_line_and_exit_code_2(value, capsys):
    assert main(["train", "ppo", "--precision", value, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert f"--precision must be one of auto, f32, bf16, bf16-onednn, got '{value}'" in err


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_bf16_ppo_solves_cartpole_and_its_folder_records_the_precision(tmp_path):
    """The ``cartpole-fast`` preset in bf16 solves CartPole-v1 (it stops at the solved threshold, as
    in float32); config.json and run.toml say bf16, and the restored policy (in bf16) plays well."""
    out = tmp_path / "run"
    run = train("ppo", "CartPole-v1", out=out, progress=False, precision="bf16")
    config = json.loads((out / "config.json").read_text())
    assert config["precision"] == "bf16" and config["precision_choice"]["mode"] == "bf16"
    assert tomllib.loads((out / "run.toml").read_text())["precision"] == "bf16"
    assert run.final_eval["mean_return"] >= 400, run.final_eval
    assert run.evaluate(episodes=4).mean_return >= 400
    # a folder written before precisions were recorded trained in float32, and loads so
    del config["precision"], config["precision_choice"]
    (out / "config.json").write_text(json.dumps(config))
    assert precision_of(read_config(out)) == "f32"


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.timeout(300)
def test_a_bf16_sac_learns_pendulum():
    """Two bf16 seeds from random swings (about −1,200) to upright in 5,000 steps: what
    tests/test_actor_critic.py asks of the float32 SAC (~60 s on 2 shared cores: make test-long;
    benchmarks/bench_precision.py compares both precisions' seeds)."""
    overrides = {"hidden": (64, 64), "total_steps": 5_000, "learning_starts": 500}
    cfg = presets.preset("sac", "pendulum", **overrides).config
    runner = RunnerConfig(seed=0, num_seeds=2, updates_per_chunk=1_000, eval_episodes=10)
    env = make_jax("Pendulum-v1")
    agent = agent_maker(algorithm("sac"), EnvSpec.of(env), cfg, precision="bf16")()
    result = train_program(program_of(agent, env, runner), env, runner)
    assert result.rows[0]["mean_return"] < -900, result.rows[0]
    assert min(result.eval["per_seed_mean"]) > -400, result.eval
