"""The compiled Atari runner: EnvPool stepped inside the program, its reset step left out of learning.

Checked: the reset-step bookkeeping by hand (:func:`agentax.envs.envpool_xla.track`); that PPO
learns nothing from masked steps; on a real pool, that every reset step follows a done step; the
in-program pool against the host adapter on the same seed and actions (frames, learning view, whole
games' scores and lengths); and a short run's folder, loaded back by the host runner's
``host.restore`` and resumed.
"""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.agents import ppo, presets
from agentax.agents.protocol import EnvSpec
from agentax.envs.core import Discrete
from agentax.envs.envpool_xla import EpisodeTracker, PoolStep, XlaAtari, track
from agentax.errors import UsageError
from agentax.replay import Transition
from agentax.runners.launch import agent_maker
from agentax.runs import Run, read_metrics, run_config

pytest.importorskip("envpool")

BREAKOUT = "ALE/Breakout-v5"


def _pool_step(reward, life_lost=(0, 0), game_over=(0, 0), truncated=(0, 0)) -> PoolStep:
    return PoolStep(
        obs=jnp.zeros((2, 4, 84, 84), jnp.uint8),
        reward=jnp.asarray(reward, jnp.float32),
        life_lost=jnp.asarray(life_lost, bool),
        game_over=jnp.asarray(game_over, bool),
        truncated=jnp.asarray(truncated, bool),
    )


@pytest.mark.timeout(30)
def test_track_masks_the_reset_step_and_keeps_whole_game_scores():
    """Two envs, four steps, worked by hand. Env 0: +4, loses a life (episode ends, game goes on),
    reset step (EnvPool pays 0, masked), +1 then game over: one game of score 5 over 3 valid steps.
    Env 1: +2 then the frame limit (truncated: a game ends), reset step, +7."""
    steps = [
        _pool_step([4, 2], truncated=(0, 1)),
        _pool_step([0, 0], life_lost=(1, 0)),  # env 1: its reset step (its reward, 0, is not counted)
        _pool_step([0, 7]),  # env 0: its reset step
        _pool_step([1, 0], game_over=(1, 0)),
    ]
    tracker = EpisodeTracker.create(2)
    valid, finished, scores, lengths = [], [], [], []
    for step in steps:
        tracker, tracked = jax.jit(track)(tracker, step)
        valid.append(np.asarray(tracked.valid))
        finished.append(np.asarray(tracked.game_finished))
        scores.append(np.asarray(tracked.game_score))
        lengths.append(np.asarray(tracked.game_length))
    np.testing.assert_array_equal(valid, [[1, 1], [1, 0], [0, 1], [1, 1]])
    np.testing.assert_array_equal(finished, [[0, 1], [0, 0], [0, 0], [1, 0]])
    assert scores[0][1] == 2 and lengths[0][1] == 1  # env 1: 2 points in 1 step, cut by the frame limit
    assert scores[3][0] == 4 + 0 + 1 and lengths[3][0] == 3  # env 0: steps 0, 1, 3; step 2 was the reset
    np.testing.assert_array_equal(tracker.score, [0, 7])  # env 1's next game has its 7 points
    np.testing.assert_array_equal(tracker.length, [0, 2])  # (steps 2 and 3; step 1 was the reset)
    np.testing.assert_array_equal(tracker.reset_next, [True, False])  # env 0 resets on its next step
    # the learning view: the step before each reset step ends an episode
    ended = np.array([np.asarray(s.ended) for s in steps])
    np.testing.assert_array_equal(ended[:-1], ~np.array(valid[1:], bool))


