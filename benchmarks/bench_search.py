"""Policy search: wall-clock to solve CartPole with GA and CEM, and vacuum (p, r) settings per second.

**CartPole.** For each of GA and CEM on CartPole-v0 (solved at a mean of 195) and CartPole-v1 (475),
with the default configs (population 64, 5 episodes per fitness, the lecture's 4 → 5 elu → 1 sigmoid
network, greedy actions): run generations until the policy is solved, and record the wall-clock,
compilation excluded (measured apart, ahead of time). "Solved" is checked the way the CLI reports it:
after any generation whose best fitness reaches the threshold, the final selection (20 new episodes)
picks a policy and 100 fresh episodes evaluate it; the search stops once their mean reaches the
threshold, and the time of these checks counts. The median over ``SEEDS`` seeds is reported.

**Reference, same run**: the same GA and CEM written in NumPy, each population evaluated on
Gymnasium's NumPy-vectorized CartPole (``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")``,
population × episodes envs stepped together) with a NumPy forward pass of the same network — the
fastest way to evaluate a population without JAX on this machine.

**Vacuum.** (p, r) settings evaluated per second by ``agentax.envs.vacuum.evaluate_settings``
(``VACUUM_SETTINGS`` settings × 4 episodes of 900 steps in one vmapped call, compile apart), against
the same robot model written in NumPy and vectorized over all settings × episodes.

Run: ``python benchmarks/run.py search``.
"""

from __future__ import annotations

import math
import statistics
import time
from functools import partial

import gymnasium as gym
import jax
import numpy as np

from agentax.envs.core import episode_returns
from agentax.envs.vacuum import Vacuum
from agentax.search import cem, genetic
from agentax.search.population import FlatPolicy, make_env, make_fitness, select_best
from agentax.search.settings import evaluate_settings

SEEDS = (0, 1, 2, 3, 4)
MAX_GENERATIONS = 60
FRESH_EPISODES = 100
VACUUM_SETTINGS = 1024
VACUUM_EPISODES = 4
TASKS = (("CartPole-v0", 195.0), ("CartPole-v1", 475.0))


# ---- agentax (JAX) ---------------------------------------------------------------------------------


def jax_time_to_solve(algorithm, config, env_id: str, threshold: float) -> dict:
    """Compile the generation step, final selection and fresh evaluation; then time seeds to solution."""
    env = make_env(env_id, config.net)
    flat = FlatPolicy.create(env, config.net)
    fitness = make_fitness(env, flat, config.num_episodes)
    selection = make_fitness(env, flat, config.selection_episodes)
    init = jax.jit(partial(algorithm.init, num_params=flat.num_params, config=config))
    start = time.perf_counter()
    state = init(jax.random.key(0))
    step = jax.jit(partial(algorithm.step, fitness_fn=fitness, config=config)).lower(state).compile()
    select = jax.jit(lambda state, key: select_best(selection, algorithm.candidates(state), key)[0])
    select = select.lower(state, jax.random.key(0)).compile()
    fresh = jax.jit(
        lambda theta, key: episode_returns(env, flat.policy(theta), key, FRESH_EPISODES)[0].mean()
    )
    fresh = fresh.lower(state.best_params, jax.random.key(0)).compile()
    compile_seconds = time.perf_counter() - start

    runs = []
    for seed in SEEDS:
        key = jax.random.key(seed)
        state = init(key)
        jax.block_until_ready(state)
        start, env_steps = time.perf_counter(), 0
        for generation in range(1, MAX_GENERATIONS + 1):  # noqa: B007 (reported after the loop)
            state, metrics = step(state)
            env_steps += int(metrics["env_steps"])
            if float(metrics["best_fitness"]) >= threshold:
                theta = select(state, jax.random.fold_in(key, 2))
                score = float(fresh(theta, jax.random.fold_in(key, 1)))
                if score >= threshold:
                    break
        runs.append((time.perf_counter() - start, generation, env_steps, score, score >= threshold))
    return summarize(runs, compile_seconds)


