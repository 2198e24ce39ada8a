"""Grid search over the vacuum robot's (p, r): every setting of a regular grid in one vmapped call."""

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
class GridSearchConfig:
    """A regular grid over p ∈ [0, 1] and r ∈ [0, r_max]."""

    num_p: int = 41
    """Values of p, evenly spaced over [0, 1]."""
    num_r: int = 41
    """Values of r, evenly spaced over [0, r_max]."""
    r_max: float = math.pi
    """Largest rotation bound searched (radians)."""
    num_episodes: int = 4
    """Episodes per setting in the search."""
    final_episodes: int = 100
    """Fresh episodes of the best setting for its reported mean and confidence interval."""

    def __post_init__(self):
        check_search_config(self, ("num_p", "num_r", "num_episodes"))

    def settings(self) -> tuple[np.ndarray, np.ndarray]:
        """``p, r``, each ``[num_p · num_r]``, p major (row ``i`` of the grid is ``p[i]``)."""
        p, r = np.meshgrid(
            np.linspace(0.0, 1.0, self.num_p), np.linspace(0.0, self.r_max, self.num_r), indexing="ij"
        )
        return p.ravel().astype(np.float32), r.ravel().astype(np.float32)


def grid_search(
    config: GridSearchConfig, seed: int = 0, params: VacuumParams | None = None
) -> SettingsResult:
    """Evaluate the whole grid, pick the best mean, re-evaluate it on fresh episodes."""
    p, r = config.settings()
    return search_settings(
        p, r, seed, config.num_episodes, config.final_episodes, (config.num_p, config.num_r), params
    )


def load_policy(run_dir: pathlib.Path, config: dict) -> Policy:
    """The best (p, r) policy of a saved vacuum search (its eval.json)."""
    return vacuum_policy(*load_best_setting(run_dir))