def _mlp_rollout(seed: int, valid: np.ndarray) -> tuple[Transition, dict]:
    """A random rollout ``[T=6, E=2]`` for an MLP PPO on 3-dim observations and 2 actions."""
    rng = np.random.default_rng(seed)
    t, e = valid.shape
    terminated = np.zeros((t, e), bool)
    terminated[:-1] = ~valid[1:]  # the step before a masked one ends an episode, as the runner marks it
    return Transition(
        obs=rng.normal(size=(t, e, 3)).astype(np.float32),
        action=rng.integers(2, size=(t, e)).astype(np.int32),
        reward=rng.normal(size=(t, e)).astype(np.float32),
        next_obs=rng.normal(size=(t, e, 3)).astype(np.float32),
        terminated=terminated,
        truncated=np.zeros((t, e), bool),
        num_steps=np.ones((t, e), np.int32),
        info={"log_prob": np.log(rng.uniform(0.2, 0.8, size=(t, e))).astype(np.float32), "valid": valid},
    )


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_ppo_learns_nothing_from_masked_steps():
    """Changing everything of the masked steps (observation, action, reward, log-probability, next
    observation) leaves PPO's update unchanged; changing a valid step changes it."""
    cfg = ppo.PPOConfig(num_envs=2, num_steps=6, num_minibatches=2, update_epochs=2, hidden=(8,))
    spec = EnvSpec((3,), Discrete(2))
    agent = ppo.init(jax.random.key(0), spec, cfg)
    valid = np.ones((6, 2), bool)
    valid[2, 0] = valid[5, 1] = valid[0, 1] = False  # reset steps: mid-rollout, last, first
    base = _mlp_rollout(1, valid)
    other = _mlp_rollout(2, valid)  # different numbers everywhere
    masked = jax.tree.map(lambda a, b: np.where(_broadcast(valid, a), a, b), base, other)
    touched_valid = jax.tree.map(lambda a: a.copy(), base)
    touched_valid.reward[3, 0] += 1.0
    learn = jax.jit(lambda state, rollout: ppo.learn(state, rollout, jax.random.key(3), spec, cfg))
    params = [jax.tree.leaves(learn(agent, r)[0].params) for r in (base, masked, touched_valid)]
    for a, b in zip(params[0], params[1], strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-7)
    assert any(not np.allclose(a, b, atol=1e-6) for a, b in zip(params[0], params[2], strict=True))
    unmasked = masked.replace(info={"log_prob": masked.info["log_prob"]})
    params_unmasked = jax.tree.leaves(learn(agent, unmasked)[0].params)
    assert any(not np.allclose(a, b, atol=1e-6) for a, b in zip(params[0], params_unmasked, strict=True))


def _broadcast(valid: np.ndarray, leaf: np.ndarray) -> np.ndarray:
    return valid.reshape(valid.shape + (1,) * (leaf.ndim - valid.ndim))


def _ppo_agent(env, **overrides):
    cfg = dataclasses.replace(presets.preset("ppo", "atari").config, **overrides).validate()
    return agent_maker(ppo, EnvSpec.of(env), cfg)()


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_rollout_on_a_real_pool_masks_reset_steps_after_done_steps():
    """Two 128-step rollouts of 8 Breakout envs with an untrained CNN policy (the compiled runner's
    on-policy rollout on the pool): each masked step comes right after a done step (or is the first,
    after one carried in), pays nothing, starts from the observation the done step reached, and
    finishes no game; every pool step counts as progress, and the actor's key chain is the host
    actor's (one ``split(key)`` a step)."""
    from agentax.runners.compiled_pool import PoolEnvs, start
    from agentax.runners.rollout import on_policy_rollout

    env = XlaAtari(BREAKOUT, 8, seed=3, sticky_actions=0.25)
    agent = _ppo_agent(env)
    rollout = jax.jit(on_policy_rollout(agent, PoolEnvs(env)))
    carry = start(agent.init(jax.random.key(0)), env, jax.random.key(1), 0)
    masked = ends = 0
    for i in range(2):  # the second rollout starts with the resets the first one's last steps left
        carried_in = int(carry.env_state.tracker.reset_next.sum())
        carry, trajectory = rollout(carry)
        traj = jax.device_get(trajectory)
        valid, done = traj.info["valid"], traj.terminated | traj.truncated
        np.testing.assert_array_equal(~valid[1:], done[:-1])
        assert not (done & ~valid).any() and (traj.reward[~valid] == 0).all()
        assert not (traj.info["games"].finished & ~valid).any()
        assert int(carry.episodes.env_steps) == 8 * 128 * (i + 1)
        np.testing.assert_array_equal(traj.obs[1:], traj.next_obs[:-1])  # one stream of observations
        masked += int((~valid).sum()) - carried_in
        ends += int(done[:-1].sum())
        assert set(np.unique(traj.reward)) <= {-1.0, 0.0, 1.0}
    env.close()
    assert ends >= 5 and masked == ends
    key = jax.random.key(1)
    for _ in range(2 * 128):
        key, _ = jax.random.split(key)
    np.testing.assert_array_equal(jax.random.key_data(carry.key), jax.random.key_data(key))


