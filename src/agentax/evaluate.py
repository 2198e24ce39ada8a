"""Evaluating a policy: episode returns of a JAX env, batched, under ``jit``.

``episode_returns`` is pure and jittable, so it runs inside training loops and inside ``vmap``
over policy parameters (thousands of vacuum-robot settings in one call).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from agentax.envs.core import Environment, EnvParams
from agentax.policies import Policy


@dataclass(frozen=True)
class EvalStats:
    """Statistics of episode returns over ``episodes`` episodes."""

    mean_return: float
    std_return: float
    min_return: float
    max_return: float
    episodes: int
    mean_length: float

    @classmethod
    def from_returns(cls, returns, lengths) -> EvalStats:
        returns, lengths = np.asarray(returns, np.float64), np.asarray(lengths)
        return cls(
            mean_return=float(returns.mean()),
            std_return=float(returns.std()),
            min_return=float(returns.min()),
            max_return=float(returns.max()),
            episodes=int(returns.size),
            mean_length=float(lengths.mean()),
        )

    def to_json(self) -> str:
        return json.dumps(asdict(self))


def episode_returns(
    env: Environment, policy: Policy, key: jax.Array, num_episodes: int, env_params: EnvParams | None = None
) -> tuple[jax.Array, jax.Array]:
    """Play ``num_episodes`` episodes side by side until each ends once.

    Returns ``(returns, lengths)``, each ``[num_episodes]``. ``policy(obs, key) -> action`` acts on
    one observation. Jittable (``env``, ``policy`` and ``num_episodes`` static).
    """
    params = env.default_params() if env_params is None else env_params
    reset_key, key = jax.random.split(key)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(reset_key, num_episodes), params)
    zeros = jnp.zeros(num_episodes, jnp.float32)
    alive = jnp.ones(num_episodes, bool)

    def body(carry):
        obs, state, returns, lengths, alive, key = carry
        key, act_key, step_key = jax.random.split(key, 3)
        actions = jax.vmap(policy)(obs, jax.random.split(act_key, num_episodes))
        ts, state = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
            jax.random.split(step_key, num_episodes), state, actions, params
        )
        returns = returns + ts.reward * alive
        lengths = lengths + alive
        alive = alive & ~ts.done
        return ts.obs, state, returns, lengths, alive, key

    carry = (obs, state, zeros, zeros.astype(jnp.int32), alive, key)
    _, _, returns, lengths, _, _ = jax.lax.while_loop(lambda c: c[4].any(), body, carry)
    return returns, lengths


@partial(jax.jit, static_argnums=(0, 1, 3))
def _episode_returns_jit(env, policy, key, num_episodes, env_params):
    return episode_returns(env, policy, key, num_episodes, env_params)


def evaluate(
    env: Environment, policy: Policy, num_episodes: int = 100, seed: int = 0, env_params: EnvParams | None = None
) -> EvalStats:
    """Mean, std, min and max of the returns of ``num_episodes`` episodes of ``policy`` in ``env``."""
    params = env.default_params() if env_params is None else env_params
    returns, lengths = _episode_returns_jit(env, policy, jax.random.key(seed), num_episodes, params)
    return EvalStats.from_returns(returns, lengths)
