"""Every run folder ever written still loads: the fixtures of each format version
(``tests/fixtures/runs/format-<N>/``, written by ``scripts/run_fixtures.py`` with the agentax of
that format) load, act and evaluate as that version recorded, and resume; a folder of a newer
format is one line. A change to an agent state without a migration fails here."""

import hashlib
import importlib.util
import json
import shutil
from pathlib import Path

import jax
import numpy as np
import pytest

import agentax
from agentax import formats
from agentax.api import restore_policy
from agentax.cli import main
from agentax.envs import GymnasiumEnv
from agentax.errors import UsageError
from agentax.evaluate import evaluate
from agentax.runs import checkpoints, read_json, read_metrics

FIXTURES = Path(__file__).parent / "fixtures" / "runs"
VERSIONS = sorted(int(p.name.removeprefix("format-")) for p in FIXTURES.glob("format-*"))
RUNS = [(v, name) for v in VERSIONS for name in read_json(FIXTURES / f"format-{v}" / "recorded.json")]
ENV_REPLACED = {
    (1, "Pendulum-v1"): "agentax's JAX Pendulum-v1 took the id from Gymnasium's after format 1: the "
    "same seed gives other episodes (its Gymnasium evaluation and greedy actions are still checked)"
}
"""Where ``agentax evaluate`` of an id steps another env today than it did when the fixture was written."""

_spec = importlib.util.spec_from_file_location(
    "run_fixtures", Path(__file__).parents[1] / "scripts" / "run_fixtures.py"
)
run_fixtures = importlib.util.module_from_spec(_spec)  # the fixtures' writer: their fixed observations
_spec.loader.exec_module(run_fixtures)


def copy_of(version: int, name: str, tmp_path: Path) -> Path:
    """A copy of the fixture to work on (the committed one is never written)."""
    return Path(shutil.copytree(FIXTURES / f"format-{version}" / name, tmp_path / name))


def recorded(version: int, name: str) -> dict:
    return read_json(FIXTURES / f"format-{version}" / "recorded.json")[name]


def digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_the_current_format_has_its_fixtures():
    """Raising FORMAT without writing its fixtures fails here; so does a gap in the versions."""
    assert VERSIONS == list(range(1, formats.FORMAT + 1))
    assert set(formats.FORMATS) == set(VERSIONS)
    assert set(formats.STATE_MIGRATIONS) == set(formats.CONFIG_MIGRATIONS) == set(range(1, formats.FORMAT))


@pytest.mark.slow
@pytest.mark.parametrize(("version", "name"), RUNS)
def test_a_fixture_acts_and_evaluates_as_it_did_when_written(version, name, tmp_path, capsys):
    folder = copy_of(version, name, tmp_path)
    before = digest(folder)
    want = recorded(version, name)
    env_id, policy = restore_policy(folder)
    observations = run_fixtures.observations(env_id)
    actions = np.asarray(policy(observations, jax.random.key(0)))
    np.testing.assert_allclose(actions, want["greedy_actions"], rtol=1e-5, atol=1e-5)
    on_gymnasium = evaluate(GymnasiumEnv(env_id, 5), policy, 5, 0)
    np.testing.assert_allclose(on_gymnasium.mean_return, want["gymnasium_evaluate"]["mean_return"], rtol=1e-5)
    if (version, env_id) not in ENV_REPLACED:  # what `agentax evaluate --policy DIR` printed then
        stats = agentax.load(folder).evaluate(episodes=5, seed=0)
        np.testing.assert_allclose(
            [stats.mean_return, stats.min_return, stats.max_return],
            [want["evaluate"][k] for k in ("mean_return", "min_return", "max_return")],
            rtol=1e-5,
        )
    assert digest(folder) == before  # read, never written
    err = capsys.readouterr().err
    assert err.count("run-folder format") == (version < formats.FORMAT)


@pytest.mark.slow
@pytest.mark.parametrize(("version", "name"), RUNS)
def test_a_fixture_resumes_in_todays_format(version, name, tmp_path):
    """The run continues from its checkpoint (given 2,000 steps more), and what it writes is
    today's format: config.json and its new checkpoint."""
    folder = copy_of(version, name, tmp_path)
    config = read_json(folder / "config.json")
    (start,) = checkpoints(folder)
    checkpointed = _meta_of(start)["env_steps"]
    kept = [row for row in read_metrics(folder) if row["env_steps"] <= checkpointed]
    config["config"]["total_steps"] += 2_000  # at least one more update of every fixture
    (folder / "config.json").write_text(json.dumps(config))
    run = agentax.api.resume(folder, progress=False, quiet=True)
    assert run.metrics[: len(kept)] == kept  # continued from the checkpoint, not started again
    assert run.metrics[-1]["env_steps"] > checkpointed
    assert read_json(folder / "config.json")["format"] == formats.FORMAT
    newest = checkpoints(folder)[-1]
    assert newest != start
    assert _meta_of(newest)["format"] == formats.FORMAT


