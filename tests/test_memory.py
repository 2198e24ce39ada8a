"""A learning step larger than memory (issue 39): ``--batch-size`` of every off-policy agent, and the
rollout of the on-policy ones, refused up front in one line with the bytes needed and available,
instead of XLA's RESOURCE_EXHAUSTED traceback mid-run; the estimate checked against XLA's own."""

import dataclasses
import subprocess
import sys

import jax
import pytest

from agentax.agents import algorithm, algorithm_config, memory
from agentax.agents.protocol import EnvSpec
from agentax.cli import main
from agentax.envs import make_jax


@pytest.mark.parametrize(
    ("argv", "setting"),
    [
        (
            ["sac", "--env", "Pendulum-v1", "--batch-size", "100000000"],
            "--batch-size 100,000,000 needs about",
        ),
        (
            ["td3", "--env", "Pendulum-v1", "--batch-size", "100000000"],
            "--batch-size 100,000,000 needs about",
        ),
        (["dqn", "--env", "CartPole-v1", "--batch-size", "1000000000"], "--batch-size 1,000,000,000 needs"),
        (["dqn", "--env", "Acrobot-v1", "--batch-size", "1000000000"], "--batch-size 1,000,000,000 needs"),
        (
            ["ppo", "--env", "CartPole-v1", "--num-envs", "10000", "--num-steps", "100000"],
            "--num-envs 10,000 × --num-steps 100,000 needs about",
        ),
    ],
)
def test_a_learning_step_past_memory_is_one_line_and_nothing_written(argv, setting, capsys, tmp_path):
    out = tmp_path / "run"
    assert main(["train", *argv, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"agentax train: error: {setting}") and err.count("\n") == 1, err
    assert "GB for one learning step (" in err and "GB of memory is available; lower it to about" in err
    assert not out.exists()


def test_the_message_names_the_bytes_and_what_fits(monkeypatch, capsys, tmp_path):
    """With 1 GB available, SAC's batch of 10**6 transitions (about 27 KB each on Pendulum) is refused
    and the line says how many fit; a batch that fits once but not for 200 seeds side by side blames
    --seeds."""
    monkeypatch.setattr(memory, "available_memory", lambda: 10**9)
    argv = ["train", "sac", "--env", "Pendulum-v1", "--out", str(tmp_path / "r"), "--no-progress"]
    assert main([*argv, "--batch-size", "1000000"]) == 2
    err = capsys.readouterr().err
    assert "only 1.0 GB of memory is available" in err and "bytes per transition)" in err, err
    fits = int(err.split("lower it to about ")[1].split()[0].replace(",", ""))
    assert 20_000 < fits < 60_000, err
    assert main([*argv, "--batch-size", "10000", "--seeds", "200"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("agentax train: error: --seeds 200 needs about") and "bytes a seed)" in err, err
    assert 2 < int(err.split("at most about ")[1].split()[0]) < 6, err  # 1 GB / (10,000 × ~27 KB)


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize(
    ("algo", "env_id", "sizes"),
    [
        ("sac", "Pendulum-v1", {"batch_size": 8192}),
        ("dqn", "CartPole-v1", {"batch_size": 8192}),
        ("ppo", "CartPole-v1", {"num_envs": 64, "num_steps": 256}),
    ],
)
def test_the_estimate_is_within_a_factor_of_two_or_so_of_xlas_own(algo, env_id, sizes):
    """``learning_bytes`` (a trace) against the arguments and temporaries XLA allocates for the
    compiled ``learn`` on the same shapes: between half and two and a half times."""
    spec = EnvSpec.of(make_jax(env_id))
    cfg = dataclasses.replace(algorithm_config(algo)(), **sizes)
    agent = algorithm(algo).make_agent(spec, cfg)
    state, experience = memory.learn_input(agent, spec)
    compiled = jax.jit(agent.learn).lower(state, experience, jax.random.key(0)).compile()
    analysis = compiled.memory_analysis()
    xla = analysis.temp_size_in_bytes + analysis.argument_size_in_bytes
    estimate = memory.learning_bytes(agent, spec)
    assert 0.5 * xla < estimate < 2.5 * xla, (estimate, xla)


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_check_leaves_jax_without_a_cpu_client():
    """The check runs before the runner chooses how jax makes its CPU client (every CPU for the host
    and parallel runners): it traces on abstract values only, so no client exists after it."""
    script = (
        "import agentax\n"
        "from jax._src import xla_bridge\n"
        "from agentax.agents import algorithm, algorithm_config\n"
        "from agentax.runners.launch import env_specs\n"
        "from agentax.agents.memory import check_learning_fits\n"
        "for algo in ('dqn', 'ppo', 'reinforce'):\n"
        "    spec, _ = env_specs('host', 'Acrobot-v1')\n"
        "    check_learning_fits(algorithm(algo).make_agent(spec, algorithm_config(algo)()), spec)\n"
        "print('cpu' in xla_bridge._backends)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=100)
    assert done.returncode == 0 and done.stdout.strip() == "False", done.stderr[-2000:]