def _host_env(training: bool, seed: int):
    from agentax.envs.atari import make_atari

    env = make_atari(BREAKOUT, 8, backend="envpool", sticky_actions=0.25, training=training)
    env.reset(seed=seed)
    return env


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_in_program_pool_plays_the_host_adapters_games():
    """Same seed, same actions (the in-program pool gets an extra, different action on each reset
    step, which EnvPool ignores): frame for frame the same games, the same learning view (clipped
    rewards, a lost life ends an episode) and the same whole games (true score, length) per env as
    the host adapter's ``drain_scores``."""
    seed, num_steps = 11, 450
    actions = np.random.default_rng(0).integers(4, size=(num_steps, 8))
    train_env, eval_env = _host_env(True, seed), _host_env(False, seed)
    host_games: list[list[tuple[float, int]]] = [[] for _ in range(8)]
    host_steps = []
    for action in actions:
        ts, evaluation = train_env.step(action), eval_env.step(action)
        drained = eval_env.drain_scores()
        for i, game in zip(
            np.flatnonzero(evaluation.terminated | evaluation.truncated), drained, strict=True
        ):
            host_games[i].append(game)
        host_steps.append(ts)
    train_env.close()
    eval_env.close()

    env = XlaAtari(BREAKOUT, 8, seed=seed, sticky_actions=0.25)
    step_and_track = jax.jit(lambda handle, tracker, a: _step_and_track(env, handle, tracker, a))
    handle, obs = env.reset()
    tracker = EpisodeTracker.create(8)
    played = np.zeros(8, int)  # valid steps per env: the host adapter's step index
    games: list[list[tuple[float, int]]] = [[] for _ in range(8)]
    ignored = np.random.default_rng(1).integers(1, 4, size=8)  # never the host adapter's 0
    while played.min() < num_steps:
        reset_step = np.asarray(tracker.reset_next)
        index = np.minimum(played, num_steps - 1)
        action = np.where(reset_step, ignored, actions[index, np.arange(8)])
        handle, tracker, step, tracked = step_and_track(handle, tracker, jnp.asarray(action))
        valid = np.asarray(tracked.valid) & (played < num_steps)
        for i in np.flatnonzero(valid):
            host = host_steps[played[i]]
            np.testing.assert_array_equal(np.asarray(step.obs[i]), host.final_obs[i])
            assert np.sign(float(step.reward[i])) == host.reward[i]
            assert bool(step.terminated[i]) == host.terminated[i]
            assert bool(step.truncated[i]) == host.truncated[i]
            if tracked.game_finished[i]:
                games[i].append((float(tracked.game_score[i]), int(tracked.game_length[i])))
        played += valid
    env.close()
    assert games == host_games
    assert sum(map(len, games)) >= 8 and any(score > 0 for g in games for score, _ in g)


def _step_and_track(env, handle, tracker, action):
    handle, step = env.step(handle, action)
    tracker, tracked = track(tracker, step)
    return handle, tracker, step, tracked


@pytest.mark.timeout(30)
def test_refuses_what_it_cannot_run():
    from agentax.runners.compiled_pool import Config, check

    agent = agent_maker(
        ppo, EnvSpec((4, 84, 84), Discrete(4), jnp.uint8), presets.preset("ppo", "atari").config
    )()
    with pytest.raises(UsageError, match="cannot be vmapped over seeds"):
        check(agent, BREAKOUT, Config(), num_seeds=2)
    with pytest.raises(UsageError, match="--env-backend ale"):
        check(agent, BREAKOUT, Config(env_backend="ale"))
    with pytest.raises(UsageError, match="Atari games"):
        check(agent, "CartPole-v1", Config())