def _meta_of(path: Path) -> dict:
    from flax import serialization

    return json.loads(serialization.msgpack_restore(path.read_bytes())["meta"])


def test_removing_a_migration_fails_the_fixtures(monkeypatch, tmp_path):
    """Without its migration, a format-1 PPO checkpoint no longer loads (the test above is not vacuous)."""
    monkeypatch.setitem(formats.STATE_MIGRATIONS, 1, lambda state, algo: state)
    with pytest.raises(UsageError, match="obs_stats"):
        restore_policy(copy_of(1, "ppo-host", tmp_path))


@pytest.mark.parametrize("where", ["config.json", "checkpoint"])
def test_a_folder_of_a_newer_format_is_one_line(where, tmp_path, capsys):
    from flax import serialization

    folder = copy_of(formats.FORMAT, "ppo-host", tmp_path)
    newer = formats.FORMAT + 1
    if where == "config.json":
        config = read_json(folder / "config.json")
        (folder / "config.json").write_text(json.dumps({**config, "format": newer}))
    else:
        (path,) = checkpoints(folder)
        payload = serialization.msgpack_restore(path.read_bytes())
        payload["meta"] = json.dumps({**json.loads(payload["meta"]), "format": newer})
        path.write_bytes(serialization.msgpack_serialize(payload))
    assert main(["evaluate", "--policy", str(folder), "--episodes", "1"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert (
        f"format {newer}" in line and f"formats 1 to {formats.FORMAT}" in line and agentax.__version__ in line
    )


@pytest.mark.slow
def test_report_plot_and_play_read_a_format_1_folder(tmp_path):
    folder = copy_of(1, "ppo-compiled-2seeds", tmp_path)
    assert main(["report", str(folder)]) == 0
    assert main(["plot", str(folder), "--out", str(tmp_path / "curve.png")]) == 0
    assert (tmp_path / "curve.png").stat().st_size > 0
    assert main(["play", "--policy", str(folder), "--video", str(tmp_path / "episode.gif")]) == 0
    assert (tmp_path / "episode.gif").stat().st_size > 0


@pytest.mark.slow
def test_resume_after_its_checkpoints_folder_was_deleted_starts_again(tmp_path, capsys):
    folder = copy_of(formats.FORMAT, "ppo-host", tmp_path)
    shutil.rmtree(folder / "checkpoints")
    assert main(["train", "--resume", str(folder), "--no-progress"]) == 0
    assert "has no checkpoint yet" in capsys.readouterr().err
    assert checkpoints(folder)


def test_a_format_1_folder_exports_the_policy_it_recorded(tmp_path):
    from agentax import export

    folder = copy_of(1, "ppo-host", tmp_path)
    path = agentax.load(folder).export(tmp_path / "policy.stablehlo", format="stablehlo")
    obs = run_fixtures.observations("CartPole-v1")
    np.testing.assert_array_equal(export.load(path).run(obs), recorded(1, "ppo-host")["greedy_actions"])


def test_format_1_kept_the_early_stop_in_the_algorithms_settings(tmp_path):
    """Before 2026-12 DQN's per-seed early stop sat in the algorithm's config; a config that named
    no runner was the compiled runner's. Read today, both are the compiled runner's settings."""
    folder = copy_of(1, "dqn-compiled", tmp_path)
    config = read_json(folder / "config.json")
    del config["runner_kind"]
    for name in ("freeze_at_return", "freeze_episodes"):
        config["config"][name] = config["runner"].pop(name)
    (folder / "config.json").write_text(json.dumps(config))
    read = agentax.load(folder).config
    assert read["runner_kind"] == "compiled" and read["runner"]["freeze_episodes"] == 8
    assert "freeze_episodes" not in read["config"]
    np.testing.assert_array_equal(
        agentax.load(folder).policy(run_fixtures.observations("CartPole-v1"), jax.random.key(0)),
        recorded(1, "dqn-compiled")["greedy_actions"],
    )
