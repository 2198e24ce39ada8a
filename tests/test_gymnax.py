"""gymnax's envs through agentax's adapter: gymnax's own step, transition for transition, and
training on the compiled runner (vmapped seeds, a sweep)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agentax

gymnax = pytest.importorskip("gymnax")

from agentax.agents.protocol import EnvSpec  # noqa: E402
from agentax.envs.gymnax import GymnaxEnv  # noqa: E402
from agentax.errors import UsageError  # noqa: E402
from agentax.nets import MinAtarCNN  # noqa: E402
from agentax.sweeps import sweep  # noqa: E402


@pytest.mark.slow
@pytest.mark.parametrize("name", ["Breakout-MinAtar", "Asterix-MinAtar", "CartPole-v1", "Catch-bsuite"])
def test_the_adapter_steps_as_gymnax_steps(name):
    """600 random steps from the same keys through gymnax's ``step`` and the adapter's: the same
    observations (flattened), rewards, terminations, truncations and final observations."""
    theirs, params = gymnax.make(name)
    ours = GymnaxEnv(name)
    num_actions = ours.action_space().n
    reset_key, run_key = jax.random.split(jax.random.key(7))
    obs, state = theirs.reset(reset_key, params)
    our_obs, our_state = ours.reset(reset_key, params)
    np.testing.assert_array_equal(our_obs, np.ravel(obs))

    def step(carry, key):
        state, our_state = carry
        action_key, step_key = jax.random.split(key)
        action = jax.random.randint(action_key, (), 0, num_actions)
        obs, state, reward, terminated, truncated, info = theirs.step(step_key, state, action, params)
        ts, our_state = ours.step(step_key, our_state, action, params)
        mine = (ts.obs, ts.reward, ts.terminated, ts.truncated, ts.final_obs)
        gymnax_view = (jnp.ravel(obs), reward, terminated, truncated, jnp.ravel(info["final_observation"]))
        return (state, our_state), (mine, gymnax_view)

    _, (mine, gymnax_view) = jax.jit(
        lambda k: jax.lax.scan(step, (state, our_state), jax.random.split(k, 600))
    )(run_key)
    for got, want in zip(mine, gymnax_view, strict=True):
        np.testing.assert_array_equal(np.asarray(got, np.float32), np.asarray(want, np.float32))
    assert np.asarray(mine[2]).any(), "the steps should reach at least one episode's end"


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
@pytest.mark.timeout(300)
def test_ppo_learns_gymnax_cartpole_on_the_compiled_runner(tmp_path):
    """Two seeds vmapped, made by id through agentax.make: far above random play (~22)."""
    assert isinstance(agentax.make("gymnax/Breakout-MinAtar"), GymnaxEnv)
    run = agentax.train(
        "ppo",
        env="gymnax/CartPole-v1",
        preset="cartpole-fast",
        seeds=2,
        total_steps=20_480,
        stop_at_return=None,
        out=tmp_path / "g",
        progress=False,
    )
    assert min(s["mean_return"] for s in run.final_eval["per_seed"]) > 150, run.final_eval


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
@pytest.mark.timeout(300)
def test_a_sweep_runs_on_a_minatar_game(tmp_path):
    swept = sweep(
        "pqn",
        "gymnax/Breakout-MinAtar",
        grid={"learning_rate": "3e-4,1e-3"},
        seeds=1,
        total_steps=4_096,
        out=tmp_path / "s",
        progress=False,
    )
    assert [row["learning_rate"] for row in swept.settings] == [3e-4, 1e-3]
    assert all(np.isfinite(row["scores"]).all() for row in swept.settings)


@pytest.mark.slow
def test_the_minatar_torso_on_flat_observations_is_the_conv_net_on_gymnax_image():
    """MinAtarCNN on the adapter's flat observations equals MinAtar's network written out with
    ``lax.conv`` on gymnax's own ``[10, 10, 4]`` images (so the reshape undoes the flattening and the
    matrix-product convolution is a convolution), and maps ``[..., 400] -> [..., 128]``."""
    theirs, params = gymnax.make("Breakout-MinAtar")
    ours = GymnaxEnv("Breakout-MinAtar")
    assert ours.image_shape == (10, 10, 4) and EnvSpec.of(ours).image_shape == (10, 10, 4)
    keys = jax.random.split(jax.random.key(3), 6)
    images = jax.vmap(lambda k: theirs.reset(k, params)[0])(keys).astype(jnp.float32)  # (6, 10, 10, 4)
    flat = jax.vmap(lambda k: ours.reset(k, params)[0])(keys)  # (6, 400)
    torso = MinAtarCNN((10, 10, 4))
    variables = torso.init(jax.random.key(0), flat)
    p = variables["params"]
    dims = ("NHWC", "HWIO", "NHWC")
    conv = jax.lax.conv_general_dilated(images, p["conv_kernel"], (1, 1), "VALID", dimension_numbers=dims)
    hidden = jax.nn.relu(conv + p["conv_bias"]).reshape(6, 8 * 8 * 16)
    want = jax.nn.relu(hidden @ p["Dense_0"]["kernel"] + p["Dense_0"]["bias"])
    np.testing.assert_allclose(torso.apply(variables, flat), want, rtol=1e-5, atol=1e-5)
    assert float(jnp.abs(want).sum()) > 0
    assert torso.apply(variables, jnp.zeros((5, 3, 400))).shape == (5, 3, 128)


def test_the_conv_torso_needs_an_image():
    with pytest.raises(UsageError, match="conv_torso"):
        agentax.train("pqn", env="gymnax/CartPole-v1", total_steps=4_096, conv_torso=True, progress=False)


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
@pytest.mark.timeout(300)
def test_pqn_with_the_minatar_torso_learns_breakout_minatar(tmp_path):
    """PQN with MinAtar's conv torso, one seed, 32k agent steps (~10 s of training): greedy returns
    above 1.5, nearly 4x random play (0.40 ± 0.67 over 500 episodes of uniform actions, measured)."""
    run = agentax.train(
        "pqn",
        env="gymnax/Breakout-MinAtar",
        total_steps=32_768,
        conv_torso=True,
        stop_at_return=None,
        out=tmp_path / "c",
        progress=False,
    )
    assert run.config["config"]["conv_torso"]
    assert run.final_eval["mean_return"] > 1.5, run.final_eval


@pytest.mark.slow
def test_ppo_and_pqn_put_the_minatar_torso_before_their_heads():
    """``conv_torso``: PPO's actor and critic share one MinAtarCNN, PQN's Q-head sits on one; both
    map a batch of flat boards to ``[batch, 3]`` (and PPO's values to ``[batch]``)."""
    from agentax.agents import ppo, pqn

    spec = EnvSpec.of(GymnaxEnv("Breakout-MinAtar"))
    obs = jnp.zeros((5, 400))
    actor_critic = ppo.network(ppo.PPOConfig(conv_torso=True), spec)
    params = actor_critic.init(jax.random.key(0), obs)
    assert set(params["params"]) == {"MinAtarCNN_0", "Dense_0", "Dense_1"}  # the torso, the two heads
    assert params["params"]["MinAtarCNN_0"]["conv_kernel"].shape == (3, 3, 4, 16)
    logits, value = actor_critic.apply(params, obs)
    assert logits.shape == (5, 3) and value.shape == (5,)
    q_net = pqn.q_network(pqn.PQNConfig(conv_torso=True), spec)
    q_params = q_net.init(jax.random.key(0), obs)
    assert q_net.apply(q_params, obs).shape == (5, 3)
    assert {"LayerNorm_0", "LayerNorm_1"} <= set(q_params["params"]["layers_0"])  # PQN's LayerNorms