@pytest.mark.slow
@pytest.mark.timeout(150)
def test_short_run_writes_the_run_folder_loads_and_resumes(tmp_path):
    """Two iterations of 2 envs x 32 steps: metrics rows, a checkpoint that the host runner's
    ``host.restore`` loads into the trained greedy policy, eval.json and curve.png; resumed with a
    longer budget it continues from iteration 2."""
    from agentax.runners import compiled_pool, host

    probe = XlaAtari(BREAKOUT, 1, sticky_actions=0.0)
    overrides = dict(num_envs=2, num_steps=32, num_minibatches=2, update_epochs=1)
    agent = _ppo_agent(probe, total_steps=128, **overrides)
    probe.close()
    runner = compiled_pool.Config(log_every_steps=64, eval_episodes=1, sticky_actions=0.0)
    config = run_config("ppo", BREAKOUT, "atari", "compiled-atari", runner, {})
    run = Run.create(tmp_path / "run", config)
    result = compiled_pool.train(agent, BREAKOUT, runner, run)
    assert result.updates == 2 and result.env_steps == 128
    rows = read_metrics(tmp_path / "run")
    assert [r["env_steps"] for r in rows] == [64, 128] and [r["frames"] for r in rows] == [256, 512]
    for column in ("mean_return", "steps_per_second", "policy_loss", "masked_fraction"):
        assert column in rows[0]
    evaluation = json.loads((tmp_path / "run" / "eval.json").read_text())
    assert evaluation["episodes"] == 1 and evaluation["mean_return"] >= 0
    assert (tmp_path / "run" / "curve.png").is_file()

    policy = host.restore(tmp_path / "run", {}, agent)
    obs = jnp.asarray(np.random.default_rng(0).integers(0, 256, (5, 4, 84, 84)), jnp.uint8)
    np.testing.assert_array_equal(
        policy(obs, jax.random.key(0)), agent.greedy_policy(result.state)(obs, None)
    )

    longer = _ppo_agent(probe, total_steps=256, **overrides)
    resumed = compiled_pool.train(longer, BREAKOUT, runner, Run.open(tmp_path / "run"), resume=True)
    assert resumed.updates == 4
    assert [r["env_steps"] for r in read_metrics(tmp_path / "run")] == [64, 128, 192, 256]


def _versioned_steps(lag: int, count: int):
    """The compiled EnvPool runner's iterations on a stand-in whose parameters are a version number:
    ``collect`` records the version it acted with, ``learn`` makes the next version; with lag 1,
    learning on rollout k waits until the collection of rollout k+1 has begun (it would time out
    if the two ran one after the other)."""
    import threading

    from agentax.runners.compiled_pool import in_one_program, side_by_side
    from agentax.runners.rollout import OnPolicyCarry

    began = [threading.Event() for _ in range(count + 1)]
    collected: list[int] = []

    def collect(carry):
        began[len(collected)].set()
        collected.append(int(carry.agent))
        return carry, {"k": len(collected) - 1}, None

    def learn(state, trajectory, key):
        if lag and trajectory["k"] + 1 < count:
            assert began[trajectory["k"] + 1].wait(timeout=10), "rollout k+1 did not run beside learning on k"
        return state + 1, key, {"learned_on": trajectory["k"]}

    def update(carry, key):
        carry, trajectory, games = collect(carry)
        state, key, metrics = learn(carry.agent, trajectory, key)
        return carry.replace(agent=state), key, metrics, games

    carry = OnPolicyCarry(0, None, None, None, None)
    steps = side_by_side(collect, learn, carry, None, count) if lag else in_one_program(update, carry, None)
    states = [state for state, _, _, _ in (next(steps) for _ in range(count))]
    steps.close()
    return collected, states


@pytest.mark.timeout(60)
def test_policy_lag_1_collects_rollout_k_plus_1_beside_learning_on_k_with_its_starting_parameters():
    """Lag 0: rollout k acts with the parameters of k updates. Lag 1: rollout k+1 is collected
    while the learner updates on rollout k, with the parameters that update starts from, so each
    rollout is one version behind lag 0's (the first two both act with the starting parameters);
    the learner's versions are the same, and no rollout is collected past the last update."""
    collected, states = _versioned_steps(lag=0, count=5)
    assert collected == [0, 1, 2, 3, 4] and states == [1, 2, 3, 4, 5]
    collected, states = _versioned_steps(lag=1, count=5)
    assert collected == [0, 0, 1, 2, 3] and states == [1, 2, 3, 4, 5]