def summarize(runs, compile_seconds) -> dict:
    solved = [run for run in runs if run[4]]
    return {
        "seconds": statistics.median(run[0] for run in runs) if len(solved) == len(runs) else math.nan,
        "generations": statistics.median(run[1] for run in runs),
        "env_steps": int(statistics.median(run[2] for run in runs)),
        "fresh_mean": statistics.median(run[3] for run in runs),
        "steps_per_second": statistics.median(run[2] / run[0] for run in runs),
        "solved": f"{len(solved)}/{len(runs)}",
        "compile_seconds": compile_seconds,
    }


# ---- the NumPy + Gymnasium reference ---------------------------------------------------------------


class NumpyPopulation:
    """Fitness of a population of 4 → 5 elu → 1 sigmoid networks on Gymnasium's vectorized CartPole."""

    def __init__(self, env_id: str, population_size: int, num_episodes: int):
        self.population_size, self.num_episodes = population_size, num_episodes
        self.envs = {}
        self.env_id = env_id
        self.num_params = 4 * 5 + 5 + 5 + 1

    def _env(self, num_envs: int):
        if num_envs not in self.envs:
            self.envs[num_envs] = gym.make_vec(
                self.env_id, num_envs=num_envs, vectorization_mode="vector_entry_point"
            )
        return self.envs[num_envs]

    def fitness(self, population: np.ndarray, num_episodes: int, seed: int) -> tuple[np.ndarray, int]:
        """Mean return ``[P]`` over ``num_episodes`` episodes each (common initial states), and env steps."""
        size = population.shape[0]
        env = self._env(size * num_episodes)
        env.reset(seed=seed)
        initial = np.random.default_rng(seed).uniform(
            -0.05, 0.05, (4, num_episodes)
        )  # the same for every member
        env.unwrapped.state = np.tile(
            initial, (1, size)
        )  # env i = member i // num_episodes, episode i % num_episodes
        obs = env.unwrapped.state.T.astype(np.float32)
        w1 = population[:, :20].reshape(size, 4, 5)
        b1, w2, b2 = population[:, 20:25], population[:, 25:30], population[:, 30]
        returns = np.zeros(size * num_episodes)
        alive = np.ones(size * num_episodes, bool)
        steps = 0
        while alive.any():
            x = obs.reshape(size, num_episodes, 4)
            h = np.einsum("pei,pih->peh", x, w1) + b1[:, None]
            h = np.where(h > 0, h, np.expm1(np.minimum(h, 0)))  # elu
            z = np.einsum("peh,ph->pe", h, w2) + b2[:, None]
            action = np.where(z > 0, 0, 1).reshape(-1)  # logits [z, 0]: greedy picks action 0 when z > 0
            obs, reward, terminated, truncated, _ = env.step(action)
            steps += int(alive.sum())
            returns += reward * alive
            alive &= ~(terminated | truncated)
        return returns.reshape(size, num_episodes).mean(axis=1), steps


def numpy_ga_step(rng, population, fitness, config):
    num_elites, size = config.num_elites, config.population_size
    elites = np.argsort(-fitness, kind="stable")[:num_elites]
    contenders = rng.integers(0, size, (size - num_elites, 2, config.tournament_size))
    winners = np.take_along_axis(contenders, np.argmax(fitness[contenders], axis=-1)[..., None], -1)[..., 0]
    first, second = population[winners[:, 0]], population[winners[:, 1]]
    crossed = (rng.random(first.shape) < 0.5) & (rng.random((first.shape[0], 1)) < config.crossover_rate)
    children = np.where(crossed, second, first) + config.mutation_scale * rng.standard_normal(first.shape)
    return np.concatenate([population[elites], children]), population  # next generation, candidates


