"""Random search over the vacuum robot's (p, r): uniform settings, all evaluated in one vmapped call."""

from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass

import numpy as np

from agentax.envs.vacuum import VacuumParams
from agentax.policies import Policy
from agentax.search.settings import (
    SettingsResult,
    check_search_config,
    load_best_setting,
    search_settings,
    vacuum_policy,
)


@dataclass(frozen=True)
class RandomSearchConfig:
    """Settings drawn uniformly from p ∈ [0, 1] and r ∈ [0, r_max]."""

    num_settings: int = 1681
    """Settings drawn (the default grid's 41 × 41, for a fair comparison)."""
    r_max: float = math.pi
    """Largest rotation bound searched (radians)."""
    num_episodes: int = 4
    """Episodes per setting in the search."""
    final_episodes: int = 100
    """Fresh episodes of the best setting for its reported mean and confidence interval."""

    def __post_init__(self):
        check_search_config(self, ("num_settings", "num_episodes"))

    def settings(self, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """``p, r``, each ``[num_settings]``, uniform and reproducible from ``seed``."""
        rng = np.random.default_rng(seed)
        p = rng.uniform(0.0, 1.0, self.num_settings)
        r = rng.uniform(0.0, self.r_max, self.num_settings)
        return p.astype(np.float32), r.astype(np.float32)


def random_search(
    config: RandomSearchConfig, seed: int = 0, params: VacuumParams | None = None
) -> SettingsResult:
    """Evaluate ``num_settings`` random settings, pick the best mean, re-evaluate it on fresh episodes."""
    p, r = config.settings(seed)
    return search_settings(p, r, seed, config.num_episodes, config.final_episodes, None, params)


def load_policy(run_dir: pathlib.Path, config: dict) -> Policy:
    """The best (p, r) policy of a saved vacuum search (its eval.json)."""
    return vacuum_policy(*load_best_setting(run_dir))
