"""The rest of Rainbow as DQN options: C51's projection and loss by hand, noisy layers, DrQ's random
shifts, the combined agent learning CartPole and the data-efficient Rainbow preset on frames."""

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.agents import dqn, presets
from agentax.agents.protocol import EnvSpec
from agentax.envs import make_host_env, make_jax
from agentax.envs.core import Discrete
from agentax.errors import UsageError
from agentax.nets import NoisyDense, factorised_noise, random_shift, scaled_noise, shift
from agentax.replay import ReplaySample, Transition
from agentax.runners import host
from agentax.runners.compiled import compiled_program
from agentax.runners.host import HostRunnerConfig

Z3 = jnp.array([-1.0, 0.0, 1.0])
P3 = jnp.array([0.2, 0.5, 0.3])


@pytest.mark.slow
@pytest.mark.parametrize("wrap", [lambda f: f, jax.jit], ids=["plain", "jit"])
def test_categorical_projection_by_hand(wrap):
    project = wrap(dqn.categorical_projection)
    # r 0.5, discount 0.5: atoms 0.5 + 0.5 · [-1, 0, 1] = [0, 0.5, 1]; 0.2 all to 0, 0.5 halved between
    # 0 and 1, 0.3 all to 1: [0, 0.2 + 0.25, 0.25 + 0.3]. Mean 0.55 = 0.5 + 0.5 · (−0.2 + 0.3).
    np.testing.assert_allclose(project(Z3, P3, 0.5, 0.5, Z3), [0.0, 0.45, 0.55], atol=1e-6)
    # Terminated (discount 0), r 0.25: everything at 0.25, 3/4 of it to 0 and 1/4 to 1.
    np.testing.assert_allclose(project(Z3, P3, 0.25, 0.0, Z3), [0.0, 0.75, 0.25], atol=1e-6)
    # Out of range: 2 + 0.9 · [-1, 0, 1] = [1.1, 2, 2.9] clip to 1; -3 + [-1, 0, 1] clip to -1.
    np.testing.assert_allclose(project(Z3, P3, 2.0, 0.9, Z3), [0.0, 0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(project(Z3, P3, -3.0, 1.0, Z3), [1.0, 0.0, 0.0], atol=1e-6)
    # 5 atoms [-2 .. 2], r 1, discount 0.5: atoms [0, 0.5, 1, 1.5, 2] with [.1, .2, .3, .2, .2]:
    # 0 ← .1 + .1, 1 ← .1 + .3 + .1, 2 ← .1 + .2.
    z5 = jnp.linspace(-2.0, 2.0, 5)
    p5 = jnp.array([0.1, 0.2, 0.3, 0.2, 0.2])
    np.testing.assert_allclose(project(z5, p5, 1.0, 0.5, z5), [0.0, 0.0, 0.2, 0.5, 0.3], atol=1e-6)


@pytest.mark.slow
def test_categorical_projection_keeps_the_mass_vmapped():
    key_r, key_d, key_p = jax.random.split(jax.random.key(0), 3)
    rewards = jax.random.uniform(key_r, (64,), minval=-15.0, maxval=15.0)
    discounts = jax.random.uniform(key_d, (64,))
    probs = jax.nn.softmax(jax.random.normal(key_p, (64, 51)))
    z = jnp.linspace(-10.0, 10.0, 51)
    projected = jax.vmap(dqn.categorical_projection, in_axes=(None, 0, 0, 0, None))(
        z, probs, rewards, discounts, z
    )
    assert projected.shape == (64, 51)
    assert float(projected.min()) >= 0.0
    np.testing.assert_allclose(projected.sum(-1), 1.0, rtol=1e-5)
    one = dqn.categorical_projection(z, probs[3], rewards[3], discounts[3], z)
    np.testing.assert_allclose(projected[3], one, atol=1e-6)


def tabular_c51_agent(cfg, online_logits, target_logits=None):
    """A C51 learner with 2 actions, 3 atoms on [-1, 1] and a linear network without hidden layers:
    logits(s) = s @ W reshaped to [2, 3], so one-hot states read off rows of W."""
    agent = dqn.init(jax.random.key(0), jnp.zeros(2), 2, cfg)

    def params(logits):
        kernel = jnp.asarray(logits, jnp.float32).reshape(2, 6)
        return {"params": {"Dense_0": {"kernel": kernel, "bias": jnp.zeros(6)}}}

    target = params(online_logits if target_logits is None else target_logits)
    return agent.replace(
        params=params(online_logits),
        target_params=target,
        opt_state=dqn.optimizer(cfg).init(params(online_logits)),
    )


LN = np.log
# state s = [1, 0]: action 0 uniform (Q 0), action 1 probs [1/4, 1/4, 1/2] (Q 0.25);
# state s' = [0, 1]: action 0 uniform (Q 0), action 1 probs [0.2, 0.5, 0.3] (Q 0.1).
ONLINE = [[[0.0, 0.0, 0.0], [0.0, 0.0, LN(2.0)]], [[0.0, 0.0, 0.0], [LN(0.2), LN(0.5), LN(0.3)]]]


def c51_sample(action, reward, terminated, weights):
    n = len(action)
    return ReplaySample(
        transition=Transition(
            obs=jnp.tile(jnp.array([1.0, 0.0]), (n, 1)),
            action=jnp.asarray(action),
            reward=jnp.asarray(reward),
            next_obs=jnp.tile(jnp.array([0.0, 1.0]), (n, 1)),
            terminated=jnp.asarray(terminated),
            truncated=jnp.zeros(n, bool),
            num_steps=jnp.ones(n, jnp.int32),
        ),
        indices=jnp.arange(n),
        weights=jnp.asarray(weights),
    )


C51 = dqn.DQNConfig(
    hidden=(),
    distributional=True,
    num_atoms=3,
    v_min=-1.0,
    v_max=1.0,
    discount_factor=0.5,
    target_update_period=0,
    max_grad_norm=None,
)


@pytest.mark.slow
def test_c51_loss_is_the_cross_entropy_by_hand():
    sample = c51_sample([1, 0], [0.5, 0.25], [False, True], [1.0, 0.5])
    _, metrics = jax.jit(dqn.make_learn(C51))(tabular_c51_agent(C51, ONLINE), sample)
    # 1: the next action is argmax [0, 0.1] = 1, target [0, 0.45, 0.55] (the projection test's first
    #    case); −(0.45 ln 1/4 + 0.55 ln 1/2) = 0.45 · 1.386294 + 0.55 · 0.693147 = 1.005063
    # 2: terminated, r 0.25: target [0, 0.75, 0.25] against action 0's uniform: −ln(1/3) = 1.098612
    np.testing.assert_allclose(metrics["priority"], [1.005063, 1.098612], rtol=1e-5)
    # Weighted mean: (1.005063 + 0.5 · 1.098612) / 2 = 0.777185
    assert float(metrics["loss"]) == pytest.approx(0.777185, rel=1e-5)
    # Q(s) = [0, −1/4 + 1/2] = [0, 0.25] in both samples: mean 0.125
    assert float(metrics["q_mean"]) == pytest.approx(0.125, rel=1e-5)


@pytest.mark.slow
def test_c51_double_picks_with_the_online_network():
    # The target network has s' rows swapped: action 0 → [0.2, 0.5, 0.3] (Q 0.1), action 1 uniform.
    target = [ONLINE[0], [ONLINE[1][1], ONLINE[1][0]]]
    cfg = dataclasses.replace(C51, target_update_period=100, double=True)
    sample = c51_sample([1], [0.5], [False], [1.0])
    _, metrics = jax.jit(dqn.make_learn(cfg))(tabular_c51_agent(cfg, ONLINE, target), sample)
    # Double: the online net picks action 1, the target's uniform there projects (r 0.5, γ 0.5) to
    # [0, 1/3 + 1/6, 1/6 + 1/3]: −(0.5 ln 1/4 + 0.5 ln 1/2) = 1.039721
    np.testing.assert_allclose(metrics["priority"], [1.039721], rtol=1e-5)
    _, metrics = jax.jit(dqn.make_learn(dataclasses.replace(cfg, double=False)))(
        tabular_c51_agent(cfg, ONLINE, target), sample
    )
    np.testing.assert_allclose(metrics["priority"], [1.005063], rtol=1e-5)  # the target's own argmax


@pytest.mark.slow
def test_noisy_dense():
    x = jax.random.normal(jax.random.key(0), (5, 3))
    layer = NoisyDense(4, sigma0=0.0)
    params = layer.init(jax.random.key(1), x)
    noisy = layer.apply(params, x, deterministic=False, rngs={"noise": jax.random.key(2)})
    mean_weights = {"params": {k: params["params"][k] for k in ("kernel", "bias")}}
    np.testing.assert_allclose(noisy, nn.Dense(4).apply(mean_weights, x), rtol=1e-6)  # σ = 0: a Dense
    # Initialisation (p = 3 inputs): μ within ±1/√3, σ = σ0/√3.
    layer = NoisyDense(4, sigma0=0.5)
    params = layer.init(jax.random.key(1), x)
    assert float(jnp.abs(params["params"]["kernel"]).max()) <= 1 / np.sqrt(3)
    np.testing.assert_allclose(params["params"]["sigma_kernel"], 0.5 / np.sqrt(3), rtol=1e-6)
    # Evaluation (the default) uses the mean weights, whatever the key; training draws per key.
    evaluate = [layer.apply(params, x, rngs={"noise": jax.random.key(k)}) for k in (3, 4)]
    np.testing.assert_array_equal(evaluate[0], evaluate[1])
    np.testing.assert_allclose(
        evaluate[0], x @ params["params"]["kernel"] + params["params"]["bias"], rtol=1e-6
    )
    train = [
        layer.apply(params, x, deterministic=False, rngs={"noise": jax.random.key(k)}) for k in (3, 3, 4)
    ]
    np.testing.assert_array_equal(train[0], train[1])
    assert not np.allclose(train[0], train[2])


def test_factorised_noise():
    np.testing.assert_allclose(scaled_noise(jnp.array([-4.0, 0.0, 2.25])), [-2.0, 0.0, 1.5])
    eps_kernel, eps_bias = factorised_noise(jax.random.key(0), 3, 4)
    assert eps_kernel.shape == (3, 4) and eps_bias.shape == (4,)
    # Rank one: ε_kernel[i, j] = f(ε_in)[i] · f(ε_out)[j] with ε_bias = f(ε_out).
    f_in = eps_kernel[:, 0] / eps_bias[0]
    np.testing.assert_allclose(eps_kernel, jnp.outer(f_in, eps_bias), rtol=1e-5)


def test_shift_moves_pixels_exactly():
    frames = jnp.arange(2 * 6 * 7, dtype=jnp.uint8).reshape(2, 6, 7)
    for dx, dy in [(1, 2), (-3, 1), (0, -4), (4, 4)]:
        moved = shift(frames, dx, dy)
        assert moved.shape == frames.shape and moved.dtype == jnp.uint8
        rows = np.clip(np.arange(6) - dy, 0, 5)
        cols = np.clip(np.arange(7) - dx, 0, 6)
        np.testing.assert_array_equal(moved, np.asarray(frames)[:, rows][:, :, cols])
    moved = shift(frames, 1, 2)
    assert moved[0, 2, 1] == frames[0, 0, 0] and moved[1, 5, 6] == frames[1, 3, 5]
    np.testing.assert_array_equal(moved[:, 0], moved[:, 2])  # the top row replicated into the gap


@pytest.mark.slow
def test_random_shift_crops_each_sample_at_its_own_offset():
    frames = jax.random.randint(jax.random.key(0), (8, 4, 84, 84), 0, 256).astype(jnp.uint8)
    shifted = random_shift(jax.random.key(1), frames)
    assert shifted.shape == frames.shape and shifted.dtype == frames.dtype
    padded = np.pad(np.asarray(frames), ((0, 0), (0, 0), (4, 4), (4, 4)), mode="edge")
    offsets = []
    for sample, original in zip(np.asarray(shifted), padded, strict=True):
        found = [
            (dx, dy)
            for dx in range(-4, 5)
            for dy in range(-4, 5)
            if np.array_equal(sample, original[:, 4 - dy : 88 - dy, 4 - dx : 88 - dx])  # all 4 frames alike
        ]
        assert len(found) == 1
        offsets.append(found[0])
    assert len(set(offsets)) > 1  # each sample its own offset


RAINBOW_CARTPOLE = dqn.DQNConfig(
    distributional=True,
    num_atoms=51,
    v_min=0.0,
    v_max=100.0,
    noisy=True,
    dueling=True,
    prioritized=True,
    n_step=3,
    epsilon_start=0.0,
    epsilon_end=0.0,
    learning_rate=1e-3,
    num_envs=1,
    learning_starts=500,
    train_frequency=16,
    gradient_steps=4,
    target_update_period=100,
    total_steps=5_000,
)


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
@pytest.mark.timeout(180)
def test_rainbow_learns_cartpole_through_the_host_runner():
    """C51 + noisy nets (no ε) + dueling + Double + PER + 3-step returns: in 5,000 env steps (1,128
    learning steps) from ~22 (random) to a greedy policy (mean weights) well above it; seed 0 measured
    rows [31.7, 89.0, 107.2], evaluation 148.6 (seeds 1, 2: evaluations 88.3 and 99.7)."""
    env = make_host_env("CartPole-v1", 1)
    spec = EnvSpec.of(env)
    env.close()
    agent = dqn.make_agent(spec, RAINBOW_CARTPOLE)
    result = host.train(agent, "CartPole-v1", HostRunnerConfig(seed=0, log_every_steps=2_000))
    assert result.updates == int(result.state.step) == 282 * 4  # phases of 4 every 16 steps from 500 on
    assert result.rows[0]["mean_return"] < 50 < result.rows[-1]["mean_return"]
    assert result.eval["mean_return"] > 75, result.eval


@pytest.mark.slow
def test_rainbow_on_the_compiled_runner():
    """The compiled program gives learn its key (noise) inside the scan; uniform replay (PER: host test)."""
    cfg = dataclasses.replace(
        RAINBOW_CARTPOLE,
        hidden=(16,),
        prioritized=False,
        num_envs=2,
        learning_starts=32,
        batch_size=8,
        train_frequency=4,
    )
    env = make_jax("CartPole-v1")
    algorithm = compiled_program(dqn, env, cfg)
    state = jax.jit(algorithm.init)(jax.random.key(0))
    update = jax.jit(algorithm.update)
    for _ in range(6):
        state, metrics = update(state)
    assert int(state.agent.step) == 3 * 4  # 8 env steps an update: learning in updates 4, 5 and 6
    assert np.isfinite(float(metrics["loss"])) and float(metrics["loss"]) > 0
    policy = algorithm.greedy_policy(state)
    obs = jnp.ones(4)
    assert int(policy(obs, jax.random.key(1))) == int(policy(obs, jax.random.key(2)))  # mean weights


@pytest.mark.long  # (make test-long: too long for make test's 10 minutes cold)
def test_der_preset_on_frames():
    cfg = presets.preset("dqn", "der", augment="shift", batch_size=2).config
    assert (cfg.n_step, cfg.learning_starts, cfg.target_update_period, cfg.total_steps) == (
        10,
        1_600,
        2_000,
        100_000,
    )
    assert (
        cfg.noisy and cfg.distributional and cfg.prioritized and cfg.epsilon_start == cfg.epsilon_end == 0.0
    )
    spec = EnvSpec((4, 84, 84), Discrete(6), jnp.uint8)  # Atari's stacked frames, 6 actions
    agent = dqn.make_agent(spec, cfg)
    state = jax.jit(agent.init)(jax.random.key(0))
    network = state.network
    assert network.cnn and network.noisy and network.num_atoms == 51
    assert "NoisyDense_0" in state.params["params"] and "Dense_0" not in state.params["params"]
    frames = jax.random.randint(jax.random.key(1), (2, 4, 84, 84), 0, 256).astype(jnp.uint8)
    out = jax.eval_shape(lambda p: dqn.forward(network, p, frames, jax.random.key(2)), state.params)
    assert out.shape == (2, 6, 51)
    actions, _ = jax.eval_shape(agent.act, state, frames, jax.random.key(3), 0)
    assert actions.shape == (2,)
    sample = ReplaySample(
        transition=Transition(
            obs=frames,
            action=jnp.array([0, 5]),
            reward=jnp.array([1.0, 0.0]),
            next_obs=frames[::-1],
            terminated=jnp.array([False, True]),
            truncated=jnp.zeros(2, bool),
            num_steps=jnp.array([10, 3]),
        ),
        indices=jnp.arange(2),
        weights=jnp.ones(2),
    )
    learned, metrics = jax.jit(agent.learn)(state, sample, jax.random.key(4))
    assert metrics["priority"].shape == (2,) and bool(jnp.all(metrics["priority"] > 0))
    assert int(learned.step) == 1
    with pytest.raises(UsageError, match="key"):
        dqn.make_learn(cfg)(state, sample)
    with pytest.raises(UsageError, match="augment"):
        dqn.init(jax.random.key(0), jnp.zeros(4), 2, cfg)
    with pytest.raises(UsageError, match="augment"):
        presets.preset("dqn", "der", augment="crop")
