"""The ``--policy`` argument of ``agentax evaluate`` and ``agentax play``: a policy's name or a run's folder.

``basic`` (the lecture's CartPole policy) and ``random`` name hand-written policies; any other
value is a trained run's folder, whose config also names the env.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from agentax.envs import AtariEnv, Box, Discrete, Environment, GymnasiumEnv, is_atari_id, make
from agentax.errors import UsageError
from agentax.evaluate import check_policy_fits
from agentax.policies import Policy, basic_policy, random_policy

POLICY_CHOICES = "basic, random, or a trained run's folder"


def named_policy(name: str, env: Environment | GymnasiumEnv, env_id: str = "") -> Policy:
    """The policy called ``name`` (``basic`` or ``random``) for ``env``; ``UsageError`` if it does not fit."""
    env_id = env_id or getattr(env, "id", type(env).__name__)
    obs_space = getattr(env, "original_space", None) or env.observation_space()  # as the env declares it
    action_space = env.action_space()
    if name == "basic":
        is_cartpole = isinstance(obs_space, Box) and obs_space.shape == (4,) and action_space == Discrete(2)
        if not is_cartpole:
            raise UsageError(
                f"policy 'basic' is the lecture's CartPole policy (reads the pole angle, pushes left or "
                f"right); {env_id} has observations {obs_space} and actions {action_space}: choose "
                "random or a trained run's folder"
            )
        return basic_policy
    if name == "random":
        return random_policy(action_space)
    raise UsageError(f"unknown policy {name!r}; choose from {POLICY_CHOICES}")


def resolve_policy(
    policy: str,
    env_id: str | None,
    num_envs: int = 1,
    *,
    env_backend: str | None = None,
    sticky_actions: float | None = None,
) -> tuple[str, Environment | GymnasiumEnv | AtariEnv, Policy]:
    """``(env_id, env, policy_fn)`` for a policy name or a trained run's folder, checked to fit the env.

    A run's folder also gives the env id when ``env_id`` is ``None``. Gymnasium envs get ``num_envs``
    sub-envs. An Atari game is made in its evaluation view (whole games, true scores) with
    ``env_backend`` and ``sticky_actions`` where given, else the run's own (its config.json's
    "runner"), else the defaults (auto, 0.25).
    """
    options: dict[str, Any] = {}
    if Path(policy).is_dir():
        from agentax.api import restore_policy  # here: only a run's folder needs the run machinery
        from agentax.runs import read_config

        run_env_id, policy_fn = restore_policy(policy)
        env_id = env_id or run_env_id
        options = read_config(policy).get("runner") or {}
        env = _make(env_id, num_envs, env_backend, sticky_actions, options)
    elif "/" in policy or "\\" in policy:
        raise UsageError(
            f"no trained run at {policy!r}: the folder does not exist; choose from {POLICY_CHOICES}"
        )
    elif env_id is None:
        raise UsageError(
            "no env id given; name one (agentax envs lists them) or give a trained run's folder as policy"
        )
    else:
        env = _make(env_id, num_envs, env_backend, sticky_actions, options)
        policy_fn = named_policy(policy, env, env_id)
    check_policy_fits(env, policy_fn, env_id)
    return env_id, env, policy_fn


def _make(
    env_id: str, num_envs: int, env_backend: str | None, sticky_actions: float | None, run: dict[str, Any]
) -> Environment | GymnasiumEnv | AtariEnv:
    """The env to evaluate on: ``make(env_id, num_envs)``; an Atari game in its evaluation view with the
    options given, else the run's (``run``: its runner settings), else the defaults."""
    if not is_atari_id(env_id):
        return make(env_id, num_envs)
    backend = env_backend if env_backend is not None else run.get("env_backend", "auto")
    sticky = sticky_actions if sticky_actions is not None else run.get("sticky_actions", 0.25)
    return make(env_id, num_envs, backend=backend, sticky_actions=float(sticky), training=False)


def env_description(env: Any) -> str:
    """The settings a score depends on, for an Atari env (``"envpool, sticky actions 0.25"``), else ""."""
    if isinstance(env, AtariEnv):
        return f"{env.backend_name}, sticky actions {env.sticky_actions:g}"
    return ""
