"""Runners: where and when an algorithm's pure functions run.

``compiled`` trains JAX envs inside one jitted, vmapped-over-seeds program (and PPO on Atari and
on EnvPool's MuJoCo tasks with EnvPool's step inside the program, ``compiled-atari`` and
``compiled-mujoco``); ``host`` steps any env on the host with a
Driver, one step after the other; ``parallel`` runs the host runner's actors in threads beside a
learner, ``ray`` in Ray actor processes on any node of a cluster. :data:`RUNNERS` is the one
table the API reads: :func:`kind_for` chooses a kind for ``--runner`` and an env id, the kind's
launcher (:mod:`agentax.runners.compiled_launch`, :mod:`agentax.runners.host_launch`) configures,
trains, resumes and restores it, so :mod:`agentax.api` names no runner. The modules are imported
only when a kind is used.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any


@dataclass(frozen=True)
class RunnerSpec:
    """What the API needs to know of a kind of runner."""

    module: str
    """the module with its ``train`` function"""
    config: str
    """the dotted name of its config class (saved in config.json under "runner")"""
    envs: str
    """the env family it takes (a key of :data:`ENV_FAMILIES`): "jax" (agentax's JAX envs), "any"
    (any Gymnasium id or Atari), "atari", "mujoco" (EnvPool's MuJoCo v5 tasks)"""
    many_seeds: bool
    """whether ``--seeds N`` trains N agents in one program (else one seed per process)"""
    launcher: str
    """the module that configures a run of it from a run description and starts, resumes and
    restores it: ``prepare``, ``reopen``, ``restore`` (see :mod:`agentax.runners.launch`)"""
    chosen_as: str
    """the ``--runner`` choice (a name in :data:`CHOICES`) that picks it for an env of its family"""
    host_loop: bool = True
    """whether it steps envs outside one compiled program (its checkpoints hold the agent state and
    the learner key; ``compiled`` holds whole vmapped carries)"""
    remakes_agent: bool = False
    """whether its actors run in other processes and build the agent again (``train(...,
    make_agent=...)``)"""
    configure: str = ""
    """host family: the dotted name of its ``configure(run_args, agent, common) -> (runner config,
    where)``, which adds its own settings to the family's ``common`` ones"""
    actors: bool = False
    """whether it splits the agent's envs between actors (``--actors``, ``--envs-per-actor``)"""

    def load(self) -> ModuleType:
        return importlib.import_module(self.module)

    def config_type(self) -> type:
        return _dotted(self.config)

    def launch(self) -> ModuleType:
        return importlib.import_module(self.launcher)

    def configurer(self) -> Callable[..., tuple[Any, str]]:
        return _dotted(self.configure)


def _dotted(name: str) -> Any:
    module, attribute = name.rsplit(".", 1)
    return getattr(importlib.import_module(module), attribute)


_HOST = "agentax.runners.host_launch"
RUNNERS: dict[str, RunnerSpec] = {
    "compiled": RunnerSpec(
        "agentax.runners.compiled",
        "agentax.runners.compiled.RunnerConfig",
        "jax",
        True,
        "agentax.runners.compiled_launch",
        "compiled",
        host_loop=False,
    ),
    "host": RunnerSpec(
        "agentax.runners.host",
        "agentax.runners.host.HostRunnerConfig",
        "any",
        False,
        _HOST,
        "host",
        configure="agentax.runners.host.configure",
    ),
    "parallel": RunnerSpec(
        "agentax.runners.parallel",
        "agentax.runners.parallel.ParallelRunnerConfig",
        "any",
        False,
        _HOST,
        "parallel",
        configure="agentax.runners.parallel.configure",
        actors=True,
    ),
    "ray": RunnerSpec(
        "agentax.runners.ray",
        "agentax.runners.ray.RayRunnerConfig",
        "any",
        False,
        _HOST,
        "ray",
        remakes_agent=True,
        configure="agentax.runners.ray.configure",
        actors=True,
    ),
    "compiled-atari": RunnerSpec(
        "agentax.runners.compiled_atari",
        "agentax.runners.compiled_atari.PoolRunnerConfig",
        "atari",
        False,
        _HOST,
        "compiled",
        configure="agentax.runners.host_launch.configure_in_program",
    ),
    "compiled-mujoco": RunnerSpec(
        "agentax.runners.compiled_atari",
        "agentax.runners.compiled_atari.PoolRunnerConfig",
        "mujoco",
        False,
        _HOST,
        "compiled",
        configure="agentax.runners.host_launch.configure_in_program",
    ),
}
"""Every kind of runner by its name in config.json's ``runner_kind`` (``--runner compiled`` on an
Atari id is ``compiled-atari``, on EnvPool's MuJoCo ids ``compiled-mujoco``)."""
CHOICES = ("compiled", "host", "parallel", "ray")
"""The kinds ``--runner`` names."""
AUTO = ("compiled", "host")
"""What ``--runner auto`` picks: the first of these whose env family takes the env id."""
UNNAMED_KIND = "compiled"
"""The kind of a run whose config.json names none (written before runners had kinds)."""


def _is_jax_env(env_id: str) -> bool:
    from agentax.envs import JAX_ENVS

    return env_id in JAX_ENVS


def _is_atari(env_id: str) -> bool:
    from agentax.envs.atari import is_atari_id

    return is_atari_id(env_id)


def _is_envpool_mujoco(env_id: str) -> bool:
    from agentax.envs.envpool_xla import is_envpool_mujoco_id

    return is_envpool_mujoco_id(env_id)


ENV_FAMILIES: dict[str, Callable[[str], bool]] = {
    "jax": _is_jax_env,
    "any": lambda env_id: True,
    "atari": _is_atari,
    "mujoco": _is_envpool_mujoco,
}
"""Whether an env id belongs to the family a runner's ``envs`` names."""


def takes(kind: str, env_id: str) -> bool:
    """Whether the ``kind`` runner trains ``env_id``."""
    return ENV_FAMILIES[RUNNERS[kind].envs](env_id)


def kind_for(choice: str, env_id: str) -> str:
    """The kind of runner that trains ``env_id`` under ``--runner choice`` ('auto' or one of
    :data:`CHOICES`): the choice's kind for the env's family; a ``UsageError`` where none takes it."""
    from agentax.errors import UsageError

    if choice == "auto":
        return next(kind for kind in AUTO if takes(kind, env_id))
    if choice not in CHOICES:
        raise UsageError(f"unknown runner {choice!r}; choose from {', '.join(CHOICES)}")
    chosen = [kind for kind, spec in RUNNERS.items() if spec.chosen_as == choice and takes(kind, env_id)]
    if not chosen:
        from agentax.envs import JAX_ENVS

        raise UsageError(
            f"the {choice} runner needs one of agentax's JAX envs ({', '.join(JAX_ENVS)}); "
            f"train {env_id} with --runner host or --runner parallel"
        )
    return chosen[0]


def kind_of(config: dict[str, Any]) -> str:
    """The kind of runner a run's config.json names."""
    return config.get("runner_kind", UNNAMED_KIND)


def runner_settings(config: dict[str, Any], where: str) -> Any:
    """The runner's config of a run's ``config`` (config.json, read from ``where``); a
    ``UsageError`` for an unknown kind or settings its config class does not take."""
    from agentax.errors import UsageError

    kind = kind_of(config)
    if kind not in RUNNERS:
        raise UsageError(f"{where} names an unknown runner {kind!r}; known: {', '.join(RUNNERS)}")
    try:
        return RUNNERS[kind].config_type()(**config["runner"])
    except (KeyError, TypeError) as error:
        raise UsageError(f"{where} has no valid 'runner' settings ({error})") from None


SETTINGS_ONCE_IN_CONFIG = ("freeze_at_return", "freeze_episodes")
"""Settings that runs written before 2026-12 kept in the algorithm's config (DQN's per-seed early
stop) and that now belong to the compiled runner's."""


def upgraded(config: dict[str, Any]) -> dict[str, Any]:
    """``config.json`` of an older run in today's layout (the runner's settings in "runner")."""
    moved = {k: config["config"][k] for k in SETTINGS_ONCE_IN_CONFIG if k in config.get("config", {})}
    if not moved:
        return config
    settings = {k: v for k, v in config["config"].items() if k not in moved}
    runner = dict(config.get("runner", {}))
    if not RUNNERS[kind_of(config)].host_loop:
        runner.update(moved)
    return {**config, "config": settings, "runner": runner}


def algorithm_of(config: dict[str, Any]) -> tuple[ModuleType, Any]:
    """``(module, cfg)``: the algorithm a run's config.json names, and its config."""
    from agentax.agents import algorithm, algorithm_config, config_from_dict

    return algorithm(config["algo"]), config_from_dict(algorithm_config(config["algo"]), config["config"])


def resumes(run_dir: Any, config: dict[str, Any]) -> bool:
    """Whether the run in ``run_dir`` continues from a checkpoint rather than starting again (a run
    of workers decides worker by worker: those without a checkpoint start again)."""
    from agentax.runs import checkpoints

    return config.get("runner", {}).get("workers", 1) > 1 or bool(checkpoints(run_dir))
