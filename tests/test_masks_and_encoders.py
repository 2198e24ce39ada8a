"""Every agent on packed observations and legal-action masks (issue 41): the encoders each leaf kind
gets, masked ε-greedy and masked bootstraps (DQN, PQN), masked and multi-entry categoricals
(REINFORCE), encoders for SAC's and TD3's actor and critics; FrozenLake (Discrete observations) learned
by DQN and PPO, and Taxi-v4's mask kept by DQN in every evaluation step."""

import dataclasses

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.agents import dqn, ppo, pqn, reinforce, sac, td3
from agentax.agents.protocol import PRIORITY, EnvSpec
from agentax.envs import make_host_env
from agentax.envs.core import Box, Discrete
from agentax.envs.spaces import Dict, MultiBinary, MultiDiscrete, layout_of
from agentax.errors import UsageError
from agentax.nets import Encoder, entropy, legal_max, log_prob
from agentax.replay import ReplaySample, Transition
from agentax.runners import host

NUM_ACTIONS = 5
LAYOUT = layout_of(
    Dict(
        (
            ("cell", Discrete(6)),
            ("velocity", Box(-1.0, 1.0, (3,))),
            ("action_mask", MultiBinary(NUM_ACTIONS)),
        )
    )
)
"""packed: cell [0], velocity [1:4], mask [4:9]"""
SPEC = EnvSpec((LAYOUT.size,), Discrete(NUM_ACTIONS), jnp.float32, None, LAYOUT)


def packed_observations(count: int, seed: int = 0, masks: np.ndarray | None = None) -> np.ndarray:
    """``count`` packed observations ``[count, 9]``, random masks with at least one legal action."""
    rng = np.random.default_rng(seed)
    if masks is None:
        masks = rng.random((count, NUM_ACTIONS)) < 0.4
        masks[np.arange(count), rng.integers(NUM_ACTIONS, size=count)] = True
    cells = rng.integers(6, size=(count, 1))
    return np.concatenate([cells, rng.uniform(-1, 1, (count, 3)), masks], axis=1).astype(np.float32)


def legal_of(obs: np.ndarray) -> np.ndarray:
    return np.asarray(LAYOUT.legal(jnp.asarray(obs)))


def chosen_legally(obs: np.ndarray, actions: jax.Array) -> np.ndarray:
    return legal_of(obs)[np.arange(len(obs)), np.asarray(actions)]


# --- encoders ----------------------------------------------------------------------------------------


@pytest.mark.slow  # compiles learning steps or plays thousands of games: not for the edit-test loop
def test_each_leaf_kind_has_its_encoder_and_the_mask_is_not_seen():
    layout = layout_of(
        Dict(
            (
                ("joints", Box(-1.0, 1.0, (3,))),
                ("camera", Box(0, 255, (12, 12, 3), jnp.uint8)),  # [H, W, C] below 36 px: small conv
                ("frames", Box(0.0, 1.0, (3, 40, 40))),  # [C, H, W] from 36 px: Nature convolutions
                ("depth", Box(0.0, 1.0, (10, 10))),  # one channel
                ("cell", Discrete(5)),
                ("dice", MultiDiscrete((2, 3))),
                ("switches", MultiBinary(4)),
                ("action_mask", MultiBinary(NUM_ACTIONS)),
            )
        )
    )
    kinds = [leaf.kind for leaf in layout.leaves]
    assert kinds == ["vector", "image", "image", "image", "discrete", "multi_discrete", "binary", "mask"]
    obs = jnp.zeros((2, layout.size))
    # The parameters' shapes from init, their values from NumPy, and apply compiled once: compiling
    # init (random conv and dense kernels) or running it op by op costs ~130 compiles and a minute.
    shapes = jax.eval_shape(Encoder(layout).init, jax.random.key(0), obs)
    rng = np.random.default_rng(0)
    params = jax.tree.map(lambda s: (0.05 * rng.normal(size=s.shape)).astype(s.dtype), shapes)
    apply = jax.jit(Encoder(layout).apply)
    features = apply(params, obs)
    assert features.shape == (2, 3 + 256 + 512 + 256 + 5 + (2 + 3) + 4)  # nothing of the mask

    cell = layout.leaves[4]
    obs = obs.at[:, cell.start].set(jnp.array([2.0, 4.0]))
    tail = apply(params, obs)[:, -(5 + 5 + 4) :]  # the discrete leaves' features
    assert jnp.array_equal(tail[:, :5], jax.nn.one_hot(jnp.array([2, 4]), 5))
    assert jnp.array_equal(tail[:, 5:10], jnp.tile(jnp.array([1.0, 0, 1, 0, 0]), (2, 1)))  # dice (0, 0)


