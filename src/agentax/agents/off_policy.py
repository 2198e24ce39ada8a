"""What the off-policy actor-critics for continuous actions (SAC, TD3) share: the replay and schedule
settings of their configs, the experience they ask runners for, the learner's state, the setup (the
twin critics and one Adam), the uniform warm-up, the twin critics' clipped double-Q loss and the
``Agent`` they make.

Both act in ``[-1, 1]^d`` (the env receives actions rescaled to its bounds by ``env_action``), learn
one step per ``learn`` call, and take ``utd · train_frequency · num_envs`` learning steps per phase.
A block beside the algorithms, not an algorithm: no algorithm imports another.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from agentax.agents.protocol import (
    Agent,
    EnvSpec,
    OffPolicy,
    check_fields,
    continuous_action_dim,
    flat_observations,
    scale_action,
)
from agentax.errors import UsageError
from agentax.nets import TwinQ, with_encoder
from agentax.policies import linear_schedule
from agentax.replay import ReplaySample
from agentax.returns import bootstrap_discount


@dataclass(frozen=True)
class ReplayConfig:
    """The replay and learning schedule of an off-policy actor-critic (defaults: SB3's)."""

    hidden: tuple[int, ...] = (256, 256)
    """Widths of the hidden layers of the actor and of each critic."""
    activation: str = "relu"
    """Activation of the hidden layers: elu, relu, tanh, gelu or swish."""
    learning_rate: float = 3e-4
    """Adam's step size for every network."""
    discount_factor: float = 0.99
    """γ of the TD target."""
    tau: float = 0.005
    """Polyak rate of the target networks."""
    batch_size: int = 256
    """Transitions per learning step."""
    buffer_size: int = 1_000_000
    """Replay capacity."""
    learning_starts: int = 100
    """Env steps of uniformly random actions before the first learning step."""
    num_envs: int = 1
    """Environments stepped side by side."""
    train_frequency: int = 1
    """Steps per env collected between learning phases."""
    utd: float = 1.0
    """Updates per env step: a learning phase takes ``utd · train_frequency · num_envs`` learning steps."""
    n_step: int = 1
    """Rewards summed per transition before bootstrapping."""
    prioritized: bool = False
    """Prioritized replay: sample ∝ (|δ| + ε)^ζ, weight the critic loss by importance weights."""
    priority_exponent: float = 0.6
    """ζ of prioritized replay."""
    importance_exponent_start: float = 0.4
    """β at the start, annealed linearly to 1 by the end."""
    total_steps: int = 1_000_000
    """Env steps of the whole run (summed over envs)."""

    @property
    def steps_per_update(self) -> int:
        """Env steps (summed over envs) of one ``update`` of the compiled runner."""
        return self.num_envs * self.train_frequency

    @property
    def gradient_steps(self) -> int | jax.Array:
        """Learning steps per learning phase (a traced int where ``utd`` is traced)."""
        steps = self.utd * self.steps_per_update
        if isinstance(steps, jax.Array):  # utd traced (a sweep over it): the count is a traced int
            return jnp.maximum(1, jnp.round(steps)).astype(jnp.int32)
        return max(1, round(steps))

    @property
    def num_updates(self) -> int:
        return max(1, self.total_steps // self.steps_per_update)

    def check_replay(self, positive: tuple[str, ...] = (), non_negative: tuple[str, ...] = ()) -> None:
        """A ``UsageError`` naming the first bad shared value (and of ``positive``/``non_negative``)."""
        check_fields(
            self,
            positive=("learning_rate", "tau", "utd", "batch_size", "buffer_size", *positive),
            unit_interval=("discount_factor", "tau"),
            non_negative=("learning_starts", *non_negative),
        )
        for name in ("num_envs", "train_frequency", "n_step", "total_steps"):
            if getattr(self, name) < 1:
                raise UsageError(f"{name} must be at least 1, got {getattr(self, name)}")

    def experience(self) -> OffPolicy:
        """The replay and schedule runners drive the agent with."""
        return OffPolicy(
            num_envs=self.num_envs,
            capacity=self.buffer_size,
            batch_size=self.batch_size,
            learning_starts=self.learning_starts,
            train_frequency=self.train_frequency,
            gradient_steps=self.gradient_steps,
            n_step=self.n_step,
            discount_factor=self.discount_factor,
            prioritized=self.prioritized,
            priority_exponent=self.priority_exponent,
            importance_exponent=linear_schedule(self.importance_exponent_start, 1.0, self.total_steps),
        )


@struct.dataclass
class ActorCriticState:
    """The learner of SAC or TD3: ``params`` {"actor", "critic", ...}, the target networks, one
    optimizer state per entry of ``params``, learning steps taken."""

    params: Any
    target_params: Any
    opt_state: Any
    step: jax.Array  # int32 []


def actor_critic_setup(
    name: str, spec: EnvSpec, cfg: ReplayConfig, precision: str = "f32"
) -> tuple[int, Any, Any]:
    """``(action_dim, critic, tx)`` of actor-critic ``name`` on ``spec``: the twin critics (behind an
    encoder of packed observations; their products in ``precision``) and one Adam for every
    network, once ``cfg`` is valid and the env has flat observations and continuous actions."""
    cfg.validate()
    action_dim = continuous_action_dim(spec, name)
    flat_observations(spec, name)
    critic = with_encoder(TwinQ(tuple(cfg.hidden), cfg.activation, precision), spec.layout, precision)
    return action_dim, critic, optax.adam(cfg.learning_rate)


def adam_step(tx: Any, name: str, params: dict, opt_state: dict, grads: Any) -> tuple[Any, Any]:
    """``(params[name], opt_state[name])`` after one step of ``tx`` on ``grads``."""
    updates, new_opt_state = tx.update(grads, opt_state[name], params[name])
    return optax.apply_updates(params[name], updates), new_opt_state


def warm_up(action: jax.Array, key: jax.Array, progress: jax.Array, learning_starts: int) -> jax.Array:
    """``action`` ``[E, d]``, or uniform actions in ``[-1, 1]`` while ``progress < learning_starts``."""
    uniform = jax.random.uniform(key, action.shape, minval=-1.0, maxval=1.0)
    return jnp.where(progress < learning_starts, uniform, action)


def twin_q_loss(
    critic: TwinQ, critic_params: Any, sample: ReplaySample, next_value: jax.Array, discount_factor: float
) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """The twin critics' loss ``Σ_i mean(w · (Q_i(s, a) − y)²)`` towards the constant target
    ``y = r + γ^k (1 − terminated) · next_value`` (``next_value`` ``[batch]``: the clipped double-Q
    value of ``s′``, SAC's with its entropy bonus); with ``(mean Q, priority [batch])``, the
    priority the mean |TD error| of the two critics."""
    t = sample.transition
    discount = bootstrap_discount(t.terminated, t.num_steps, discount_factor)
    target = jax.lax.stop_gradient(t.reward + discount * next_value)
    q = critic.apply(critic_params, t.obs, t.action)  # (2, batch)
    td = q - target
    return (sample.weights * td**2).mean(axis=-1).sum(), (q.mean(), jnp.abs(td).mean(axis=0))


def continuous_agent(name: str, spec: EnvSpec, cfg: ReplayConfig, **functions: Callable) -> Agent:
    """The ``Agent`` of off-policy actor-critic ``name`` from its ``init``, ``act``, ``greedy_policy``
    and ``learn``: actions in ``[-1, 1]^d`` rescaled to the env's bounds, ``state.step`` learning steps."""
    return Agent(
        name=name,
        experience=cfg.experience(),
        total_steps=cfg.total_steps,
        env_action=lambda action: scale_action(action, spec.action_space),
        learning_steps=lambda state: state.step,
        **functions,
    )


__all__ = [
    "ActorCriticState",
    "ReplayConfig",
    "actor_critic_setup",
    "adam_step",
    "continuous_agent",
    "twin_q_loss",
    "warm_up",
]
