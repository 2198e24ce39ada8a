"""Policy search: grid and random search over the vacuum robot's (p, r) policy (``vacuum_policy``, all
settings evaluated at once by ``evaluate_settings``); a genetic algorithm and the cross-entropy method over
the parameters of a neural policy, each population evaluated in one vmapped call.
"""

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

__all__ = [
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
    "make_env",
    "make_fitness",
    "mean_confidence_interval",
    "plot_heatmap",
    "random_search",
    "run_generations",
    "vacuum_policy",
]