@pytest.mark.slow  # compiles learning steps or plays thousands of games: not for the edit-test loop
@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_sac_and_td3_encode_packed_observations_in_actor_and_critic(algo):
    layout = layout_of(Dict((("cell", Discrete(6)), ("velocity", Box(-1.0, 1.0, (3,))))))
    spec = EnvSpec((layout.size,), Box(-2.0, 2.0, (2,)), jnp.float32, None, layout)
    module, config = (sac, sac.SACConfig) if algo == "sac" else (td3, td3.TD3Config)
    agent = module.make_agent(spec, config(hidden=(16,), learning_starts=0, batch_size=8))
    state = jax.jit(agent.init)(jax.random.key(0))  # each step compiled whole, not op by op (~290 compiles)
    inputs = sorted(k.shape[0] for k in jax.tree.leaves(state.params) if k.ndim == 2 and k.shape[0] != 16)
    assert inputs == [9, 11, 11], inputs  # one-hot cell (6) and velocity (3); the critics' + action (2)
    obs = jnp.asarray(packed_observations(8)[:, :4])
    action, _ = jax.jit(agent.act)(state, obs, jax.random.key(1), jnp.int32(100))
    assert action.shape == (8, 2) and bool(jnp.all(jnp.abs(action) <= 1.0))
    batch = Transition(
        obs, action, jnp.ones(8), obs[::-1], jnp.zeros(8, bool), jnp.zeros(8, bool), jnp.ones(8, jnp.int32)
    )
    sample = ReplaySample(batch, jnp.arange(8), jnp.ones(8))
    _, metrics = jax.jit(agent.learn)(state, sample, jax.random.key(2))
    assert np.isfinite(float(metrics["critic_loss"]))
    assert jax.jit(agent.greedy_policy(state))(obs[0], jax.random.key(3)).shape == (2,)


# --- masks: DQN and PQN ------------------------------------------------------------------------------

DQN_VARIANTS = {
    "plain": {},
    "dueling": {"dueling": True},
    "c51": {"distributional": True, "num_atoms": 11},
    "noisy": {"noisy": True},
}


@pytest.mark.parametrize("variant", list(DQN_VARIANTS))
def test_dqn_acts_greedily_and_explores_among_the_legal_actions_only(variant):
    cfg = dqn.DQNConfig(hidden=(16,), **DQN_VARIANTS[variant])
    state = dqn.make_agent(SPEC, cfg).init(jax.random.key(0))
    obs = packed_observations(2_000)
    act = jax.jit(dqn.act)  # one program for the three epsilons, not op by op
    for epsilon in (0.0, 0.3, 1.0):
        actions = act(state, jnp.asarray(obs), jax.random.key(int(epsilon * 10)), jnp.float32(epsilon))
        assert chosen_legally(obs, actions).all(), epsilon
    greedy_policy = jax.jit(jax.vmap(dqn.greedy_policy(state), in_axes=(0, None)))
    greedy = greedy_policy(jnp.asarray(obs), jax.random.key(0))
    assert chosen_legally(obs, greedy).all()
    unmasked = jnp.argmax(jax.jit(dqn.greedy_q)(state, jnp.asarray(obs)), axis=-1)
    assert not chosen_legally(obs, unmasked).all()  # the network alone would pick illegal actions


def test_dqn_explores_uniformly_over_the_legal_actions():
    state = dqn.make_agent(SPEC, dqn.DQNConfig(hidden=(16,))).init(jax.random.key(0))
    mask = np.zeros((4_000, NUM_ACTIONS), bool)
    mask[:, [0, 2, 3]] = True
    actions = np.asarray(
        dqn.act(state, jnp.asarray(packed_observations(4_000, masks=mask)), jax.random.key(5), 1.0)
    )
    counts = np.bincount(actions, minlength=NUM_ACTIONS)
    assert counts[1] == counts[4] == 0
    assert np.all(np.abs(counts[[0, 2, 3]] / 4_000 - 1 / 3) < 0.03), counts  # ~4.6 binomial std


