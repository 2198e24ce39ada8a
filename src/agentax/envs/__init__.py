"""Environments: agentax's JAX envs by id, and ``make`` that falls back to Gymnasium."""

from __future__ import annotations

import difflib
import importlib
from collections.abc import Callable
from typing import Any

import gymnasium

from agentax.envs.atari import AtariEnv, atari_games, is_atari_id, make_atari
from agentax.envs.cartpole import CartPole, CartPoleNoVel, cartpole_v0, cartpole_v1
from agentax.envs.core import Box, Discrete, Environment, TimeStep
from agentax.envs.gridworld import GridWorld
from agentax.envs.gym import (
    NAMESPACE,
    GymnasiumEnv,
    JaxToGymnasium,
    is_gymnasium_id,
    register_envs,
)
from agentax.envs.gymnax import factories as gymnax_envs
from agentax.envs.mdp import lecture_mdp_env
from agentax.envs.pendulum import MountainCarContinuous, Pendulum, PendulumNoVel
from agentax.envs.spaces import packed
from agentax.envs.tictactoe import TicTacToe
from agentax.envs.vacuum import Vacuum
from agentax.errors import UsageError

JAX_ENVS: dict[str, Callable[[], Environment]] = {
    "CartPole-v0": cartpole_v0,
    "CartPole-v1": cartpole_v1,
    "CartPoleNoVel-v1": CartPoleNoVel,
    "Vacuum-v0": Vacuum,
    "LectureMDP-v0": lecture_mdp_env,
    "Pendulum-v1": Pendulum,
    "PendulumNoVel-v1": PendulumNoVel,
    "MountainCarContinuous-v0": MountainCarContinuous,
    "GridWorld-v0": GridWorld,
    "TicTacToe-v0": TicTacToe,
    **gymnax_envs(),  # gymnax/<ID>, where gymnax is installed
}


def make_jax(env_id: str) -> Environment:
    """The JAX-native env registered as ``env_id`` (its observations packed where they are composite,
    :func:`agentax.envs.spaces.packed`); a clear error for any other id."""
    if env_id not in JAX_ENVS:
        raise UsageError(f"unknown JAX env {env_id!r}; choose from {', '.join(JAX_ENVS)}")
    return packed(JAX_ENVS[env_id]())


_made: dict[str, Environment] = {}


def make(env_id: str, num_envs: int = 1, **gymnasium_kwargs: Any) -> Environment | GymnasiumEnv | AtariEnv:
    """The JAX-native env ``env_id`` where one exists, else an Atari game or Gymnasium's, on the host.

    ``agentax/ID`` names the same JAX env as ``ID``. Atari ids (``ALE/Breakout-v5``, EnvPool's
    ``Breakout-v5``) give ``make_atari(env_id, num_envs, **gymnasium_kwargs)`` (its keywords:
    backend, sticky_actions, noop_max, training, max_frames). ``num_envs`` and ``gymnasium_kwargs``
    otherwise shape a Gymnasium env (``gymnasium.make_vec``); JAX envs batch with ``vmap`` instead.
    """
    name = env_id.removeprefix(f"{NAMESPACE}/")
    if name in JAX_ENVS:
        if name not in _made:  # one instance per id, so compiled functions keyed on the env are reused
            _made[name] = make_jax(name)
        return _made[name]
    if is_atari_id(env_id):
        return make_atari(env_id, num_envs, **gymnasium_kwargs)
    if is_gymnasium_id(env_id):
        return GymnasiumEnv(env_id, num_envs, **gymnasium_kwargs)
    raise unknown_env(env_id)


def unknown_env(env_id: str) -> UsageError:
    """The one-line error for an id neither agentax nor Gymnasium registers: the closest ids of each
    (difflib) and Gymnasium's own word on it (a deprecated or missing version, a misspelt name)."""
    theirs = [i for i in gymnasium.registry if not i.startswith(f"{NAMESPACE}/")]
    theirs += [f"ALE/{game}-v5" for game in atari_games()]
    guesses = [
        f"{' or '.join(close)} ({owner})"
        for owner, ids in (("agentax", JAX_ENVS), ("Gymnasium", dict.fromkeys(theirs)))
        if (close := difflib.get_close_matches(env_id, list(ids), n=3, cutoff=0.6))
    ]
    if guesses:
        where = f"did you mean {', '.join(guesses)}? "
    else:
        where = f"choose from agentax's JAX envs ({', '.join(JAX_ENVS)}) or any Gymnasium id; "
    return UsageError(
        f"unknown env {env_id!r}; {where}{gymnasium_says(env_id)}(agentax envs lists a selection)"
    )


def gymnasium_says(env_id: str) -> str:
    """Gymnasium's own message on ``env_id`` ("Gymnasium says: ... "), or "" where it has none."""
    try:
        gymnasium.spec(env_id)
    except gymnasium.error.Error as error:
        return f"Gymnasium says: {' '.join(str(error).split())} "
    return ""


def host_env_id(env_id: str) -> str:
    """The Gymnasium id to step ``env_id`` on the host: Gymnasium's own where it has one (CartPole,
    step-for-step equal to agentax's), else agentax's JAX env registered as ``agentax/ID`` where
    agentax registers that id; a ``module:Env`` id as it is, once its module imports (a
    ``UsageError`` where it does not); a ``UsageError`` (:func:`unknown_env`) for any other id."""
    if env_id in gymnasium.registry:
        return env_id
    if ":" in env_id:  # "module:Env-v0": Gymnasium imports the module, whose import registers the env
        module = env_id.partition(":")[0]
        try:
            importlib.import_module(module)
        except ImportError as error:
            raise UsageError(
                f"cannot import {module!r} for {env_id} ({error}): run from the folder that holds it, "
                "or put that folder on PYTHONPATH"
            ) from None
        return env_id
    if f"{NAMESPACE}/{env_id}" in gymnasium.registry:
        return f"{NAMESPACE}/{env_id}"
    if env_id in JAX_ENVS:
        raise UsageError(f"{env_id} steps only inside a compiled program: train it with --runner compiled")
    raise unknown_env(env_id)


def make_host_env(
    env_id: str, num_envs: int, *, training: bool = False, backend: str = "auto", sticky_actions: float = 0.25
) -> Any:
    """``num_envs`` copies of ``env_id`` stepped on the host. Atari games get the standard
    preprocessing (``agentax.envs.atari``): with ``training``, the learning view (a lost life ends
    an episode, clipped rewards), else whole games and true scores; other envs ignore these options."""
    if is_atari_id(env_id):
        return make_atari(env_id, num_envs, backend=backend, sticky_actions=sticky_actions, training=training)
    return GymnasiumEnv(host_env_id(env_id), num_envs)


register_envs({k: v for k, v in JAX_ENVS.items() if "/" not in k})  # gymnax/ ids are gymnax's own

__all__ = [
    "JAX_ENVS",
    "Box",
    "CartPole",
    "Discrete",
    "Environment",
    "GymnasiumEnv",
    "JaxToGymnasium",
    "TimeStep",
    "host_env_id",
    "make",
    "make_host_env",
    "make_jax",
]
