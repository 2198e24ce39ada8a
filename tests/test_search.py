"""Policy search: GA and CEM on a known optimum and on CartPole; the vacuum's grid search and heatmap."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agentax.envs.core import episode_returns
from agentax.envs.vacuum import Vacuum
from agentax.errors import UsageError
from agentax.evaluate import evaluate
from agentax.search import (
    CEMConfig,
    FlatPolicy,
    GAConfig,
    GridSearchConfig,
    NetConfig,
    RandomSearchConfig,
    cem,
    evaluate_settings,
    genetic,
    grid_search,
    make_env,
    make_fitness,
    mean_confidence_interval,
    plot_heatmap,
    random_search,
    run_generations,
    vacuum_policy,
)
from agentax.search.population import evaluate_population, select_final

OPTIMUM = jnp.array([1.0, -2.0, 0.5, 3.0, -1.5, 0.0])


def shifted_sphere(theta, key):
    """Fitness -||theta - OPTIMUM||², at most 0, reached only at OPTIMUM; no env steps."""
    return -jnp.sum((theta - OPTIMUM) ** 2), jnp.int32(0)


def run(algorithm, config, fitness, num_params, seeds=1, seed=0):
    history = []
    keys = jax.vmap(jax.random.key)(jnp.arange(seed, seed + seeds))
    state = run_generations(
        partial(algorithm.init, num_params=num_params, config=config),
        partial(algorithm.step, fitness_fn=fitness, config=config),
        keys,
        config.generations,
        lambda generation, metrics: history.append(metrics),
    )
    return state, history


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "algorithm, config",
    [
        (genetic, GAConfig(population_size=64, generations=60, mutation_scale=0.05, init_scale=2.0)),
        (cem, CEMConfig(population_size=64, generations=40, init_std=2.0, extra_noise=0.01)),
    ],
    ids=["ga", "cem"],
)
def test_finds_the_optimum_of_a_shifted_sphere(algorithm, config):
    state, history = run(algorithm, config, shifted_sphere, OPTIMUM.size, seeds=2)
    # Started at distance ~ ||OPTIMUM|| = sqrt(1 + 4 + 0.25 + 9 + 2.25) = 4.06 from the origin.
    for best in state.best_params:
        np.testing.assert_allclose(best, OPTIMUM, atol=0.15)
    assert np.all(history[-1]["best_fitness"] > -0.1)
    assert np.all(history[-1]["best_fitness"] > history[0]["best_fitness"])


@pytest.mark.slow
def test_population_evaluated_in_one_call_equals_one_by_one():
    env = make_env("CartPole-v0", NetConfig())
    flat = FlatPolicy.create(env, NetConfig())
    assert flat.num_params == 4 * 5 + 5 + 5 * 1 + 1  # the lecture's 4 -> 5 elu -> 1 sigmoid network
    fitness = make_fitness(env, flat, num_episodes=3)
    population = flat.init_population(jax.random.key(1), 4)
    key = jax.random.key(2)
    together, steps = jax.jit(partial(evaluate_population, fitness))(population, key)
    alone = [jax.jit(fitness)(theta, key) for theta in population]
    np.testing.assert_allclose(together, [value for value, _ in alone])
    # CartPole pays 1 per step, so the env steps are the returns summed: mean * 3 episodes per member.
    assert int(steps) == int(round(float(together.sum()) * 3))


@pytest.mark.slow
@pytest.mark.timeout(200)
@pytest.mark.parametrize("algorithm, config_type", [(genetic, GAConfig), (cem, CEMConfig)], ids=["ga", "cem"])
def test_improves_cartpole_and_solves_v0(algorithm, config_type):
    config = config_type(population_size=32, generations=10, num_episodes=5)
    env = make_env("CartPole-v0", config.net)
    flat = FlatPolicy.create(env, config.net)
    fitness = make_fitness(env, flat, config.num_episodes)
    state, history = run(algorithm, config, fitness, flat.num_params, seed=3)
    first, last = history[0], history[-1]
    # A random lecture network balances ~20 steps on average; selection must raise the population's mean.
    assert float(first["mean_fitness"][0]) < 60
    assert float(last["mean_fitness"][0]) > 2 * float(first["mean_fitness"][0])
    assert float(last["best_fitness"][0]) >= 195
    selection = make_fitness(env, flat, config.selection_episodes)
    best, score = select_final(algorithm.candidates, state, selection, jax.random.key(99))
    assert best.shape == (1, flat.num_params) and float(score[0]) >= 195
    stats = evaluate(env, flat.policy(best[0]), num_episodes=100, seed=12345)  # fresh seeds
    assert stats.mean_return >= 195


def test_confidence_interval_by_hand():
    # [1..5]: mean 3, sample std sqrt(2.5) = 1.5811, t(0.975, 4 dof) = 2.7764;
    # half width = 2.7764 * 1.5811 / sqrt(5) = 1.9632.
    low, high = mean_confidence_interval([1, 2, 3, 4, 5])
    assert low == pytest.approx(3 - 1.9632, abs=1e-3) and high == pytest.approx(3 + 1.9632, abs=1e-3)


def test_vacuum_policy_probabilities():
    keys = jax.random.split(jax.random.key(0), 20_000)
    actions = np.asarray(jax.vmap(vacuum_policy(0.3, 0.7), in_axes=(None, 0))(jnp.zeros(5), keys))
    # Binomial(20000, 0.3): std of the fraction = sqrt(0.3 * 0.7 / 20000) = 0.0032; 5 sigma = 0.016.
    assert abs(actions[:, 0].mean() - 0.3) < 0.016
    assert np.abs(actions[:, 1]).max() <= 0.7 and np.abs(actions[:, 1]).max() > 0.69


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_many_vacuum_settings_in_one_call_equal_one_by_one():
    p, r = np.array([0.2, 0.8, 0.95, 0.6], np.float32), np.array([0.5, 3.0, 1.5, 2.0], np.float32)
    key = jax.random.key(11)
    together = np.asarray(evaluate_settings(p, r, key, num_episodes=2))  # [4, 2]
    run_one = jax.jit(lambda p, r, key: episode_returns(Vacuum(), vacuum_policy(p, r), key, 2)[0])
    for i, setting_key in enumerate(jax.random.split(key, 4)):
        np.testing.assert_allclose(together[i], run_one(p[i], r[i], setting_key))
    # The setting that drives and turns widely beats the one that mostly turns in place.
    assert together[1].mean() > together[0].mean()


# A 10-minute episode (300 steps) keeps the grid-search tests quick.
SHORT = Vacuum().default_params().replace(episode_seconds=600.0)


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_vacuum_grid_search_heatmap_marks_the_best(tmp_path):
    config = GridSearchConfig(num_p=6, num_r=5, num_episodes=3, final_episodes=20)
    result = grid_search(config, seed=4, params=SHORT)
    means = result.returns.mean(axis=1).reshape(6, 5)  # [p, r]
    row, column = np.unravel_index(np.argmax(means), means.shape)
    p_values, r_values = np.linspace(0, 1, 6), np.linspace(0, np.pi, 5)
    assert (result.best_p, result.best_r) == pytest.approx((p_values[row], r_values[column]))
    marked = plot_heatmap(result, tmp_path / "heatmap.png")
    assert marked == pytest.approx((result.best_p, result.best_r))
    assert (tmp_path / "heatmap.png").stat().st_size > 10_000
    # p = 0 never moves (1 cell); the best setting drives, so it collects far more.
    assert means[0].max() == 1.0 and means.max() > 20
    low, high = result.ci95
    assert low < result.final_returns.mean() < high and result.final_returns.shape == (20,)
    summary = result.summary()
    assert summary["p"] == pytest.approx(result.best_p) and summary["episodes"] == 20


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_vacuum_random_search_is_reproducible():
    config = RandomSearchConfig(num_settings=8, r_max=1.0, num_episodes=2, final_episodes=5)
    first, second = random_search(config, seed=7, params=SHORT), random_search(config, seed=7, params=SHORT)
    np.testing.assert_array_equal(first.p, second.p)
    np.testing.assert_array_equal(first.returns, second.returns)
    # The settings are NumPy's uniform draws from the seed: p in [0, 1], r in [0, r_max].
    rng = np.random.default_rng(7)
    np.testing.assert_array_equal(first.p, rng.uniform(0.0, 1.0, 8).astype(np.float32))
    np.testing.assert_array_equal(first.r, rng.uniform(0.0, 1.0, 8).astype(np.float32))
    assert first.best_index == int(np.argmax(first.returns.mean(axis=1)))


@pytest.mark.parametrize(
    "make",
    [
        lambda: GAConfig(population_size=1),
        lambda: GAConfig(mutation_scale=-0.1),
        lambda: GAConfig(elite_fraction=1.0),
        lambda: GAConfig(crossover_rate=1.5),
        lambda: CEMConfig(population_size=0),
        lambda: CEMConfig(elite_fraction=0.0),
        lambda: CEMConfig(extra_noise=-1.0),
        lambda: NetConfig(activation="sigmoidal"),
        lambda: GridSearchConfig(final_episodes=1),
        lambda: make_env("Vacuum-v0", NetConfig()),
        lambda: make_env("CartPole-v9", NetConfig()),
    ],
)
def test_bad_input_raises_usage_error(make):
    with pytest.raises(UsageError):
        make()
