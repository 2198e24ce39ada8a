"""The run folder's format: its version, what each version changed, and the migrations that read
every older one. What an older agentax wrote, this one loads.

Every ``config.json`` and every checkpoint's meta hold ``"format": FORMAT`` (folders written before
format 2 hold none and are format 1). Reading goes through this module: :func:`config_of` turns an
older ``config.json`` into today's layout and :func:`state_of` an older checkpoint's state dict (the
raw tree of :func:`agentax.runs.load_tree`, before it meets today's agent state), one migration per
version step; the folder on disk is left as it was, unless the run resumes (its new checkpoints and
config.json are then written in today's format). A folder from a newer agentax than this one is one
line naming both formats. A replay buffer saved with a checkpoint (``replay-<U>.npz``) has that
checkpoint's format.

Changing what an agent state holds, or the layout of a run folder, means: raise ``FORMAT``, add a
row to ``FORMATS``, a migration from the previous version, and the new format's fixtures
(``scripts/run_fixtures.py``); ``tests/test_formats.py`` loads the fixtures of every version.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

from agentax.errors import UsageError

FORMAT = 2
"""The format this agentax writes."""

FORMATS: dict[int, str] = {
    1: "agentax 0.1.0 before run-folder versions (no version written, up to 2026-12-06): PPO's state "
    "without its normalisation fields",
    2: "the version written in config.json and every checkpoint; PPO's state holds obs_stats, "
    "return_stats and discounted_return (None when normalisation is off)",
}
"""Each version and what it changed, for the messages and the docs."""

PPO_NORMALISATION = ("obs_stats", "return_stats", "discounted_return")
AGENT_STATE_KEYS = {"params", "opt_state", "updates"}


def _ppo_without_normalisation(state: Any, algo: str) -> Any:
    """1 → 2: a PPO state gained its normalisation statistics; a format-1 run never normalised, so
    they are None (identity), as today's PPO state is with normalisation off."""
    if algo != "ppo":
        return state
    return _map_dicts(state, lambda d: {**{k: None for k in PPO_NORMALISATION}, **d}, AGENT_STATE_KEYS)


STATE_MIGRATIONS: dict[int, Callable[[Any, str], Any]] = {1: _ppo_without_normalisation}
"""``STATE_MIGRATIONS[v](state, algo)``: a checkpoint's state dict of format ``v`` in format ``v + 1``."""


def _runner_settings_out_of_config(config: dict[str, Any]) -> dict[str, Any]:
    """1 → 2: a config.json that names no runner kind is the compiled runner's (written before
    runners had kinds); DQN's per-seed early stop (``freeze_at_return``, ``freeze_episodes``), kept
    in the algorithm's settings before 2026-12, is the compiled runner's setting (no other runner
    had it, so elsewhere it goes)."""
    config = {"runner_kind": "compiled", **config}
    settings = config.get("config", {})
    moved = {k: settings[k] for k in ("freeze_at_return", "freeze_episodes") if k in settings}
    if not moved:
        return config
    runner = {**config.get("runner", {}), **(moved if config["runner_kind"] == "compiled" else {})}
    return {**config, "config": {k: v for k, v in settings.items() if k not in moved}, "runner": runner}


CONFIG_MIGRATIONS: dict[int, Callable[[dict[str, Any]], dict[str, Any]]] = {1: _runner_settings_out_of_config}
"""``CONFIG_MIGRATIONS[v](config)``: a ``config.json`` of format ``v`` in format ``v + 1``."""


def version_of(record: dict[str, Any]) -> int:
    """The format of a ``config.json`` or checkpoint meta: its ``"format"``, else 1 (written before
    versions were)."""
    version = record.get("format", 1)
    if not isinstance(version, int) or version < 1:
        raise UsageError(f"a run-folder format must be a whole number from 1, not {version!r}")
    return version


class NewerFormat(UsageError):
    """A run folder or checkpoint written by a newer agentax than this one (exit code 2)."""


def check_readable(version: int, where: Any) -> None:
    """One line, exit 2, for a folder or file of a newer format than this agentax reads."""
    if version > FORMAT:
        from importlib.metadata import version as installed

        raise NewerFormat(
            f"{where} was written in run-folder format {version}, by a newer agentax; this agentax "
            f"({installed('agentax')}) reads formats 1 to {FORMAT}: upgrade agentax to load it"
        )


def config_of(config: dict[str, Any], where: Any) -> dict[str, Any]:
    """A ``config.json`` of any format in today's layout, with ``"format": FORMAT``; says once on
    stderr when it came from an older format."""
    version = version_of(config)
    check_readable(version, where)
    for step in range(version, FORMAT):
        config = CONFIG_MIGRATIONS[step](config)
    if version < FORMAT:
        announce(where, version)
    return {**config, "format": FORMAT}


def state_of(state: Any, meta: dict[str, Any], algo: str, where: Any) -> Any:
    """A checkpoint's raw state dict (format from its ``meta``) in today's format."""
    version = version_of(meta)
    check_readable(version, where)
    for step in range(version, FORMAT):
        state = STATE_MIGRATIONS[step](state, algo)
    return state


_announced: set[str] = set()


def announce(where: Any, version: int) -> None:
    """Say once per folder and process that it is read through migrations, and left as it is."""
    if str(where) in _announced:
        return
    _announced.add(str(where))
    print(
        f"note: {where} was written in run-folder format {version} (this agentax writes {FORMAT}); "
        "read through its migrations, the folder stays as it is unless the run resumes",
        file=sys.stderr,
    )


def _map_dicts(tree: Any, fn: Callable[[dict], dict], having: set[str]) -> Any:
    """``tree`` with ``fn`` applied to every dict (a state dict's node) holding all keys of ``having``."""
    if not isinstance(tree, dict):
        return tree
    tree = {k: _map_dicts(v, fn, having) for k, v in tree.items()}
    return fn(tree) if having <= tree.keys() else tree