@pytest.mark.slow
@pytest.mark.timeout(150)
def test_policy_lag_1_on_a_real_pool_learns_the_first_update_as_lag_0_and_then_goes_its_way(tmp_path):
    """Two iterations of 2 Breakout envs × 32 steps at lag 0 and at lag 1 (a row each, a large
    step size so that one update changes how the policy acts): the first rollouts act with the same
    parameters, so the first rows agree; the second acts with older ones at lag 1, so the second
    rows do not. A bad lag is refused."""
    from agentax.runners import compiled_pool
    from agentax.runners.compiled_pool import Config

    probe = XlaAtari(BREAKOUT, 1, sticky_actions=0.0)
    overrides = dict(num_envs=2, num_steps=32, num_minibatches=2, update_epochs=1, learning_rate=0.05)
    agent = _ppo_agent(probe, total_steps=128, **overrides)
    probe.close()
    losses = {}
    for lag in (0, 1):
        runner = Config(log_every_steps=64, eval_episodes=1, sticky_actions=0.0, policy_lag=lag)
        config = run_config("ppo", BREAKOUT, "atari", "compiled-atari", runner, {})
        result = compiled_pool.train(agent, BREAKOUT, runner, Run.create(tmp_path / f"lag{lag}", config))
        assert result.updates == 2 and result.env_steps == 128
        losses[lag] = np.array(
            [[r["policy_loss"], r["value_loss"]] for r in read_metrics(tmp_path / f"lag{lag}")]
        )
    np.testing.assert_allclose(losses[1][0], losses[0][0], rtol=1e-4)
    assert not np.allclose(losses[1][1], losses[0][1], rtol=1e-3)
    with pytest.raises(UsageError, match="policy lag 0 or 1"):
        compiled_pool.check(agent, BREAKOUT, Config(policy_lag=2))


@pytest.mark.long  # ~40 s: make test-long (2,400 iterations in 6 processes ran clean on 2026-12-06)
@pytest.mark.timeout(170)
def test_policy_lag_1_runs_400_iterations_without_hanging():
    """XLA's CPU client hung on some programs called again and again (DESIGN.md's hazard): 400
    iterations of a small PPO's rollout in a thread beside its learning, in a fresh process."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(
        """
        import dataclasses, jax
        from agentax import _xla
        _xla.let_xla_use_every_cpu()
        from agentax.agents import ppo, presets
        from agentax.agents.protocol import EnvSpec
        from agentax.envs.envpool_xla import XlaAtari
        from agentax.runners import compiled_pool as ca
        from agentax.runners.launch import agent_maker
        probe = XlaAtari("ALE/Breakout-v5", 1, sticky_actions=0.0)
        cfg = dataclasses.replace(presets.preset("ppo", "atari").config, num_envs=4, num_steps=16,
                                  num_minibatches=2, update_epochs=1).validate()
        agent = agent_maker(ppo, EnvSpec.of(probe), cfg)()
        probe.close()
        env = ca.make_pool("ALE/Breakout-v5", 4, 0, ca.Config())
        carry = ca.start(agent.init(jax.random.key(0)), env, jax.random.key(1), 0)
        collect, learn = jax.jit(ca.make_collect(agent, env)), jax.jit(ca.make_learn(agent))
        steps = ca.side_by_side(collect, learn, carry, jax.random.key(2), 400)
        done = sum(1 for _, _, metrics, _ in steps if jax.block_until_ready(metrics) is not None)
        env.close()
        print("iterations", done)
        """
    )
    ran = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=160)
    assert ran.returncode == 0 and "iterations 400" in ran.stdout, ran.stderr[-2000:]


@pytest.mark.slow
@pytest.mark.timeout(150)
def test_a_recurrent_rollout_on_a_real_pool_starts_memory_after_each_reset_step():
    """PPO with a core on the pool: the carry holds each env's memory; an episode starts at the
    observation a reset step returns (the ending step returns the last observation itself), so
    ``info["first"]`` follows each masked step, and is true for every env at the start."""
    from agentax.runners.compiled_pool import PoolEnvs, start
    from agentax.runners.rollout import RecurrentCarry, on_policy_rollout

    env = XlaAtari(BREAKOUT, 2, seed=3, sticky_actions=0.25)
    agent = _ppo_agent(env, num_envs=2, num_steps=64, num_minibatches=2, core="gru", core_size=8)
    rollout = jax.jit(on_policy_rollout(agent, PoolEnvs(env)))
    carry = start(agent.init(jax.random.key(0)), env, jax.random.key(1), 0, agent)
    assert isinstance(carry, RecurrentCarry) and carry.first.all()
    resets = 0
    for _ in range(2):
        first_in = np.asarray(carry.first)
        carry, trajectory = rollout(carry)
        valid, first = jax.device_get((trajectory.info["valid"], trajectory.info["first"]))
        np.testing.assert_array_equal(first[0], first_in)
        np.testing.assert_array_equal(first[1:], ~valid[:-1])
        np.testing.assert_array_equal(np.asarray(carry.first), ~valid[-1])
        resets += int((~valid).sum())
    env.close()
    assert resets >= 2  # random play loses a life every ~24 steps
