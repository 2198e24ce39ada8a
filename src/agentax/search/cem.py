"""The cross-entropy method over the flat parameter vector of a neural policy.

A diagonal Gaussian N(mean, std²) over parameter vectors. One iteration (:func:`step`, pure and
jittable): draw ``population_size − 1`` samples plus the mean itself, evaluate them all in one vmapped
call, and refit the Gaussian to the ``num_elites`` fittest (their mean and standard deviation). A
little extra noise, ``extra_noise`` decaying linearly to zero over ``noise_decay_generations``, is
added to the variance so the search does not collapse early (Szita & Lőrincz, 2006). Because the
mean is one of the candidates, the best candidate reported is often the distribution's centre.
"""

from __future__ import annotations

import pathlib
from dataclasses import dataclass

import jax
import jax.numpy as jnp
from flax import struct

from agentax.errors import UsageError
from agentax.policies import Policy
from agentax.search.population import (
    FitnessFn,
    PopulationConfig,
    evaluate_population,
    load_net_policy,
    rank_elites,
)


@dataclass(frozen=True)
class CEMConfig(PopulationConfig):
    """Hyperparameters of the cross-entropy method (defaults solve CartPole-v0 and -v1). The
    candidates are the current mean and ``population_size − 1`` samples."""

    elite_fraction: float = 0.2
    """Fraction of the candidates the Gaussian is refitted to."""
    init_std: float = 1.0
    """Standard deviation of the first Gaussian (its mean is zero)."""
    extra_noise: float = 0.3
    """Standard deviation added (in quadrature) to the refitted one at the first iteration."""
    noise_decay_generations: int = 20
    """Iterations over which the extra noise decays linearly to zero."""

    counts = ("noise_decay_generations",)

    def __post_init__(self):
        super().__post_init__()
        if not 0 < self.elite_fraction <= 1:
            raise UsageError(f"elite fraction must be in (0, 1], got {self.elite_fraction}")
        if self.init_std <= 0:
            raise UsageError(f"initial std must be > 0, got {self.init_std}")
        if self.extra_noise < 0:
            raise UsageError(f"extra noise (a mutation scale) must be >= 0, got {self.extra_noise}")

    @property
    def num_elites(self) -> int:
        return max(1, round(self.elite_fraction * self.population_size))


@struct.dataclass
class CEMState:
    mean: jax.Array  # [num_params]
    std: jax.Array  # [num_params]
    best_params: jax.Array  # [num_params]: the fittest candidate of the latest iteration
    best_fitness: jax.Array  # []
    generation: jax.Array  # int32 []: iterations done
    key: jax.Array


def init(key: jax.Array, num_params: int, config: CEMConfig) -> CEMState:
    """The first Gaussian: N(0, init_std²) on every parameter."""
    mean = jnp.zeros(num_params, jnp.float32)
    std = jnp.full(num_params, config.init_std, jnp.float32)
    return CEMState(mean, std, mean, jnp.float32(-jnp.inf), jnp.int32(0), key)


def step(state: CEMState, fitness_fn: FitnessFn, config: CEMConfig) -> tuple[CEMState, dict]:
    """Sample, evaluate and refit once. Pure: jit it with ``fitness_fn`` and ``config`` fixed."""
    key, sample_key, eval_key = jax.random.split(state.key, 3)
    noise = jax.random.normal(sample_key, (config.population_size - 1, state.mean.size))
    candidates = jnp.concatenate(
        [state.mean[None], state.mean + state.std * noise]
    )  # (population_size, num_params)
    fitness, env_steps = evaluate_population(fitness_fn, candidates, eval_key)  # (population_size,)
    elites = candidates[rank_elites(fitness, config.num_elites)]  # (num_elites, num_params), best first
    decay = jnp.maximum(1.0 - state.generation / config.noise_decay_generations, 0.0)
    extra_variance = (config.extra_noise * decay) ** 2
    state = CEMState(
        mean=elites.mean(axis=0),
        std=jnp.sqrt(elites.var(axis=0) + extra_variance),
        best_params=elites[0],
        best_fitness=fitness.max(),
        generation=state.generation + 1,
        key=key,
    )
    metrics = {"best_fitness": fitness.max(), "mean_fitness": fitness.mean(), "env_steps": env_steps}
    return state, metrics


def candidates(state: CEMState) -> jax.Array:
    """What the final selection chooses from: the Gaussian's mean and the latest best ``[2, num_params]``."""
    return jnp.stack([state.mean, state.best_params])


def load_policy(run_dir: pathlib.Path, config: dict) -> Policy:
    """The greedy policy of a saved CEM run (``agentax play/evaluate --policy DIR``)."""
    return load_net_policy(run_dir, config)


__all__ = ["CEMConfig", "CEMState", "candidates", "init", "load_policy", "step"]
