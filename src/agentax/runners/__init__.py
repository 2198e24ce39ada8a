"""Runners: where and when an algorithm's pure functions run.

``compiled`` trains JAX envs inside one jitted, vmapped-over-seeds program (and PPO on Atari and
on EnvPool's MuJoCo tasks with EnvPool's step inside the program, ``compiled-atari`` and
``compiled-mujoco``); ``host`` steps any env on the host with a
Driver, one step after the other; ``parallel`` runs the host runner's actors in threads beside a
learner, ``ray`` in Ray actor processes on any node of a cluster. :data:`RUNNERS` is the one
table the API reads (``agentax.train`` chooses a kind, :func:`agentax.api.restore_policy` reads
any run back); the modules are imported only when a kind is used.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import ModuleType


@dataclass(frozen=True)
class RunnerSpec:
    """What the API needs to know of a kind of runner."""

    module: str
    """the module with its ``train`` function"""
    config: str
    """the dotted name of its config class (saved in config.json under "runner")"""
    envs: str
    """the envs it takes: "jax" (agentax's JAX envs), "any" (any Gymnasium id or Atari), "atari",
    "mujoco" (EnvPool's MuJoCo v5 tasks)"""
    many_seeds: bool
    """whether ``--seeds N`` trains N agents in one program (else one seed per process)"""
    host_loop: bool = True
    """whether it steps envs outside one compiled program (its checkpoints hold the agent state and
    the learner key; ``compiled`` holds whole vmapped carries)"""
    remakes_agent: bool = False
    """whether its actors run in other processes and build the agent again (``train(...,
    make_agent=...)``)"""

    def load(self) -> ModuleType:
        return importlib.import_module(self.module)

    def config_type(self) -> type:
        module, name = self.config.rsplit(".", 1)
        return getattr(importlib.import_module(module), name)


RUNNERS: dict[str, RunnerSpec] = {
    "compiled": RunnerSpec(
        "agentax.runners.compiled", "agentax.runners.compiled.RunnerConfig", "jax", True, host_loop=False
    ),
    "host": RunnerSpec("agentax.runners.host", "agentax.runners.host.HostRunnerConfig", "any", False),
    "parallel": RunnerSpec(
        "agentax.runners.parallel", "agentax.runners.parallel.ParallelRunnerConfig", "any", False
    ),
    "ray": RunnerSpec(
        "agentax.runners.ray", "agentax.runners.ray.RayRunnerConfig", "any", False, remakes_agent=True
    ),
    "compiled-atari": RunnerSpec(
        "agentax.runners.compiled_atari", "agentax.runners.host.HostRunnerConfig", "atari", False
    ),
    "compiled-mujoco": RunnerSpec(
        "agentax.runners.compiled_atari", "agentax.runners.host.HostRunnerConfig", "mujoco", False
    ),
}
"""Every kind of runner by its name in config.json's ``runner_kind`` (``--runner compiled`` on an
Atari id is ``compiled-atari``, on EnvPool's MuJoCo ids ``compiled-mujoco``)."""
CHOICES = ("compiled", "host", "parallel", "ray")
"""The kinds ``--runner`` names."""