def replay_sample(
    next_masks: np.ndarray | None = None, terminated: bool = False, batch: int = 64
) -> ReplaySample:
    rng = np.random.default_rng(3)
    obs = packed_observations(batch, seed=1)
    transition = Transition(
        obs=jnp.asarray(obs),
        action=jnp.asarray(np.argmax(legal_of(obs), axis=-1), jnp.int32),  # a legal action
        reward=jnp.asarray(rng.normal(size=batch), jnp.float32),
        next_obs=jnp.asarray(packed_observations(batch, seed=2, masks=next_masks)),
        terminated=jnp.full(batch, terminated),
        truncated=jnp.zeros(batch, bool),
        num_steps=jnp.ones(batch, jnp.int32),
    )
    return ReplaySample(transition, jnp.arange(batch), jnp.ones(batch))


@pytest.mark.slow  # compiles learning steps or plays thousands of games: not for the edit-test loop
@pytest.mark.parametrize("double", [False, True])
def test_dqn_bootstraps_from_the_best_legal_action_of_the_next_observation(double):
    cfg = dqn.DQNConfig(hidden=(16,), n_step=1, loss="mse", double=double)
    state = dqn.make_agent(SPEC, cfg).init(jax.random.key(0))  # target = online at first
    sample = replay_sample()
    t = sample.transition
    _, metrics = jax.jit(dqn.make_learn(cfg))(state, sample)  # one program, not op by op
    greedy_q = jax.jit(dqn.greedy_q)
    q_t = np.asarray(greedy_q(state, t.next_obs))
    legal_t = legal_of(np.asarray(t.next_obs))
    best_legal = np.array([q[legal].max() for q, legal in zip(q_t, legal_t, strict=True)])
    q_tm1 = np.asarray(greedy_q(state, t.obs))[np.arange(64), np.asarray(t.action)]
    expected = np.asarray(t.reward) + cfg.discount_factor * best_legal - q_tm1
    np.testing.assert_allclose(np.asarray(metrics[PRIORITY]), expected, rtol=1e-5, atol=1e-5)
    assert not np.allclose(best_legal, q_t.max(axis=-1))  # the mask changed some maxima


@pytest.mark.slow  # compiles learning steps or plays thousands of games: not for the edit-test loop
@pytest.mark.parametrize("variant", ["plain", "c51"])
def test_a_next_observation_without_legal_actions_bootstraps_finitely(variant):
    cfg = dqn.DQNConfig(hidden=(16,), n_step=1, loss="mse", **DQN_VARIANTS[variant])
    state = dqn.make_agent(SPEC, cfg).init(jax.random.key(0))
    no_legal = np.zeros((64, NUM_ACTIONS), bool)
    key, learn = jax.random.key(1), jax.jit(dqn.make_learn(cfg))  # one program for both, not op by op
    for terminated in (True, False):  # a final observation: terminated, or truncated (bootstrapped)
        sample = replay_sample(no_legal, terminated)
        _, metrics = learn(state, sample, key)
        priority = np.asarray(metrics[PRIORITY])
        assert np.all(np.isfinite(priority)) and np.all(np.abs(priority) < 1e3), (terminated, priority)
        if terminated and variant == "plain":  # no bootstrap at all: r − Q(s, a)
            t = sample.transition
            q_tm1 = np.asarray(jax.jit(dqn.greedy_q)(state, t.obs))[np.arange(64), np.asarray(t.action)]
            np.testing.assert_allclose(priority, np.asarray(t.reward) - q_tm1, rtol=1e-5, atol=1e-5)


def test_legal_max_is_the_max_over_legal_actions_and_finite_without_any():
    q = jnp.array([[1.0, 5.0, 3.0], [2.0, 0.0, 7.0], [4.0, 9.0, -1.0]])
    legal = jnp.array([[True, False, True], [False, False, False], [True, True, True]])
    assert legal_max(q, legal).tolist() == [3.0, 2.0, 9.0]  # no legal action: Q of action 0, finite
    assert legal_max(q, None).tolist() == [5.0, 7.0, 9.0]


