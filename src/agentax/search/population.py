"""What the genetic algorithm and the cross-entropy method share: a neural policy as a flat vector,
its fitness, the whole population evaluated in one vmapped call, and the outer loop over generations.

A candidate is the flat parameter vector ``theta: [num_params]`` of an ``agentax.nets.PolicyNet``
(``jax.flatten_util.ravel_pytree``); a population is ``[population_size, num_params]``. Its fitness
is the mean return over a few episodes. By default actions are *greedy* (the most probable action):
that is the policy we deploy, and a deterministic policy gives a less noisy fitness than sampled
actions, so selection needs fewer episodes; ``sample_actions=True`` searches the stochastic policy.
Every member of a generation plays episodes from the same initial states (common random numbers),
so differences in fitness come from the policies rather than from luck of the draw.
"""

from __future__ import annotations

import math
import pathlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization
from jax.flatten_util import ravel_pytree

from agentax.envs import JAX_ENVS, make_jax
from agentax.envs.core import Box, Discrete, Environment, EnvParams, episode_returns
from agentax.errors import UsageError
from agentax.nets import ACTIVATIONS, PolicyNet, greedy_action, sample_action
from agentax.policies import Policy

# fitness(theta [num_params], key) -> (fitness [], env_steps []): the mean return and the env steps it took
FitnessFn = Callable[[jax.Array, jax.Array], tuple[jax.Array, jax.Array]]


@dataclass(frozen=True)
class NetConfig:
    """The policy network searched: the lecture's 4 → 5 elu → 1 sigmoid network by default."""

    hidden: tuple[int, ...] = (5,)
    """Widths of the hidden layers."""
    activation: str = "elu"
    """Activation of the hidden layers: elu, relu, tanh, gelu or swish."""
    sigmoid_head: bool = True
    """Two actions only: one sigmoid output giving P(action 0), as in the lecture; else a softmax head."""

    def __post_init__(self):
        if self.activation not in ACTIVATIONS:
            raise UsageError(f"unknown activation {self.activation!r}; choose from {', '.join(ACTIVATIONS)}")
        if any(width < 1 for width in self.hidden):
            raise UsageError(f"hidden layer widths must be >= 1, got {self.hidden}")


@dataclass(frozen=True)
class PopulationConfig:
    """What every population search shares: its size and length, and how fitness is measured."""

    population_size: int = 64
    """Candidates per generation."""
    generations: int = 20
    """Generations to run (at most)."""
    num_episodes: int = 5
    """Episodes per fitness evaluation (fitness = their mean return)."""
    selection_episodes: int = 20
    """Episodes of the final selection among the last candidates (new episodes, not the search's)."""
    sample_actions: bool = False
    """Evaluate fitness with sampled actions instead of greedy ones."""
    net: NetConfig = field(default_factory=NetConfig)
    """The policy network whose parameters are searched."""

    def __post_init__(self):
        if self.population_size <= 1:
            raise UsageError(f"population size must be at least 2, got {self.population_size}")
        for name in ("generations", "num_episodes", "selection_episodes", *self.counts):
            if getattr(self, name) < 1:
                raise UsageError(f"{name.replace('_', ' ')} must be >= 1, got {getattr(self, name)}")

    counts = ()
    """The search's own settings that must be >= 1 too."""


def check_env(env: Environment, net: NetConfig) -> None:
    """``UsageError`` unless a ``PolicyNet`` can act in ``env``: vector observations, discrete actions."""
    obs_space, action_space = env.observation_space(), env.action_space()
    if not _fits(env):
        raise UsageError(
            f"a neural policy needs vector observations and discrete actions; {env.id} has observations "
            f"{obs_space} and actions {action_space}; choose from {', '.join(fitting_envs())}"
        )
    if net.sigmoid_head and action_space.n != 2:
        raise UsageError(f"the sigmoid head needs exactly 2 actions; {env.id} has {action_space.n}")


def fitting_envs() -> list[str]:
    """The JAX envs a policy network can act in (each made once: for an error message only)."""
    return [name for name, factory in JAX_ENVS.items() if _fits(factory())]


def _fits(env: Environment) -> bool:
    obs_space = env.observation_space()
    return (
        isinstance(env.action_space(), Discrete) and isinstance(obs_space, Box) and len(obs_space.shape) == 1
    )


def make_env(env_id: str, net: NetConfig) -> Environment:
    """The JAX env ``env_id``, checked to be one the policy network can act in."""
    if env_id not in JAX_ENVS:
        raise UsageError(f"unknown env {env_id!r} for policy search; choose from {', '.join(fitting_envs())}")
    env = make_jax(env_id)
    check_env(env, net)
    return env


