"""MuJoCo: Gymnasium's v5 tasks on the host, EnvPool's inside the compiled program, and the two agree.

Checked: a MuJoCo id without ``mujoco`` is one line naming the extra; the two backends' spaces and
reward settings; the same reset (reset noise 0 in both) and the same actions give the same rewards,
observations, terminations and time limit, EnvPool's in-program pool against Gymnasium's env (so
also the float64 call traced under ``enable_x64``); PPO's Gaussian head for two updates on the host
runner (HalfCheetah) and on the compiled EnvPool runner (Hopper, whose falls exercise EnvPool's
reset step); the runner ``--runner compiled`` and ``auto`` choose; a video where EGL works, one
line where no OpenGL does.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.agents import algorithm, ppo, presets
from agentax.agents.protocol import EnvSpec
from agentax.errors import UsageError
from agentax.runners import kind_for
from agentax.runners.launch import agent_maker
from agentax.runs import Run, read_metrics, run_config

pytest.importorskip("mujoco")
envpool = pytest.importorskip("envpool")

from agentax.envs.envpool_xla import XlaMujoco  # noqa: E402  (after the skips: it needs envpool)
from agentax.envs.gym import require_mujoco  # noqa: E402

require_mujoco("HalfCheetah-v5")  # (its warning handler: Gymnasium's files use a deprecated attribute)

TASKS = ("HalfCheetah-v5", "Hopper-v5", "Walker2d-v5", "Ant-v5", "Humanoid-v5")


def test_a_mujoco_id_without_mujoco_names_the_extra(monkeypatch, capsys, tmp_path):
    from agentax.cli import main

    monkeypatch.setitem(sys.modules, "mujoco", None)  # `import mujoco` raises ImportError
    code = main(["train", "ppo", "--env", "HalfCheetah-v5", "--runner", "host", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
    assert err == (
        "agentax train: error: HalfCheetah-v5 needs MuJoCo, which is not installed: "
        "pip install 'agentax[mujoco]'"
    )
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("task", TASKS)
def test_envpool_and_gymnasium_spaces_agree(task):
    gym_env = gymnasium.make(task)
    spec = envpool.make_spec(task)
    config = spec.config._asdict()
    assert spec.observation_space.shape == gym_env.observation_space.shape
    # EnvPool's bounds are float64, Gymnasium's float32 (Humanoid's ±0.4 differs by 6e-9)
    np.testing.assert_array_equal(spec.action_space.low.astype(np.float32), gym_env.action_space.low)
    np.testing.assert_array_equal(spec.action_space.high.astype(np.float32), gym_env.action_space.high)
    assert config["max_episode_steps"] == gym_env.spec.max_episode_steps == 1000
    assert config["frame_skip"] == gym_env.unwrapped.frame_skip
    assert config["reset_noise_scale"] == gym_env.unwrapped._reset_noise_scale
    gym_env.close()


def test_reward_and_termination_settings_agree():
    """The weights of each reward term and Hopper's healthy range, as both define them."""
    cheetah, pool = gymnasium.make("HalfCheetah-v5").unwrapped, envpool.make_spec("HalfCheetah-v5").config
    assert pool.ctrl_cost_weight == cheetah._ctrl_cost_weight == 0.1
    assert pool.forward_reward_weight == cheetah._forward_reward_weight == 1.0
    hopper, pool = gymnasium.make("Hopper-v5").unwrapped, envpool.make_spec("Hopper-v5").config._asdict()
    assert pool["ctrl_cost_weight"] == hopper._ctrl_cost_weight == 1e-3
    assert pool["healthy_reward"] == hopper._healthy_reward == 1.0
    assert pool["terminate_when_unhealthy"] and hopper._terminate_when_unhealthy
    assert (pool["healthy_z_min"], np.inf) == hopper._healthy_z_range == (0.7, np.inf)
    assert (pool["healthy_angle_min"], pool["healthy_angle_max"]) == hopper._healthy_angle_range
    assert (pool["healthy_state_min"], pool["healthy_state_max"]) == hopper._healthy_state_range
    assert not pool["legacy_healthy_reward"]  # v5: the healthy reward only while healthy, as Gymnasium's v5