@pytest.mark.slow  # compiles learning steps or plays thousands of games: not for the edit-test loop
def test_pqn_explores_among_legal_actions_and_its_targets_use_the_legal_maximum():
    cfg = pqn.PQNConfig(
        num_envs=2, num_steps=4, hidden=(16,), q_lambda=0.0, update_epochs=1, num_minibatches=1
    )
    agent = pqn.make_agent(SPEC, cfg)
    state = agent.init(jax.random.key(0))
    obs = jnp.asarray(packed_observations(2_000))
    act = jax.jit(agent.act)  # each step compiled whole, not op by op
    for progress in (0, cfg.total_steps):  # ε = 1, then 0.05
        actions, info = act(state, obs, jax.random.key(progress), jnp.int32(progress))
        assert chosen_legally(np.asarray(obs), actions).all()
    greedy = jax.jit(jax.vmap(agent.greedy_policy(state), in_axes=(0, None)))(obs, jax.random.key(0))
    assert chosen_legally(np.asarray(obs), greedy).all()

    t = replay_sample(batch=8).transition
    rollout = jax.tree.map(lambda x: x.reshape(4, 2, *x.shape[1:]), t)
    rollout = rollout.replace(info={"epsilon": jnp.zeros((4, 2))})
    _, metrics = jax.jit(agent.learn)(state, rollout, jax.random.key(1))
    q_values = jax.jit(pqn.q_values_of(pqn.q_network(cfg, SPEC), SPEC))
    q_t = np.asarray(q_values(state.params, t.next_obs))
    best_legal = np.array(
        [q[legal].max() for q, legal in zip(q_t, legal_of(np.asarray(t.next_obs)), strict=True)]
    )
    q_taken = np.asarray(q_values(state.params, t.obs))[np.arange(8), np.asarray(t.action)]
    target = np.asarray(t.reward) + cfg.discount_factor * best_legal  # λ = 0: one-step targets
    # one epoch of one minibatch: the loss is the one of the parameters before the step
    assert float(metrics["loss"]) == pytest.approx(0.5 * np.mean((q_taken - target) ** 2), rel=1e-5)


@pytest.mark.parametrize("algo", ["dqn", "pqn"])
@pytest.mark.parametrize("space", [MultiDiscrete((3, 2)), MultiBinary(3)])
def test_q_learners_refuse_multi_entry_actions_in_one_line(algo, space):
    module, config = (dqn, dqn.DQNConfig) if algo == "dqn" else (pqn, pqn.PQNConfig)
    with pytest.raises(
        UsageError, match=rf"^{algo} takes Discrete actions, but .*ppo and reinforce take"
    ) as error:
        module.make_agent(EnvSpec((4,), space), config())
    assert "\n" not in str(error.value)


# --- REINFORCE: masks and multi-entry actions ---------------------------------------------------------


def test_multi_discrete_log_prob_and_entropy_are_sums_over_entries():
    logits = jax.random.normal(jax.random.key(0), (7, 3 + 2 + 4))
    action = jnp.stack([jnp.arange(7) % 3, jnp.arange(7) % 2, (jnp.arange(7) * 3) % 4], axis=-1)
    parts = [logits[:, :3], logits[:, 3:5], logits[:, 5:]]
    by_hand = sum(jax.nn.log_softmax(x)[jnp.arange(7), action[:, i]] for i, x in enumerate(parts))
    np.testing.assert_allclose(log_prob(logits, action, (3, 2, 4)), by_hand, rtol=1e-6)
    entropies = sum(-(jax.nn.softmax(x) * jax.nn.log_softmax(x)).sum(-1) for x in parts)
    np.testing.assert_allclose(entropy(logits, (3, 2, 4)), entropies, rtol=1e-6)


@pytest.mark.parametrize("space", [MultiDiscrete((3, 2)), MultiBinary(3)])
def test_reinforce_takes_multi_entry_actions(space):
    spec = EnvSpec((4,), space)
    cfg = reinforce.ReinforceConfig(hidden=(8,))
    agent = reinforce.make_agent(spec, cfg)
    state = agent.init(jax.random.key(0))
    obs = jax.random.normal(jax.random.key(1), (500, 4))
    actions, _ = agent.act(state, obs, jax.random.key(2), 0)
    nvec = np.array(getattr(space, "nvec", (2,) * 3))
    assert actions.shape == (500, len(nvec)) and np.all((0 <= actions) & (actions < nvec))
    assert all(len(np.unique(actions[:, i])) == n for i, n in enumerate(nvec))  # each choice sampled
    out = reinforce.policy_network(cfg, space).apply(state.params["policy"], obs)
    start = np.cumsum([0, *nvec])
    by_hand = sum(
        jax.nn.log_softmax(out[:, a:b])[jnp.arange(500), actions[:, i]]
        for i, (a, b) in enumerate(zip(start[:-1], start[1:], strict=True))
    )
    np.testing.assert_allclose(reinforce.action_log_prob(out, actions, space), by_hand, rtol=1e-5)
    assert agent.greedy_policy(state)(obs[0], jax.random.key(3)).shape == (len(nvec),)


