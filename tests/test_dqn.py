"""DQN's pieces against hand-computed values; one learning step the same on both runners."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agentax
from agentax.agents import config_from_dict, dqn, presets
from agentax.errors import UsageError
from agentax.nets import QNetwork, dueling_aggregate
from agentax.replay import ReplaySample, Transition, example_transition, host, uniform
from agentax.returns import bootstrap_discount


def test_td_error_by_hand():
    q_tm1, q_t = jnp.array([1.0, 2.0]), jnp.array([3.0, 5.0])
    # Q-learning: 1 + 0.9 * max(3, 5) - Q(s, 1) = 1 + 4.5 - 2 = 3.5
    assert float(dqn.td_error(q_tm1, 1, 1.0, 0.9, q_t, q_t)) == pytest.approx(3.5)
    # Double DQN: the online net [4, 1] picks action 0, the target net values it at 3: 1 + 2.7 - 2 = 1.7
    assert float(dqn.td_error(q_tm1, 1, 1.0, 0.9, q_t, jnp.array([4.0, 1.0]))) == pytest.approx(1.7)
    # A terminal transition (discount 0): 1 - 2 = -1
    assert float(dqn.td_error(q_tm1, 1, 1.0, 0.0, q_t, q_t)) == pytest.approx(-1.0)


def transitions(terminated, truncated, num_steps=(1, 1)):
    n = len(terminated)
    return Transition(
        obs=jnp.zeros((n, 4)),
        action=jnp.zeros(n, jnp.int32),
        reward=jnp.ones(n),
        next_obs=jnp.ones((n, 4)),
        terminated=jnp.asarray(terminated),
        truncated=jnp.asarray(truncated),
        num_steps=jnp.asarray(num_steps, jnp.int32),
    )


def test_terminated_stops_bootstrapping_truncated_does_not():
    t = transitions([True, False], [False, True])
    np.testing.assert_allclose(bootstrap_discount(t.terminated, t.num_steps, 0.9), [0.0, 0.9])
    # An n-step transition of 3 rewards bootstraps with γ^3 = 0.729; one of 2 that terminated: 0.
    t = transitions([False, True], [False, False], (3, 2))
    discount = bootstrap_discount(t.terminated, t.num_steps, 0.9)
    np.testing.assert_allclose(discount, [0.729, 0.0], rtol=1e-6)


@pytest.mark.slow
def test_dueling_aggregation_by_hand():
    value, advantage = jnp.array([[1.0]]), jnp.array([[1.0, 2.0, 4.0]])
    # max: V + A - max A = 1 + [1, 2, 4] - 4 = [-2, -1, 1]
    np.testing.assert_allclose(dueling_aggregate(value, advantage, "max"), [[-2.0, -1.0, 1.0]])
    # mean: mean A = 7/3 -> 1 + [1, 2, 4] - 7/3 = [-1/3, 2/3, 8/3]
    np.testing.assert_allclose(
        dueling_aggregate(value, advantage, "mean"), [[-1 / 3, 2 / 3, 8 / 3]], rtol=1e-6
    )
    # The dueling network: with "mean", the average over actions of Q is V, so Q - mean Q is A - mean A.
    net = QNetwork(num_actions=3, hidden=(8,), dueling="mean")
    params = net.init(jax.random.key(0), jnp.zeros((1, 4)))
    obs = jax.random.normal(jax.random.key(1), (5, 4))
    features = jax.nn.elu(
        obs @ params["params"]["MLP_0"]["Dense_0"]["kernel"] + params["params"]["MLP_0"]["Dense_0"]["bias"]
    )
    value = features @ params["params"]["Dense_0"]["kernel"] + params["params"]["Dense_0"]["bias"]
    np.testing.assert_allclose(net.apply(params, obs).mean(axis=-1), value[:, 0], rtol=1e-5, atol=1e-6)


def test_target_update_copy_and_polyak():
    target, online = {"w": jnp.array(0.0)}, {"w": jnp.array(1.0)}
    assert float(dqn.update_target(target, online, jnp.int32(3), 2, 1.0)["w"]) == 0.0  # not due
    assert float(dqn.update_target(target, online, jnp.int32(4), 2, 1.0)["w"]) == 1.0  # copied
    assert float(dqn.update_target(target, online, jnp.int32(1), 1, 0.01)["w"]) == pytest.approx(
        0.01
    )  # Polyak


def linear_agent(cfg, weight=((1.0, 2.0), (0.0, 1.0))):
    """A DQN learner whose Q-network is linear with known weights: Q(s) = s @ W (no hidden layer)."""
    agent = dqn.init(jax.random.key(0), jnp.zeros(2), 2, cfg)
    params = jax.tree.map(jnp.zeros_like, agent.params)
    params = {
        "params": {**params["params"], "Dense_0": {"kernel": jnp.asarray(weight), "bias": jnp.zeros(2)}}
    }
    return agent.replace(params=params, target_params=params, opt_state=dqn.optimizer(cfg).init(params))


@pytest.mark.slow
def test_learn_uses_the_td_targets_it_should():
    # Q(s) = s @ [[1, 2], [0, 1]]: Q([1, 0]) = [1, 2], Q([0, 1]) = [0, 1], Q([1, 1]) = [1, 3].
    cfg = dqn.DQNConfig(
        hidden=(), loss="mse", discount_factor=0.5, target_update_period=0, max_grad_norm=None
    )
    sample = ReplaySample(
        transition=Transition(
            obs=jnp.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]]),
            action=jnp.array([0, 1, 0]),
            reward=jnp.array([1.0, 1.0, 0.0]),
            next_obs=jnp.array([[1.0, 1.0], [0.0, 1.0], [1.0, 1.0]]),
            terminated=jnp.array([False, True, False]),
            truncated=jnp.array([False, False, True]),
            num_steps=jnp.array([1, 1, 2]),
        ),
        indices=jnp.arange(3),
        weights=jnp.array([1.0, 1.0, 0.5]),
    )
    _, metrics = dqn.make_learn(cfg)(linear_agent(cfg), sample)
    # 1: 1 + 0.5 * max[1, 3] - Q(s, 0) = 1 + 1.5 - 1 = 1.5
    # 2: terminated: 1 - Q(s, 1) = 1 - 2 = -1
    # 3: truncated after 2 steps: 0 + 0.25 * 3 - 1 = -0.25 (truncation bootstraps)
    np.testing.assert_allclose(metrics["priority"], [1.5, -1.0, -0.25], rtol=1e-6)
    # Weighted MSE: (1.5² + 1² + 0.5 · 0.25²) / 3 = (2.25 + 1 + 0.03125) / 3
    assert float(metrics["loss"]) == pytest.approx(3.28125 / 3, rel=1e-6)


def test_double_dqn_target_through_learn():
    # Online Q(s') = [1, 3] picks action 1; the target network Q⁻(s') = s' @ [[2, 0], [2, 0]] = [4, 0]
    # values it at 0.
    cfg = dqn.DQNConfig(hidden=(), loss="mse", discount_factor=0.5, target_update_period=100, double=True)
    agent = linear_agent(cfg)
    target = {"params": {"Dense_0": {"kernel": jnp.array([[2.0, 0.0], [2.0, 0.0]]), "bias": jnp.zeros(2)}}}
    agent = agent.replace(target_params=target)
    sample = ReplaySample(
        transition=Transition(
            obs=jnp.array([[1.0, 0.0]]),
            action=jnp.array([0]),
            reward=jnp.array([1.0]),
            next_obs=jnp.array([[1.0, 1.0]]),
            terminated=jnp.array([False]),
            truncated=jnp.array([False]),
            num_steps=jnp.array([1]),
        ),
        indices=jnp.arange(1),
        weights=jnp.ones(1),
    )
    _, metrics = dqn.make_learn(cfg)(agent, sample)
    assert float(metrics["priority"][0]) == pytest.approx(1 + 0.5 * 0 - 1)  # Double: 0.0
    _, metrics = dqn.make_learn(dataclasses.replace(cfg, double=False))(agent, sample)
    assert float(metrics["priority"][0]) == pytest.approx(1 + 0.5 * 4 - 1)  # max over the target: 2.0


@pytest.mark.slow
def test_compiled_and_host_runners_take_the_same_learning_step():
    """The same transitions in the JAX buffer (compiled runner) and the NumPy buffer (host driver), the
    same batch drawn from each, one learning step vmapped over seeds and one jitted on the host."""
    cfg = dqn.DQNConfig(hidden=(16,), double=True, n_step=1, target_update_period=2, batch_size=8)
    key = jax.random.key(1)
    batch = Transition(
        obs=jax.random.normal(key, (20, 4)),
        action=jnp.arange(20, dtype=jnp.int32) % 2,
        reward=jnp.linspace(0, 1, 20),
        next_obs=jax.random.normal(jax.random.key(2), (20, 4)),
        terminated=jnp.arange(20) % 7 == 0,
        truncated=jnp.arange(20) % 5 == 0,
        num_steps=jnp.ones(20, jnp.int32),
    )
    one = example_transition(jnp.zeros(4), jnp.int32(0))
    jax_buffer = uniform.add(uniform.init(16, one), batch)
    host_buffer = host.add(host.init(16, jax.device_get(one)), jax.device_get(batch))
    indices = np.array([0, 3, 5, 7, 9, 11, 13, 15])
    take = lambda storage: jax.tree.map(lambda s: s[indices], storage)
    jax_sample = ReplaySample(take(jax_buffer.storage), jnp.asarray(indices), jnp.ones(8))
    host_sample = ReplaySample(take(host_buffer.storage), indices, np.ones(8, np.float32))
    agents = jax.vmap(lambda k: dqn.init(k, jnp.zeros(4), 2, cfg))(jax.random.split(key, 2))
    learn = dqn.make_learn(cfg)
    compiled, compiled_metrics = jax.jit(jax.vmap(learn, in_axes=(0, None)))(agents, jax_sample)
    for seed in range(2):
        agent = jax.tree.map(lambda x, seed=seed: x[seed], agents)
        hosted, host_metrics = dqn.learn(agent, host_sample, cfg)
        np.testing.assert_allclose(host_metrics["priority"], compiled_metrics["priority"][seed], rtol=1e-5)
        for a, b in zip(jax.tree.leaves(hosted.params), jax.tree.leaves(compiled.params), strict=True):
            np.testing.assert_allclose(a, b[seed], rtol=1e-5, atol=1e-7)


def test_presets_and_validation():
    lecture = presets.preset("dqn", "lecture").config
    # LECTURE-FACTS.md: 32-32 elu, batch 32, γ 0.95, Adam 1e-3, MSE, replay 2,000, ε to 0.01 in 500 episodes.
    assert (lecture.hidden, lecture.activation, lecture.batch_size) == ((32, 32), "elu", 32)
    assert (lecture.discount_factor, lecture.learning_rate, lecture.loss) == (0.95, 1e-3, "mse")
    assert (lecture.buffer_size, lecture.max_episodes, lecture.learning_starts) == (2_000, 600, 50)
    # ε = max(1 − episode / 500, 0.01): 0.8 at episode 100, 0.01 from episode 495 on.
    assert float(dqn.epsilon_at(lecture, 100)) == pytest.approx(0.8)
    assert float(dqn.epsilon_at(lecture, 495)) == pytest.approx(0.01)
    assert float(dqn.epsilon_at(lecture, 550)) == pytest.approx(0.01)
    with pytest.raises(UsageError, match="choose from"):
        presets.preset("dqn", "nope")
    with pytest.raises(UsageError, match="discount_factor"):
        presets.preset("dqn", "default", discount_factor=1.5)
    with pytest.raises(UsageError, match="dqn takes Discrete actions, but this env's actions are Box"):
        from agentax.agents.protocol import EnvSpec
        from agentax.envs.core import Box

        dqn.make_agent(EnvSpec((4,), Box(-1.0, 1.0, (1,))), lecture)
    assert config_from_dict(dqn.DQNConfig, dataclasses.asdict(lecture)) == lecture


@pytest.mark.slow
@pytest.mark.timeout(240)
@pytest.mark.parametrize("n_step", [1, pytest.param(3, marks=pytest.mark.long)])  # 3: make test-long
def test_one_agent_keeps_the_same_schedule_on_the_compiled_and_the_host_runner(tmp_path, n_step):
    """One DQN agent and schedule (2 envs, 8 steps each between phases of 3 learning steps from env
    step 96), driven by the compiled runner's program and by the host runner's Driver: the same
    number of learning steps and the same replay size after 1,024 env steps (STYLE 14). Both come
    from ``OffPolicy``, so the off-policy schedule exists once per side, not once per algorithm."""
    settings = dict(
        num_envs=2,
        train_frequency=8,
        gradient_steps=3,
        learning_starts=96,
        batch_size=16,
        buffer_size=10_000,
        hidden=(16,),
        n_step=n_step,
        total_steps=1_024,
        stop_at_return=None,
        progress=False,
        freeze_at_return="none",
    )
    compiled = agentax.train("dqn", runner="compiled", out=tmp_path / "c", **settings)
    host = agentax.train("dqn", runner="host", out=tmp_path / "h", **settings)
    phases = (1_024 - 96) // 16 + 1  # collections of 16 env steps that end at or past step 96
    emitted = 1_024 - 2 * (n_step - 1)  # each env's first n - 1 steps wait for their n-step return
    assert int(compiled.result.state.agent.step[0]) == int(host.result.state.step) == 3 * phases
    assert int(compiled.result.state.replay.size[0]) == host.metrics[-1]["replay_size"] == emitted


def test_freezing_seeds_is_a_compiled_runner_option_refused_elsewhere(tmp_path):
    """The per-seed early stop lives in the compiled program's learning gates: a host run or an
    on-policy agent asking for it gets one clear error before anything is written."""
    quick = dict(total_steps=64, progress=False, freeze_at_return=100.0)
    with pytest.raises(UsageError, match="compiled runner's program; the host runner cannot"):
        agentax.train("dqn", runner="host", out=tmp_path / "h", **quick)
    with pytest.raises(UsageError, match="off-policy agent's learning gates, not ppo's"):
        agentax.train("ppo", runner="compiled", out=tmp_path / "p", **quick)
    with pytest.raises(UsageError, match="a number, 'none' or 'auto'"):
        agentax.train("dqn", out=tmp_path / "x", total_steps=64, progress=False, freeze_at_return="soon")
    assert not (tmp_path / "h").exists() and not (tmp_path / "p").exists()


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize("prioritized", [False, True])
def test_the_host_learner_reduces_whatever_scalar_metrics_an_agent_names(prioritized):
    """No hidden contract on metric names: an off-policy agent whose ``learn`` reports ``td_loss``
    and ``spread`` (not DQN's ``loss``/``q_mean``) gets those columns, uniform or prioritized;
    per-sample arrays (the priorities) are not logged."""
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_host_env
    from agentax.runners import host

    cfg = dqn.DQNConfig(hidden=(16,), num_envs=1, learning_starts=64, batch_size=8, prioritized=prioritized)
    probe = make_host_env("CartPole-v1", 1)
    agent = dqn.make_agent(EnvSpec.of(probe), cfg)
    probe.close()

    def renamed(state, sample, key):
        state, metrics = agent.learn(state, sample, key)
        return state, {
            "td_loss": metrics["loss"],
            "spread": jnp.std(metrics["priority"]),
            "priority": metrics["priority"],
        }

    custom = dataclasses.replace(agent, learn=renamed, total_steps=512)
    result = host.train(custom, "CartPole-v1", host.HostRunnerConfig(log_every_steps=256, eval_episodes=1))
    last = result.rows[-1]
    assert {"td_loss", "spread"} <= set(last) and "priority" not in last and "loss" not in last
    assert np.isfinite(last["td_loss"]) and last["td_loss"] > 0 and last["spread"] >= 0
