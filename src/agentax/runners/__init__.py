"""Runners: where and when an algorithm's pure functions run.

``compiled`` trains JAX envs in one jitted program vmapped over seeds; ``compiled_pool`` steps
EnvPool inside the program (kinds ``compiled-atari`` and ``compiled-mujoco``); ``host`` steps any
env on the host with a Driver; ``parallel`` runs the host runner's actors in threads beside a
learner, ``ray`` in Ray actor processes. :data:`RUNNERS`, the one table the API reads, names each
kind's module (:mod:`agentax.runners.launch`) and envs; a module is imported when its kind is used
(:meth:`Runner.load`); :func:`kind_for` chooses a kind for ``--runner`` and an env id.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import ModuleType
from typing import Any


@dataclass(frozen=True)
class Runner:
    """A kind of runner: its module, the envs it takes and the ``--runner`` choice that picks it."""

    module: str
    """the runner module (``Config``, ``configure``, ``train``, ``restore``)"""
    envs: str
    """the env family it takes (:func:`takes`): "jax" (agentax's JAX envs), "any" (any Gymnasium id
    or Atari), "atari", "mujoco" (EnvPool's MuJoCo v5 tasks)"""
    chosen_as: str
    """the ``--runner`` choice (a name in :data:`CHOICES`) that picks it for an env of its family"""
    carries_memory: bool = False
    """whether it carries a recurrent agent's memory from step to step (``Agent.recurrent``); a runner
    that does not refuses an agent with memory (:func:`agentax.runners.launch.check_memory_carried`)"""

    def load(self) -> ModuleType:
        return importlib.import_module(self.module)


RUNNERS: dict[str, Runner] = {
    "compiled": Runner("agentax.runners.compiled", "jax", "compiled", carries_memory=True),
    "host": Runner("agentax.runners.host", "any", "host", carries_memory=True),
    "parallel": Runner("agentax.runners.parallel", "any", "parallel", carries_memory=True),
    "ray": Runner("agentax.runners.ray", "any", "ray", carries_memory=True),
    "compiled-atari": Runner("agentax.runners.compiled_pool", "atari", "compiled", carries_memory=True),
    "compiled-mujoco": Runner("agentax.runners.compiled_pool", "mujoco", "compiled", carries_memory=True),
}
"""Every kind of runner by its name in config.json's ``runner_kind``, which old run folders keep
(``--runner compiled`` on Atari or EnvPool's MuJoCo ids: ``compiled-atari``, ``compiled-mujoco``)."""
CHOICES = ("compiled", "host", "parallel", "ray")
"""The kinds ``--runner`` names."""
AUTO = ("compiled", "host")
"""What ``--runner auto`` picks: the first of these whose env family takes the env id."""
UNNAMED_KIND = "compiled"
"""The kind of a run whose config.json names none (written before runners had kinds)."""


def takes(kind: str, env_id: str) -> bool:
    """Whether the ``kind`` runner trains ``env_id``: whether the id is of the runner's env family
    (:attr:`Runner.envs`), the family's module imported only now."""
    family = RUNNERS[kind].envs
    if family == "jax":
        from agentax.envs import JAX_ENVS

        return env_id in JAX_ENVS
    if family == "atari":
        from agentax.envs.atari import is_atari_id

        return is_atari_id(env_id)
    if family == "mujoco":
        from agentax.envs.envpool_xla import is_envpool_mujoco_id

        return is_envpool_mujoco_id(env_id)
    return family == "any"


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
        return RUNNERS[kind].load().Config(**config["runner"])
    except (KeyError, TypeError) as error:
        raise UsageError(f"{where} has no valid 'runner' settings ({error})") from None


def algorithm_of(config: dict[str, Any]) -> tuple[ModuleType, Any]:
    """``(module, cfg)``: the algorithm a run's config.json names, and its config."""
    from agentax.agents import algorithm, algorithm_config, config_from_dict

    return algorithm(config["algo"]), config_from_dict(algorithm_config(config["algo"]), config["config"])


def resumes(run_dir: Any, config: dict[str, Any]) -> bool:
    """Whether the run in ``run_dir`` continues from a checkpoint rather than starting again (a run
    of workers decides worker by worker: those without a checkpoint start again)."""
    from agentax.runs import checkpoints

    return config.get("runner", {}).get("workers", 1) > 1 or bool(checkpoints(run_dir))