def _pool_episode(task: str, actions: np.ndarray):
    """EnvPool's in-program pool (1 env, no reset noise) stepped by ``actions [T, d]`` in one jitted
    scan: ``(obs [T, o], reward [T], terminated [T], truncated [T])`` and the reset observation."""
    pool = XlaMujoco(task, 1, seed=0, reset_noise_scale=0.0)
    handle, first_obs = pool.reset()

    def body(handle, action):
        handle, step = pool.step(handle, action[None])
        return handle, (step.obs[0], step.reward[0], step.game_over[0], step.truncated[0])

    _, outputs = jax.jit(lambda h, a: jax.lax.scan(body, h, a))(handle, jnp.asarray(actions))
    outputs = jax.device_get(outputs)
    pool.close()
    return outputs, np.asarray(first_obs[0])


def _gymnasium_episode(task: str, actions: np.ndarray):
    """Gymnasium's env (no reset noise) stepped by ``actions`` until its episode ends."""
    env = gymnasium.make(task, reset_noise_scale=0.0)
    first_obs, _ = env.reset(seed=0)
    rows = []
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        rows.append((obs, reward, terminated, truncated))
        if terminated or truncated:
            break
    env.close()
    obs, reward, terminated, truncated = (np.asarray(column) for column in zip(*rows, strict=True))
    return (obs, reward, terminated, truncated), first_obs


def test_half_cheetah_same_reset_same_actions_same_rewards():
    """HalfCheetah, 1001 random actions: rewards and observations equal to 1e-5 over the first 50
    steps (EnvPool's MuJoCo 3.6 and Gymnasium's 4.0 round differently: 1e-15 at first, growing
    chaotically to 1e-3 by step ~100); both truncate at step 1000 and never terminate; EnvPool's
    step 1001 is its reset step (reward 0, the reset observation)."""
    actions = np.random.default_rng(0).uniform(-1, 1, (1001, 6)).astype(np.float32)
    (p_obs, p_reward, p_term, p_trunc), p_first = _pool_episode("HalfCheetah-v5", actions)
    (g_obs, g_reward, g_term, g_trunc), g_first = _gymnasium_episode("HalfCheetah-v5", actions)
    np.testing.assert_allclose(p_first, g_first, atol=1e-6)
    np.testing.assert_allclose(p_reward[:50], g_reward[:50], atol=1e-5)
    np.testing.assert_allclose(p_obs[:50], g_obs[:50], atol=1e-5)
    assert len(g_reward) == 1000 and g_trunc[-1] and not g_term.any()
    assert np.flatnonzero(p_trunc).tolist() == [999] and not p_term.any()
    assert p_reward[1000] == 0.0
    np.testing.assert_allclose(p_obs[1000], g_first, atol=1e-6)


def test_hopper_same_reset_same_actions_same_fall():
    """Hopper, random actions: the same rewards (to 1e-5) until both terminate on the same step
    (it leaves the healthy range); EnvPool's next step is its reset step."""
    actions = np.random.default_rng(1).uniform(-1, 1, (200, 3)).astype(np.float32)
    (p_obs, p_reward, p_term, p_trunc), _ = _pool_episode("Hopper-v5", actions)
    (g_obs, g_reward, g_term, _), g_first = _gymnasium_episode("Hopper-v5", actions)
    end = len(g_reward) - 1
    assert g_term[end] and 5 < end < 199
    assert np.flatnonzero(p_term)[0] == end and not p_trunc[: end + 1].any()
    np.testing.assert_allclose(p_reward[: end + 1], g_reward, atol=1e-5)
    np.testing.assert_allclose(p_obs[: end + 1], g_obs, atol=1e-5)
    assert p_reward[end + 1] == 0.0
    np.testing.assert_allclose(p_obs[end + 1], g_first, atol=1e-6)


def test_compiled_picks_envpool_and_auto_the_host():
    assert kind_for("compiled", "HalfCheetah-v5") == "compiled-mujoco"
    assert kind_for("auto", "HalfCheetah-v5") == "host"
    assert kind_for("parallel", "Hopper-v5") == "parallel"


