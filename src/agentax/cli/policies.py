"""The ``--policy`` argument of ``agentax evaluate`` and ``agentax play``: a policy's name or a run's folder.

``basic`` (the lecture's CartPole policy) and ``random`` name hand-written policies; any other
value is a trained run's folder, whose config also names the env.
"""

from __future__ import annotations

from pathlib import Path

from agentax.envs import Box, Discrete, Environment, GymnasiumEnv, make
from agentax.errors import UsageError
from agentax.evaluate import check_policy_fits
from agentax.policies import Policy, basic_policy, random_policy

POLICY_CHOICES = "basic, random, or a trained run's folder"


def named_policy(name: str, env: Environment | GymnasiumEnv, env_id: str = "") -> Policy:
    """The policy called ``name`` (``basic`` or ``random``) for ``env``; ``UsageError`` if it does not fit."""
    env_id = env_id or getattr(env, "id", type(env).__name__)
    obs_space, action_space = env.observation_space(), env.action_space()
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
    policy: str, env_id: str | None, num_envs: int = 1
) -> tuple[str, Environment | GymnasiumEnv, Policy]:
    """``(env_id, env, policy_fn)`` for a policy name or a trained run's folder, checked to fit the env.

    A run's folder also gives the env id when ``env_id`` is ``None``. Gymnasium envs get ``num_envs``
    sub-envs.
    """
    if Path(policy).is_dir():
        from agentax.runs import load_policy  # here: only a run's folder needs the run machinery

        run_env_id, policy_fn = load_policy(policy)
        env_id = env_id or run_env_id
        env = make(env_id, num_envs)
    elif "/" in policy or "\\" in policy:
        raise UsageError(
            f"no trained run at {policy!r}: the folder does not exist; choose from {POLICY_CHOICES}"
        )
    elif env_id is None:
        raise UsageError(
            "no env id given; name one (agentax envs lists them) or give a trained run's folder as policy"
        )
    else:
        env = make(env_id, num_envs)
        policy_fn = named_policy(policy, env, env_id)
    check_policy_fits(env, policy_fn, env_id)
    return env_id, env, policy_fn
