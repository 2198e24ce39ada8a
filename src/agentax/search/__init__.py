"""Policy search: grid and random search over the vacuum robot's (p, r) policy (``vacuum_policy``, all
settings evaluated at once by ``evaluate_settings``); a genetic algorithm and the cross-entropy method over
the parameters of a neural policy, each population evaluated in one vmapped call.
"""

import importlib
from pathlib import Path
from typing import Any

from agentax.errors import UsageError
from agentax.search import cem, genetic
from agentax.search.cem import CEMConfig
from agentax.search.genetic import GAConfig
from agentax.search.grid import GridSearchConfig, grid_search
from agentax.search.population import (
    FlatPolicy,
    NetConfig,
    evaluate_population,
    make_env,
    make_fitness,
    mean_confidence_interval,
    run_generations,
)
from agentax.search.random_search import RandomSearchConfig, random_search
from agentax.search.settings import SettingsResult, evaluate_settings, plot_heatmap, vacuum_policy

METHODS: dict[str, str] = {
    "grid": "agentax.search.grid",
    "random": "agentax.search.random_search",
    "ga": "agentax.search.genetic",
    "cem": "agentax.search.cem",
}
"""Every policy search by its name in a run's config.json ("algo"), and the module that restores its
policy (``load_policy(run_dir, config)``): grid and random search the vacuum robot's settings, ga and
cem a neural policy's parameters."""
VACUUM_METHODS = ("grid", "random")
NEURAL_METHODS = ("ga", "cem")


def load_policy(run_dir: Path, config: dict[str, Any], also_known: tuple[str, ...] = ()) -> Any:
    """The policy a policy search's run found (its method's ``load_policy``); a ``UsageError``
    naming the known methods (and ``also_known``) for another "algo" in its config.json."""
    algo = config["algo"]
    if algo not in METHODS:
        known = ", ".join([*also_known, *METHODS])
        raise UsageError(f"{run_dir}: unknown algorithm {algo!r} in config.json; known: {known}")
    return importlib.import_module(METHODS[algo]).load_policy(run_dir, config)


__all__ = [
    "METHODS",
    "NEURAL_METHODS",
    "VACUUM_METHODS",
    "CEMConfig",
    "FlatPolicy",
    "GAConfig",
    "GridSearchConfig",
    "NetConfig",
    "RandomSearchConfig",
    "SettingsResult",
    "cem",
    "evaluate_population",
    "evaluate_settings",
    "genetic",
    "grid_search",
    "load_policy",
    "make_env",
    "make_fitness",
    "mean_confidence_interval",
    "plot_heatmap",
    "random_search",
    "run_generations",
    "vacuum_policy",
]