def _ppo_agent(spec: EnvSpec, total_steps: int, num_envs: int, num_steps: int):
    cfg = presets.preset("ppo", "default").config
    cfg = dataclasses.replace(
        cfg,
        total_steps=total_steps,
        num_envs=num_envs,
        num_steps=num_steps,
        num_minibatches=2,
        update_epochs=1,
    ).validate()
    return agent_maker(ppo, spec, cfg)()


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_host_ppo_on_half_cheetah_two_updates(tmp_path):
    """PPO's Gaussian head on Gymnasium's HalfCheetah-v5 (host runner): 2 envs x 128 steps, two
    updates; float32 observations; the greedy policy's evaluation episode runs its 1000 steps."""
    from agentax.envs import make_host_env
    from agentax.runners import host

    probe = make_host_env("HalfCheetah-v5", 1)
    spec = EnvSpec.of(probe)
    probe.close()
    assert spec.obs_shape == (17,) and spec.obs_dtype == jnp.float32 and spec.action_space.shape == (6,)
    agent = _ppo_agent(spec, total_steps=512, num_envs=2, num_steps=128)
    runner = host.HostRunnerConfig(log_every_steps=256, eval_episodes=1)
    run = Run.create(tmp_path / "run", run_config("ppo", "HalfCheetah-v5", "default", "host", runner, {}))
    result = host.train(agent, "HalfCheetah-v5", runner, run)
    assert result.updates == 2 and result.env_steps == 512
    rows = read_metrics(tmp_path / "run")
    assert [r["env_steps"] for r in rows] == [256, 512]
    assert all(np.isfinite(r["policy_loss"]) and np.isfinite(r["value_loss"]) for r in rows)
    evaluation = json.loads((tmp_path / "run" / "eval.json").read_text())
    assert evaluation["episodes"] == 1 and evaluation["mean_length"] == 1000
    assert np.isfinite(evaluation["mean_return"])


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_compiled_ppo_on_hopper_two_updates(tmp_path):
    """PPO with EnvPool's Hopper-v5 inside the program: 4 envs x 64 steps, two updates. An untrained
    Hopper falls within ~20-80 steps, so episodes finish (a mean return in each row) and EnvPool's
    reset steps are masked (``masked_fraction`` > 0); the checkpoint loads as the host runner's.
    Policy lag 1: the second rollout runs beside the first update."""
    from agentax.runners import compiled_pool, host

    pool = XlaMujoco("Hopper-v5", 1)
    spec = EnvSpec.of(pool)
    pool.close()
    agent = _ppo_agent(spec, total_steps=512, num_envs=4, num_steps=64)
    runner = compiled_pool.Config(log_every_steps=256, eval_episodes=1, policy_lag=1)
    kind = "compiled-mujoco"
    run = Run.create(tmp_path / "run", run_config("ppo", "Hopper-v5", "default", kind, runner, {}))
    result = compiled_pool.train(agent, "Hopper-v5", runner, run)
    assert result.updates == 2 and result.env_steps == 512
    rows = read_metrics(tmp_path / "run")
    assert [r["env_steps"] for r in rows] == [256, 512] and "frames" not in rows[0]
    assert all(0 < r["masked_fraction"] < 0.2 for r in rows)
    assert all(np.isfinite(r["mean_return"]) and r["mean_return"] > 0 for r in rows)  # alive: +1 a step
    assert json.loads((tmp_path / "run" / "eval.json").read_text())["episodes"] == 1
    obs = jnp.asarray(np.random.default_rng(0).normal(size=(3, 11)), jnp.float32)
    policy = host.restore(tmp_path / "run", {}, agent)
    np.testing.assert_array_equal(
        policy(obs, jax.random.key(0)), agent.greedy_policy(result.state)(obs, None)
    )


def _sac_agent(spec: EnvSpec, **settings):
    cfg = presets.preset("sac", "mujoco", hidden=(64, 64), batch_size=64, **settings).config
    return agent_maker(algorithm("sac"), spec, cfg)()


