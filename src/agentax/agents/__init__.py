"""Learning agents, one module per algorithm family: pure ``init`` / ``act`` / ``learn`` functions.

``reinforce`` (the lecture's policy gradient, with an optional learned baseline), ``ppo``
(clipped policy optimisation with GAE), ``dqn`` (deep Q-learning and its variants), ``pqn`` (deep
Q-learning from vectorized rollouts, Q(λ) targets, no replay or target network), and for continuous
actions ``sac`` (soft actor-critic) and ``td3`` (twin delayed DDPG). Each follows
the contract of :mod:`agentax.agents.protocol`: ``make_agent(spec, cfg)``, which every runner
drives. :data:`ALGORITHMS` is the one registry.
"""

from __future__ import annotations

import dataclasses
import importlib
from types import ModuleType
from typing import TYPE_CHECKING, Any, NamedTuple

from agentax.errors import UsageError

if TYPE_CHECKING:
    from agentax.agents.presets import Preset


def config_to_dict(cfg: Any) -> dict[str, Any]:
    """A frozen config as plain JSON-ready values (for ``config.json``)."""
    return dataclasses.asdict(cfg)


def config_from_dict(cls: type, values: dict[str, Any]) -> Any:
    """Rebuild a ``cls`` config from ``config.json`` (lists back to tuples); unknown keys are an error."""
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(values) - names
    if unknown:
        known = ", ".join(sorted(names))
        raise UsageError(f"unknown {cls.__name__} settings {sorted(unknown)}; known: {known}")
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


class AlgorithmEntry(NamedTuple):
    """Where an algorithm lives: its module and its config dataclass's name in it."""

    module: str
    config: str


ALGORITHMS: dict[str, AlgorithmEntry] = {
    "reinforce": AlgorithmEntry("agentax.agents.reinforce", "ReinforceConfig"),
    "ppo": AlgorithmEntry("agentax.agents.ppo", "PPOConfig"),
    "dqn": AlgorithmEntry("agentax.agents.dqn", "DQNConfig"),
    "pqn": AlgorithmEntry("agentax.agents.pqn", "PQNConfig"),
    "sac": AlgorithmEntry("agentax.agents.sac", "SACConfig"),
    "td3": AlgorithmEntry("agentax.agents.td3", "TD3Config"),
}
"""Every learning algorithm: its name on the command line and in config.json → where it lives."""


def algorithm(name: str) -> ModuleType:
    """The module of algorithm ``name``; a ``UsageError`` listing the known ones otherwise."""
    if name not in ALGORITHMS:
        raise UsageError(f"unknown algorithm {name!r}; choose from {', '.join(ALGORITHMS)}")
    return importlib.import_module(ALGORITHMS[name].module)


def algorithm_config(name: str) -> type:
    """The frozen config dataclass of algorithm ``name`` (for :func:`config_from_dict`)."""
    return getattr(algorithm(name), ALGORITHMS[name].config)


def presets_of(name: str) -> dict[str, Preset]:
    """The tuned configs of algorithm ``name`` (:mod:`agentax.agents.presets`) by preset name,
    ``"default"`` among them."""
    from agentax.agents import presets

    algorithm(name)
    return presets.PRESETS[name]