def numpy_time_to_solve(algorithm_name: str, config, env_id: str, threshold: float) -> dict:
    """The same search in NumPy on Gymnasium's vectorized CartPole."""
    evaluator = NumpyPopulation(env_id, config.population_size, config.num_episodes)
    evaluator.fitness(
        np.zeros((config.population_size, evaluator.num_params)), config.num_episodes, 0
    )  # warm up
    runs = []
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        dim = evaluator.num_params
        if algorithm_name == "ga":
            population = config.init_scale * rng.standard_normal((config.population_size, dim))
        else:
            mean, std = np.zeros(dim), np.full(dim, config.init_std)
        start, env_steps, episode_seed = time.perf_counter(), 0, 1_000_000 * (seed + 1)
        for generation in range(1, MAX_GENERATIONS + 1):
            if algorithm_name == "cem":
                noise = rng.standard_normal((config.population_size - 1, dim))
                population = np.concatenate([mean[None], mean + std * noise])
            fitness, steps = evaluator.fitness(population, config.num_episodes, episode_seed)
            env_steps, episode_seed = env_steps + steps, episode_seed + config.num_episodes
            if algorithm_name == "ga":
                population, candidates = numpy_ga_step(rng, population, fitness, config)
            else:
                elites = population[np.argsort(-fitness, kind="stable")[: config.num_elites]]
                decay = max(1.0 - (generation - 1) / config.noise_decay_generations, 0.0)
                mean, std = elites.mean(0), np.sqrt(elites.var(0) + (config.extra_noise * decay) ** 2)
                candidates = np.stack([mean, elites[0]])
            if fitness.max() >= threshold:
                scores, _ = evaluator.fitness(candidates, config.selection_episodes, 7 + seed)
                theta = candidates[np.argmax(scores)]
                score = float(evaluator.fitness(theta[None], FRESH_EPISODES, 10_000 + seed)[0][0])
                if score >= threshold:
                    break
        runs.append((time.perf_counter() - start, generation, env_steps, score, score >= threshold))
    return summarize(runs, 0.0)


# ---- the vacuum: JAX against the same model in NumPy ------------------------------------------------


def numpy_vacuum(p: np.ndarray, r: np.ndarray, num_episodes: int, seed: int) -> np.ndarray:
    """The vacuum model of ``agentax.envs.vacuum`` in NumPy: dust ``[settings, episodes]``, all at once."""
    params = Vacuum().default_params()
    rng = np.random.default_rng(seed)
    batch, grid = p.size * num_episodes, params.grid_size
    p, r = np.repeat(p, num_episodes), np.repeat(r, num_episodes)
    low, high = params.robot_radius, params.room_size - params.robot_radius
    x, y = rng.uniform(low, high, batch), rng.uniform(low, high, batch)
    heading = rng.uniform(-np.pi, np.pi, batch)
    dirty = np.ones((batch, grid, grid), bool)
    dust, rows = np.zeros(batch), np.arange(batch)
    distance_per_move = params.speed * params.step_seconds
    for _ in range(int(params.max_steps_in_episode)):
        forward = rng.random(batch) < p
        turn = (2 * rng.random(batch) - 1) * r
        distance = np.where(forward, distance_per_move, 0.0)
        travel_x, travel_y = distance * np.cos(heading), distance * np.sin(heading)
        with np.errstate(divide="ignore", invalid="ignore"):
            room_x = np.where(
                travel_x > 0, (high - x) / travel_x, np.where(travel_x < 0, (low - x) / travel_x, np.inf)
            )
            room_y = np.where(
                travel_y > 0, (high - y) / travel_y, np.where(travel_y < 0, (low - y) / travel_y, np.inf)
            )
        fraction = np.clip(np.minimum(room_x, room_y), 0.0, 1.0)
        for k in range(1, params.cleaning_points + 1):
            along = fraction * k / params.cleaning_points
            column = np.clip(((x + along * travel_x) / params.cell_size).astype(int), 0, grid - 1)
            row = np.clip(((y + along * travel_y) / params.cell_size).astype(int), 0, grid - 1)
            dust += dirty[rows, row, column]
            dirty[rows, row, column] = False
        x, y = np.clip(x + fraction * travel_x, low, high), np.clip(y + fraction * travel_y, low, high)
        heading = np.where(forward, heading, (heading + turn + np.pi) % (2 * np.pi) - np.pi)
    return dust.reshape(-1, num_episodes)