def test_compiled_runner_refuses_what_its_program_cannot_train():
    from agentax.runners.compiled_pool import Config, check

    spec = EnvSpec((11,), XlaMujoco("Hopper-v5", 1).action_space())
    agent = _ppo_agent(spec, total_steps=512, num_envs=4, num_steps=64)
    check(agent, "Hopper-v5", Config())
    with pytest.raises(UsageError, match="MuJoCo tasks"):
        check(agent, "Pendulum-v1", Config())
    with pytest.raises(UsageError, match="--env-backend ale"):
        check(agent, "Hopper-v5", Config(env_backend="ale"))
    check(_sac_agent(spec), "Hopper-v5", Config())  # SAC and TD3 with one env and one-step targets
    for settings in ({"num_envs": 2}, {"n_step": 3}):
        with pytest.raises(UsageError, match="one env and one-step targets"):
            check(_sac_agent(spec, **settings), "Hopper-v5", Config())


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_compiled_sac_on_hopper_keeps_its_replay_in_the_program_and_beside_the_checkpoints(tmp_path):
    """SAC with EnvPool's Hopper-v5, the replay and learning in one program: 600 steps in rows of 200.
    An untrained Hopper falls within ~20-80 steps, so EnvPool's reset steps come often: none of them
    is stored (the replay holds fewer transitions than steps). The replay is saved beside each
    checkpoint, and a resumed run restores it into the program's carry."""
    from agentax.runners import compiled_pool

    pool = XlaMujoco("Hopper-v5", 1)
    spec = EnvSpec.of(pool)
    pool.close()
    agent = _sac_agent(spec, total_steps=600, learning_starts=200)
    runner = compiled_pool.Config(log_every_steps=200, eval_episodes=1)
    config = run_config("sac", "Hopper-v5", "mujoco", "compiled-mujoco", runner, {})
    result = compiled_pool.train(agent, "Hopper-v5", runner, Run.create(tmp_path / "run", config))
    assert result.updates == 600 and result.env_steps == 600
    rows = read_metrics(tmp_path / "run")
    assert [r["env_steps"] for r in rows] == [200, 400, 600]
    assert all(np.isfinite(r["mean_return"]) for r in rows)  # falls: episodes end in every row
    assert 500 < rows[-1]["replay_size"] < 600  # a reset step after each fall, none of them stored
    assert all(np.isfinite(r["critic_loss"]) and r["critic_loss"] > 0 for r in rows)  # from step 200 on
    assert list((tmp_path / "run" / "checkpoints").glob("replay-*.npz"))
    resumed = compiled_pool.train(agent, "Hopper-v5", runner, Run.open(tmp_path / "run"), resume=True)
    assert resumed.updates == 600  # restored at its end, its replay loaded into the carry: nothing left


def test_the_programs_replay_saves_and_loads_as_a_replay_buffer():
    from flax import struct

    from agentax.replay import uniform
    from agentax.runners.compiled_pool import ProgramReplay

    @struct.dataclass
    class Carry:
        replay: uniform.UniformState

    empty = Carry(uniform.init(4, {"obs": jnp.zeros(3), "reward": jnp.float32(0)}))
    filled = empty.replace(replay=uniform.add(empty.replay, {"obs": jnp.ones((3, 3)), "reward": jnp.ones(3)}))
    loaded = ProgramReplay(empty)
    loaded.load_state_dict(ProgramReplay(filled).state_dict())
    assert int(loaded.carry.replay.size) == 3
    for got, want in zip(jax.tree.leaves(loaded.carry), jax.tree.leaves(filled), strict=True):
        np.testing.assert_array_equal(got, want)


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_no_opengl_is_one_line(tmp_path):
    """GLFW without a display cannot draw: ``agentax play`` says so in one line (in a process of its
    own: a process that has loaded one OpenGL platform cannot load another)."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    video = tmp_path / "hopper.gif"
    command = [sys.executable, "-m", "agentax.cli", "play", "--env", "Hopper-v5", "--policy", "random"]
    done = subprocess.run(  # in tmp_path: MuJoCo logs its errors to ./MUJOCO_LOG.TXT
        [*command, "--video", str(video)],
        env={**env, "MUJOCO_GL": "glfw"},
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    lines = [line for line in done.stderr.splitlines() if line.startswith("agentax play: error:")]
    assert done.returncode == 2 and len(lines) == 1 and not video.exists()
    assert (
        "cannot render Hopper-v5 off screen with MUJOCO_GL=glfw" in lines[0] and "MUJOCO_GL=egl" in lines[0]
    )
    assert "Traceback" not in done.stderr


@pytest.mark.slow
def test_video_of_a_mujoco_episode_where_egl_works(monkeypatch, tmp_path):
    """Hopper with random actions drawn through EGL (skipped, with its one line, where EGL is
    missing): 320x240 frames that are not blank, every third step (125 fps written at 41.7)."""
    import imageio.v3 as iio

    from agentax.envs import make
    from agentax.policies import random_policy
    from agentax.render import save_episode

    monkeypatch.setenv("MUJOCO_GL", "egl")
    env = make("Hopper-v5")
    try:
        path, episode = save_episode(env, random_policy(env.action_space()), tmp_path / "hopper.gif", seed=0)
    except UsageError as error:
        pytest.skip(str(error))
    finally:
        env.close()
    assert 5 < episode.length < 1000 and episode.fps == pytest.approx(125 / 3)
    frames = iio.imread(path, index=None)
    assert frames.shape[1:3] == (240, 320) and len(frames) == episode.length // 3 + 1 + (
        episode.length % 3 > 0
    )
    assert frames[0].std() > 10  # a scene, not a blank image
