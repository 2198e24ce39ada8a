"""Runners: where and when an algorithm's pure functions run.

``compiled`` trains JAX envs inside one jitted, vmapped-over-seeds program (and PPO on Atari with
EnvPool's step inside the program, ``compiled_atari``); ``host`` steps any env
on the host with a Driver, one step after the other; ``parallel`` runs the host runner's actors in
threads beside a learner, ``ray`` in Ray actor processes on any node of a cluster.
:func:`load_policy` rebuilds the greedy policy of a run of any of them.

This module is also callable: ``agentax.train("ppo", env=..., ...)`` is :func:`agentax.api.train`.
Python sets the attribute ``agentax.train`` to this subpackage whenever it is first imported
(``import agentax.train.host``), so a *function* named ``agentax.train`` would be replaced by the
module, or would hide it (``agentax.train.compiled`` would fail). The module's class is therefore a
``ModuleType`` subclass with a ``__call__`` that forwards to the API (``__class__`` assignment on a
module is supported since Python 3.5), and both uses share one name. The API is imported only on
call, so the runners do not depend on it.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import ModuleType
from typing import Any

from agentax.policies import Policy

RUNNERS = ("compiled", "host", "parallel", "ray")


class _CallableModule(ModuleType):
    """``agentax.train``: the runners' subpackage, and, called, :func:`agentax.api.train`."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        from agentax.api import train

        return train(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule


def load_policy(run_dir: str | Path, config: dict[str, Any]) -> Policy:
    """The greedy policy of a learning algorithm's run (its best seed), from its newest good checkpoint."""
    from agentax.agents import algorithm
    from agentax.agents.protocol import EnvSpec

    module = algorithm(config["algo"])
    cfg = module.config_from_dict(config["config"])
    if config.get("runner_kind", "compiled") == "compiled":
        from agentax.envs import make_jax
        from agentax.train.compiled import RunnerConfig, restore_policy

        env = make_jax(config["env"])
        return restore_policy(run_dir, module.make_train(env, cfg), RunnerConfig(**config["runner"]))
    from agentax.train.host import make_host_env, restore_policy

    runner = config.get("runner", {})
    options = {
        "backend": runner.get("env_backend", "auto"),
        "sticky_actions": runner.get("sticky_actions", 0.25),
    }
    env = make_host_env(config["env"], 1, **options)
    spec = EnvSpec.of(env)
    env.close()
    return restore_policy(Path(run_dir), module.make_agent(spec, cfg))
