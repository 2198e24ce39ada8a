"""A genetic algorithm over the flat parameter vector of a neural policy.

One generation (:func:`step`, pure and jittable): evaluate the whole population in one vmapped call;
copy the fittest ``num_elites`` unchanged into the next generation (elitism); fill the rest with
children, each from two parents picked by tournament selection (the fittest of ``tournament_size``
random members), mixed by uniform crossover with probability ``crossover_rate`` (else a copy of the
first parent), then perturbed by Gaussian mutation (``mutation_scale`` · N(0, 1) on every gene).
Elites are re-evaluated on new episodes each generation, so a lucky score does not keep them alive.
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
class GAConfig(PopulationConfig):
    """Hyperparameters of the genetic algorithm (defaults solve CartPole-v0 and -v1)."""

    elite_fraction: float = 0.1
    """Fraction of the population copied unchanged into the next generation (at least one member)."""
    tournament_size: int = 3
    """Members drawn at random per tournament; the fittest becomes a parent."""
    crossover_rate: float = 0.5
    """Probability that a child mixes its two parents gene by gene (uniform crossover)."""
    mutation_scale: float = 0.3
    """Standard deviation of the Gaussian noise added to every gene of a child."""
    init_scale: float = 1.0
    """Standard deviation of the first generation's genes (around zero)."""

    counts = ("tournament_size",)

    def __post_init__(self):
        super().__post_init__()
        if self.mutation_scale < 0:
            raise UsageError(f"mutation scale must be >= 0, got {self.mutation_scale}")
        if not 0 < self.elite_fraction < 1:
            raise UsageError(f"elite fraction must be in (0, 1), got {self.elite_fraction}")
        if not 0 <= self.crossover_rate <= 1:
            raise UsageError(f"crossover rate must be in [0, 1], got {self.crossover_rate}")
        if self.init_scale <= 0:
            raise UsageError(f"init scale must be > 0, got {self.init_scale}")

    @property
    def num_elites(self) -> int:
        return min(max(1, round(self.elite_fraction * self.population_size)), self.population_size - 1)


@struct.dataclass
class GAState:
    population: jax.Array  # [population_size, num_params]
    best_params: jax.Array  # [num_params]: the fittest member of the latest evaluated generation
    best_fitness: jax.Array  # []
    generation: jax.Array  # int32 []: generations evaluated so far
    key: jax.Array


def init(key: jax.Array, num_params: int, config: GAConfig) -> GAState:
    """The first generation: genes ~ N(0, init_scale²)."""
    key, population_key = jax.random.split(key)
    population = config.init_scale * jax.random.normal(population_key, (config.population_size, num_params))
    return GAState(population, population[0], jnp.float32(-jnp.inf), jnp.int32(0), key)


def step(state: GAState, fitness_fn: FitnessFn, config: GAConfig) -> tuple[GAState, dict]:
    """Evaluate one generation and breed the next. Pure: jit it with ``fitness_fn`` and ``config`` fixed."""
    key, eval_key, select_key, mix_key, cross_key, mutate_key = jax.random.split(state.key, 6)
    population = state.population  # (population_size, num_params)
    fitness, env_steps = evaluate_population(fitness_fn, population, eval_key)  # (population_size,)
    elites = rank_elites(fitness, config.num_elites)
    num_children = config.population_size - config.num_elites

    contenders = jax.random.randint(
        select_key, (num_children, 2, config.tournament_size), 0, config.population_size
    )  # (num_children, 2 parents, tournament_size)
    winner = jnp.argmax(fitness[contenders], axis=-1)[..., None]
    parents = jnp.take_along_axis(contenders, winner, axis=-1)[..., 0]  # (num_children, 2)
    first, second = population[parents[:, 0]], population[parents[:, 1]]
    from_second = jax.random.bernoulli(mix_key, 0.5, first.shape) & jax.random.bernoulli(
        cross_key, config.crossover_rate, (num_children, 1)
    )
    children = jnp.where(from_second, second, first)
    children = children + config.mutation_scale * jax.random.normal(mutate_key, children.shape)

    state = GAState(
        population=jnp.concatenate([population[elites], children]),
        best_params=population[elites[0]],
        best_fitness=fitness[elites[0]],
        generation=state.generation + 1,
        key=key,
    )
    metrics = {"best_fitness": fitness[elites[0]], "mean_fitness": fitness.mean(), "env_steps": env_steps}
    return state, metrics


def candidates(state: GAState) -> jax.Array:
    """Candidates of the final selection: the next generation [population_size, num_params], elites first."""
    return state.population


def load_policy(run_dir: pathlib.Path, config: dict) -> Policy:
    """The greedy policy of a saved GA run (``agentax play/evaluate --policy DIR``)."""
    return load_net_policy(run_dir, config)


__all__ = ["GAConfig", "GAState", "candidates", "init", "load_policy", "step"]