@dataclass(frozen=True)
class FlatPolicy:
    """A ``PolicyNet`` for ``env`` and the map between its parameter pytree and a flat vector."""

    module: PolicyNet
    obs_shape: tuple[int, ...]
    unravel: Callable[[jax.Array], dict]
    num_params: int

    @classmethod
    def create(cls, env: Environment, net: NetConfig) -> FlatPolicy:
        module = PolicyNet(env.action_space().n, tuple(net.hidden), net.activation, net.sigmoid_head)
        obs = jnp.zeros(env.observation_space().shape, jnp.float32)
        flat, unravel = ravel_pytree(module.init(jax.random.key(0), obs))
        return cls(module, obs.shape, unravel, int(flat.size))

    def init_population(self, key: jax.Array, population_size: int) -> jax.Array:
        """``[population_size, num_params]``: each member the network's own (Lecun-normal) initialisation."""
        keys = jax.random.split(key, population_size)
        obs = jnp.zeros(self.obs_shape, jnp.float32)
        return jax.vmap(lambda k: ravel_pytree(self.module.init(k, obs))[0])(keys)

    def policy(self, theta: jax.Array, greedy: bool = True) -> Policy:
        """``(obs, key) -> action`` of the network with flat parameters ``theta`` (greedy or sampled)."""
        params = self.unravel(theta)

        def act(obs: jax.Array, key: jax.Array) -> jax.Array:
            logits = self.module.apply(params, obs)
            action = greedy_action(logits) if greedy else sample_action(key, logits)
            return action.astype(jnp.int32)

        return act


def make_fitness(
    env: Environment,
    flat: FlatPolicy,
    num_episodes: int,
    greedy: bool = True,
    env_params: EnvParams | None = None,
) -> FitnessFn:
    """``fitness(theta, key)``: the mean return of ``num_episodes`` episodes of ``theta``, and the steps."""
    params = env.default_params() if env_params is None else env_params

    def fitness(theta: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        returns, lengths = episode_returns(env, flat.policy(theta, greedy), key, num_episodes, params)
        return returns.mean(), lengths.sum()

    return fitness


def evaluate_population(
    fitness: FitnessFn, population: jax.Array, key: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Fitness ``[population_size]`` of ``population: [population_size, num_params]`` in one vmapped call,
    and the env steps it took ``[]``. Every member plays from the same ``key`` (common random numbers).
    """
    fitness, env_steps = jax.vmap(fitness, in_axes=(0, None))(population, key)
    return fitness, env_steps.sum()


def select_best(fitness: FitnessFn, candidates: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The fittest of ``candidates: [num_candidates, num_params]`` on new episodes, and its fitness.

    The last step of a search: the best score seen during the search is partly luck (the best of
    thousands of noisy evaluations), so the final choice is made on episodes of its own.
    """
    scores, _ = evaluate_population(fitness, candidates, key)
    best = jnp.argmax(scores)
    return candidates[best], scores[best]


def select_final(
    candidates: Callable[[object], jax.Array], states, fitness: FitnessFn, key: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """:func:`select_best` for each seed of vmapped ``states``: ``([num_seeds, num_params], [num_seeds])``."""
    return jax.jit(jax.vmap(lambda state: select_best(fitness, candidates(state), key)))(states)


def rank_elites(fitness: jax.Array, num_elites: int) -> jax.Array:
    """Indices ``[num_elites]`` of the fittest members, best first."""
    return jax.lax.top_k(fitness, num_elites)[1]


def mean_confidence_interval(
    samples: Sequence[float] | np.ndarray, confidence: float = 0.95
) -> tuple[float, float]:
    """The two-sided Student-t confidence interval of the mean of ``samples`` (at least 2)."""
    from scipy import stats

    samples = np.asarray(samples, np.float64)
    half_width = (
        stats.t.ppf(0.5 + confidence / 2, samples.size - 1) * samples.std(ddof=1) / math.sqrt(samples.size)
    )
    mean = float(samples.mean())
    return mean - float(half_width), mean + float(half_width)


def run_generations(
    init: Callable[[jax.Array], object],
    step: Callable[[object], tuple[object, dict]],
    keys: jax.Array,
    generations: int,
    on_generation: Callable[[int, dict], bool | None] | None = None,
):
    """The outer loop: ``init`` and ``step`` vmapped over seeds (``keys: [num_seeds]``), one jitted call
    per generation, so a progress bar can show each one. ``on_generation(generation, metrics)`` gets the
    metrics as NumPy arrays ``[num_seeds]``; returning True stops early. Returns the final states.
    """
    state = jax.jit(jax.vmap(init))(keys)
    step = jax.jit(jax.vmap(step))
    for generation in range(generations):
        state, metrics = step(state)
        metrics = {name: np.asarray(value) for name, value in metrics.items()}
        if on_generation is not None and on_generation(generation, metrics):
            break
    return state


def load_net_policy(run_dir: pathlib.Path, config: dict) -> Policy:
    """The greedy policy saved by a GA or CEM run (``best_params.msgpack`` + ``config.json``)."""
    run_dir = pathlib.Path(run_dir)
    try:
        net = NetConfig(**{**config["net"], "hidden": tuple(config["net"]["hidden"])})
    except (KeyError, TypeError) as error:
        raise UsageError(f"{run_dir}/config.json does not describe the policy network ({error})") from None
    flat = FlatPolicy.create(make_env(config["env"], net), net)
    path = run_dir / "best_params.msgpack"
    try:
        theta = serialization.from_bytes(np.zeros(flat.num_params, np.float32), path.read_bytes())
    except (OSError, ValueError) as error:
        raise UsageError(f"cannot read the best parameters of run {run_dir}: {error}") from None
    if np.shape(theta) != (flat.num_params,):
        raise UsageError(
            f"{path} holds {np.shape(theta)} parameters; the network in config.json needs {flat.num_params}"
        )
    return flat.policy(jnp.asarray(theta, jnp.float32), greedy=True)