def test_reinforce_samples_and_learns_only_legal_actions():
    cfg = reinforce.ReinforceConfig(hidden=(8,), baseline=True)
    agent = reinforce.make_agent(SPEC, cfg)
    state = agent.init(jax.random.key(0))
    obs = packed_observations(2_000)
    actions, _ = agent.act(state, jnp.asarray(obs), jax.random.key(1), 0)
    assert chosen_legally(obs, actions).all()
    greedy = jax.vmap(agent.greedy_policy(state), in_axes=(0, None))(jnp.asarray(obs), jax.random.key(0))
    assert chosen_legally(obs, greedy).all()
    # the legal actions' probabilities sum to one: log π of the legal ones is that of a renormalised softmax
    out = reinforce.policy_output(
        reinforce.policy_network(cfg, NUM_ACTIONS, LAYOUT), state.params["policy"], obs
    )
    probs = np.exp(np.asarray(jax.nn.log_softmax(out)))
    np.testing.assert_allclose((probs * legal_of(obs)).sum(-1), 1.0, rtol=1e-5)


# --- learning ------------------------------------------------------------------------------------------

gymnasium.register(
    "FrozenLakeDet-v1",
    entry_point="gymnasium.envs.toy_text.frozen_lake:FrozenLakeEnv",
    kwargs={"map_name": "4x4", "is_slippery": False},
    max_episode_steps=100,
)


def spec_of(env_id: str) -> EnvSpec:
    env = make_host_env(env_id, 1)
    try:
        return EnvSpec.of(env)
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_dqn_reaches_the_goal_of_frozen_lake():
    """4×4, not slippery: Discrete(16) observations one-hot; the greedy path of 6 steps returns 1."""
    cfg = dqn.DQNConfig(
        total_steps=8_000,
        num_envs=4,
        n_step=1,
        learning_rate=1e-3,
        learning_starts=500,
        train_frequency=16,
        gradient_steps=16,
        buffer_size=10_000,
        target_update_period=100,
        exploration_duration=4_000,
        epsilon_end=0.05,
    )
    result = host.train(
        dqn.make_agent(spec_of("FrozenLakeDet-v1"), cfg),
        "FrozenLakeDet-v1",
        host.HostRunnerConfig(log_every_steps=1_000, eval_episodes=4),
    )
    returns = [row["mean_return"] for row in result.rows]
    assert returns[0] < 0.2 and result.eval["mean_return"] == 1.0, (returns, result.eval)


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_ppo_reaches_the_goal_of_frozen_lake():
    cfg = dataclasses.replace(
        ppo.PPOConfig(), total_steps=12_288, num_envs=8, num_steps=64, learning_rate=1e-3
    )
    result = host.train(
        ppo.make_agent(spec_of("FrozenLakeDet-v1"), cfg),
        "FrozenLakeDet-v1",
        host.HostRunnerConfig(log_every_steps=1_024, eval_episodes=4),
    )
    returns = [row["mean_return"] for row in result.rows]
    assert returns[0] < 0.2 and result.eval["mean_return"] == 1.0, (returns, result.eval)


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_dqn_never_takes_an_illegal_action_of_taxi():
    """Taxi-v4 gives its legal actions as ``info["action_mask"]``; stepping Gymnasium's own env with
    the greedy policy, no step takes an action the mask forbids, while the Q-network's unmasked
    argmax would."""
    spec = spec_of("Taxi-v4")
    cfg = dqn.DQNConfig(total_steps=4_000, learning_starts=500, exploration_duration=2_000, n_step=1)
    result = host.train(dqn.make_agent(spec, cfg), "Taxi-v4", host.HostRunnerConfig(eval_episodes=2))
    state = result.state
    policy = jax.jit(dqn.greedy_policy(state))
    q = jax.jit(lambda obs: dqn.greedy_q(state, obs))
    env = gymnasium.make("Taxi-v4")
    steps = illegal = unmasked_illegal = 0
    for episode in range(3):
        obs, info = env.reset(seed=episode)
        done = False
        while not done:
            packed = spec.layout.pack({"obs": obs, "action_mask": info["action_mask"]})
            action = int(policy(jnp.asarray(packed), jax.random.key(0)))
            illegal += int(info["action_mask"][action] == 0)
            unmasked_illegal += int(info["action_mask"][int(jnp.argmax(q(jnp.asarray(packed))))] == 0)
            obs, _, terminated, truncated, info = env.step(action)
            steps, done = steps + 1, terminated or truncated
    env.close()
    assert steps >= 100 and illegal == 0 and unmasked_illegal > 0, (steps, illegal, unmasked_illegal)
