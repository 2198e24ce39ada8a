"""The Python API: ``agentax.train(...) -> Run``, ``agentax.load(dir)``, and what a Run gives; the
``agentax.train`` name as function and subpackage; a wheel of the tree installs and runs."""

import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import agentax
import agentax.runners.compiled
from agentax.agents import ALGORITHMS
from agentax.cli import main
from agentax.errors import UsageError
from agentax.runners.session import TrainResult

REPO = Path(__file__).resolve().parents[1]
SMALL = {"total_steps": 2048, "learning_rate": 2e-3}  # 8 updates of cartpole-fast's 8 envs × 32 steps


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """PPO on CartPole-v1, 2 seeds vmapped, through the API (one training shared by the tests below)."""
    out = tmp_path_factory.mktemp("api") / "ppo"
    return agentax.train("ppo", env="CartPole-v1", seeds=2, out=out, progress=False, **SMALL)


@pytest.mark.xdist_group("api")  # one worker trains the shared run once
@pytest.mark.slow
@pytest.mark.timeout(120)
def test_train_then_load_scores_the_same(trained, capsys):
    run = trained
    assert isinstance(run, agentax.Run) and isinstance(run.result, TrainResult)
    assert (run.algo, run.env, run.runner_kind) == ("ppo", "CartPole-v1", "compiled")
    trained_stats = run.evaluate(episodes=20, seed=3)  # the policy held in memory since training
    loaded = agentax.load(run.path)
    assert loaded.result is None
    assert loaded.evaluate(episodes=20, seed=3) == trained_stats  # rebuilt from the checkpoint
    # ... and what `agentax evaluate` prints for the folder
    assert main(["evaluate", "--policy", str(run.path), "--episodes", "20", "--seed", "3", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["mean_return"] == trained_stats.mean_return and printed["episodes"] == 20
    # the overrides reached the config, the rest came from the preset
    config = json.loads((run.path / "config.json").read_text())
    assert config["preset"] == "cartpole-fast" and config["config"]["learning_rate"] == 2e-3
    assert config["config"]["total_steps"] == 2048 and config["runner"]["num_seeds"] == 2
    # 2 seeds × 2048 steps are far below the workers' break-even: one process, and run.toml says so
    assert config["runner"]["workers"] == 1 and "workers = 1" in (run.path / "run.toml").read_text()
    assert run.final_eval == loaded.final_eval == json.loads((run.path / "eval.json").read_text())
    assert len(run.final_eval["per_seed"]) == 2 and "iqm_ci" in run.final_eval


@pytest.mark.xdist_group("api")  # one worker trains the shared run once
@pytest.mark.slow
def test_metrics_plot_and_video(trained, tmp_path):
    run = agentax.load(trained.path)
    rows = run.metrics
    assert rows and rows[-1]["env_steps"] == trained.result.env_steps == 2048
    assert {"mean_return", "return_seed0", "return_seed1"} <= rows[-1].keys()
    assert run.plot(tmp_path / "curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    gif = run.video(tmp_path / "episode.gif", seed=1)
    assert gif == tmp_path / "episode.gif" and gif.read_bytes()[:6] == b"GIF89a"
    mp4 = run.video(tmp_path / "episode.mp4")
    assert mp4.read_bytes()[4:8] == b"ftyp"  # an ISO media file
    with pytest.raises(UsageError, match="must end in .gif or .mp4"):
        run.video(tmp_path / "episode.avi")


@pytest.mark.xdist_group("api")  # one worker trains the shared run once
@pytest.mark.slow
def test_the_cli_trains_on_the_same_path(trained, tmp_path, capsys):
    """`agentax train` with the same settings parses into the same call: the same numbers."""
    out = tmp_path / "cli"
    argv = ["train", "ppo", "--seeds", "2", "--total-steps", "2048", "--learning-rate", "0.002"]
    assert main([*argv, "--out", str(out), "--no-progress"]) == 0
    assert "run folder:" in capsys.readouterr().out
    cli_eval = json.loads((out / "eval.json").read_text())
    assert cli_eval["per_seed"] == trained.final_eval["per_seed"]


def test_bad_overrides_name_the_known_fields(tmp_path):
    out = tmp_path / "never"
    with pytest.raises(UsageError, match="unknown ppo setting lr; the PPOConfig fields are total_steps, "):
        agentax.train("ppo", out=out, lr=0.1)
    with pytest.raises(UsageError, match="learning_rate, .*the run's: env, preset, .*envs_per_actor"):
        agentax.train("ppo", out=out, lr=0.1)
    with pytest.raises(UsageError, match="learning_rate must be positive"):
        agentax.train("ppo", out=out, learning_rate=-1.0)
    with pytest.raises(UsageError, match="--seeds must be at least 1"):
        agentax.train("ppo", out=out, seeds=0)
    with pytest.raises(UsageError, match="unknown algorithm 'alchemy'"):
        agentax.train("alchemy", out=out)
    with pytest.raises(UsageError, match="unknown ppo preset 'turbo'"):
        agentax.train("ppo", out=out, preset="turbo")
    with pytest.raises(UsageError, match="trains one seed per process"):
        agentax.train("ppo", out=out, runner="host", seeds=2)
    assert not out.exists()  # refused before anything was written
    with pytest.raises(UsageError, match="holds no run"):
        agentax.load(tmp_path)


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_host_runner_through_the_api(tmp_path):
    run = agentax.train(
        "ppo", env="CartPole-v1", runner="host", out=tmp_path / "h", progress=False, total_steps=512
    )
    assert isinstance(run.result, TrainResult) and run.runner_kind == "host"
    assert run.evaluate(episodes=5, seed=2) == agentax.load(run.path).evaluate(episodes=5, seed=2)


@pytest.mark.slow
def test_train_is_a_plain_function_beside_the_runners_package():
    """``agentax.train`` is :func:`agentax.api.train`; the runners are the package ``agentax.runners``,
    so importing a runner module never rebinds the name (in a fresh interpreter, either order)."""
    assert agentax.train is agentax.api.train and agentax.runners.session.TrainResult is TrainResult
    with pytest.raises(UsageError, match="unknown algorithm"):
        agentax.train("alchemy")
    code = (
        "import agentax.runners.host, agentax.runners.compiled\n"
        "from agentax.errors import UsageError\n"
        "import agentax\n"
        "try:\n    agentax.train('alchemy')\nexcept UsageError as e:\n    print('called:', e)\n"
        "from agentax.runners.parallel import ParallelRunnerConfig\n"
        "print(agentax.runners.host.HostRunnerConfig.__name__, ParallelRunnerConfig.__name__)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == [
        f"called: unknown algorithm 'alchemy'; choose from {', '.join(ALGORITHMS)}",
        "HostRunnerConfig ParallelRunnerConfig",
    ]


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_wheel_of_the_tree_installs_a_working_agentax(tmp_path):
    """``pip install .`` gives a working ``agentax``: the wheel built from the tree, installed into a
    new virtual environment, runs from outside the tree.

    Slow (~20 s) rather than honest-and-unaffordable: the new venv does not download JAX again.
    A venv made from .venv's interpreter with ``--system-site-packages`` would see the *base*
    Python's packages, not .venv's, so the dependencies come from .venv through a ``.pth`` line
    (a path line only: .venv's own editable install of agentax, a ``.pth`` file there, is not read).
    What is proven: the wheel holds the whole package, its metadata (version, extras) and the
    ``agentax`` entry point, and its declared dependencies are satisfied (``pip check``)."""
    venv_python = Path(sys.executable)
    source = tmp_path / "source"  # a copy: setuptools writes build/ and *.egg-info into the tree it builds
    shutil.copytree(
        REPO / "src" / "agentax", source / "src" / "agentax", ignore=shutil.ignore_patterns("__pycache__")
    )
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, source / name)
    wheels = tmp_path / "wheels"
    build = [
        venv_python,
        "-m",
        "pip",
        "wheel",
        "--no-deps",
        "--no-build-isolation",
        "-q",
        "-w",
        wheels,
        source,
    ]
    subprocess.run(build, check=True, capture_output=True, timeout=120)
    (wheel,) = wheels.glob("agentax-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        metadata = archive.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    assert {"agentax/api.py", "agentax/cli/report.py", "agentax/runners/host.py"} <= set(names)
    for extra in ("atari", "ray", "docs", "dev"):
        assert f"Provides-Extra: {extra}" in metadata

    env = tmp_path / "venv"
    subprocess.run([venv_python, "-m", "venv", "--without-pip", env], check=True, timeout=60)
    (site,) = env.glob("lib/python*/site-packages")
    (dependencies,) = [Path(p) for p in sys.path if p.endswith("site-packages") and Path(p).is_dir()][:1]
    (site / "_agentax_test_dependencies.pth").write_text(f"{dependencies}\n")
    pip = [venv_python, "-m", "pip", "--python", env / "bin" / "python"]
    subprocess.run([*pip, "install", "--no-deps", "-q", wheel], check=True, capture_output=True, timeout=120)

    outside = tmp_path / "elsewhere"
    outside.mkdir()
    version = subprocess.run(
        [env / "bin" / "agentax", "--version"], cwd=outside, capture_output=True, text=True, timeout=60
    )
    assert version.returncode == 0, version.stderr
    assert version.stdout == f"agentax {agentax.__version__}\n"
    where = subprocess.run(
        [env / "bin" / "python", "-c", "import agentax; print(agentax.__file__)"],
        cwd=outside,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert Path(where.stdout.strip()).is_relative_to(site), where  # the installed copy, not the tree
    evaluate = [env / "bin" / "agentax", "evaluate", "--env", "CartPole-v1", "--episodes", "5", "--json"]
    done = subprocess.run(evaluate, cwd=outside, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["episodes"] == 5
    checked = subprocess.run([*pip, "check"], capture_output=True, text=True, timeout=60)
    assert checked.returncode in (0, 1) and checked.stdout, checked.stderr  # it ran
    assert "agentax" not in checked.stdout, checked.stdout  # and agentax's requirements are all met
