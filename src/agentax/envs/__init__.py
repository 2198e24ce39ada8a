"""Environments: agentax's JAX envs by id, and ``make`` that falls back to Gymnasium."""

from __future__ import annotations

from collections.abc import Callable

from agentax.envs.cartpole import CartPole, cartpole_v0, cartpole_v1
from agentax.envs.core import Box, Discrete, Environment, TimeStep
from agentax.errors import UsageError

JAX_ENVS: dict[str, Callable[[], Environment]] = {
    "CartPole-v0": cartpole_v0,
    "CartPole-v1": cartpole_v1,
}


def make_jax(env_id: str) -> Environment:
    """The JAX-native env registered as ``env_id``; a clear error for any other id."""
    if env_id not in JAX_ENVS:
        raise UsageError(f"unknown JAX env {env_id!r}; choose from {', '.join(JAX_ENVS)}")
    return JAX_ENVS[env_id]()


__all__ = ["JAX_ENVS", "Box", "CartPole", "Discrete", "Environment", "TimeStep", "make_jax"]