def vacuum_rates() -> tuple[float, float, float, float, float]:
    rng = np.random.default_rng(0)
    p = rng.uniform(0, 1, VACUUM_SETTINGS).astype(np.float32)
    r = rng.uniform(0, np.pi, VACUUM_SETTINGS).astype(np.float32)
    start = time.perf_counter()
    jax.block_until_ready(evaluate_settings(p, r, jax.random.key(0), VACUUM_EPISODES))
    first_call = time.perf_counter() - start
    start = time.perf_counter()
    jax.block_until_ready(evaluate_settings(p, r, jax.random.key(1), VACUUM_EPISODES))
    jax_seconds = time.perf_counter() - start
    start = time.perf_counter()
    numpy_vacuum(p, r, VACUUM_EPISODES, 0)
    numpy_seconds = time.perf_counter() - start
    # The two implementations agree on the model: the same setting collects the same dust on average.
    check_p, check_r = np.full(256, 0.8, np.float32), np.full(256, 3.0, np.float32)
    jax_mean = float(
        np.asarray(evaluate_settings(check_p, check_r, jax.random.key(2), VACUUM_EPISODES)).mean()
    )
    numpy_mean = float(numpy_vacuum(check_p, check_r, VACUUM_EPISODES, 2).mean())
    compile_seconds = first_call - jax_seconds
    return (
        VACUUM_SETTINGS / jax_seconds,
        VACUUM_SETTINGS / numpy_seconds,
        compile_seconds,
        jax_mean,
        numpy_mean,
    )


HEADERS = ["task", "implementation", "solved", "seconds (vacuum: settings/s)", "generations", "env steps",
           "env steps/s", "fresh mean return", "compile s", "speed-up"]  # fmt: skip


def run() -> dict:
    rows = []
    for env_id, threshold in TASKS:
        for name, algorithm, config in (("GA", genetic, genetic.GAConfig()), ("CEM", cem, cem.CEMConfig())):
            ours = jax_time_to_solve(algorithm, config, env_id, threshold)
            reference = numpy_time_to_solve(name.lower(), config, env_id, threshold)
            for label, result in (("agentax (JAX)", ours), ("NumPy + Gymnasium vector env", reference)):
                cells = [result[column] for column in ("solved", "seconds", "generations", "env_steps")]
                cells += [result["steps_per_second"], result["fresh_mean"], result["compile_seconds"]]
                speed_up = reference["seconds"] / result["seconds"]
                rows.append([f"{name} {env_id} (≥ {threshold:g})", label, *cells, speed_up])
    jax_rate, numpy_rate, compile_seconds, jax_mean, numpy_mean = vacuum_rates()
    steps = VACUUM_EPISODES * 900  # env steps per setting
    task = f"vacuum ({VACUUM_SETTINGS} settings × {VACUUM_EPISODES} episodes)"
    rows.append([task, "agentax (JAX)", "", jax_rate, "", "", jax_rate * steps, jax_mean, compile_seconds,
                 jax_rate / numpy_rate])  # fmt: skip
    rows.append(["", "NumPy, vectorized", "", numpy_rate, "", "", numpy_rate * steps, numpy_mean, 0.0, 1.0])
    notes = __doc__.split("\n\n", 1)[1].rsplit("\n\nRun:", 1)[0] + (
        f"\n\nColumns: seeds solved within {MAX_GENERATIONS} generations; median seconds to solve "
        "(compile apart; vacuum: settings per second); median generations, env steps and env steps per "
        f"second; median mean return of the solved policy on {FRESH_EPISODES} fresh episodes (vacuum: mean "
        "dust of p = 0.8, r = 3.0 over 1,024 episodes, the two implementations side by side, a check that "
        "they simulate the same model); compile seconds; speed-up = reference seconds ÷ agentax seconds "
        "(vacuum: rate ratio). CartPole falls to these searches in a few generations, so the seconds to "
        "solve are small and noisy; env steps per second compare the two evaluators more steadily. "
        "The vacuum in JAX pays for the env protocol's auto-reset, which draws and selects a fresh room "
        "(its 400 cells packed into 13 words) for every env on every step, and for PRNG key splits per env "
        "per step; the NumPy model needs neither, since every episode lasts exactly 900 steps."
    )
    return {
        "name": "search",
        "title": "Policy search: time to solve CartPole (GA, CEM), vacuum settings per second",
        "headers": HEADERS,
        "rows": rows,
        "notes": notes,
    }
