"""What the off-policy actor-critics for continuous actions (SAC, TD3) share: the replay and schedule
settings of their configs, the experience they ask runners for, and the uniform warm-up.

Both act in ``[-1, 1]^d`` (the env receives actions rescaled to its bounds by ``env_action``), learn
one step per ``learn`` call, and take ``utd · train_frequency · num_envs`` learning steps per phase.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from agentax.agents.protocol import OffPolicy, check_fields
from agentax.errors import UsageError
from agentax.policies import linear_schedule


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


def warm_up(action: jax.Array, key: jax.Array, progress: jax.Array, learning_starts: int) -> jax.Array:
    """``action`` ``[E, d]``, or uniform actions in ``[-1, 1]`` while ``progress < learning_starts``."""
    uniform = jax.random.uniform(key, action.shape, minval=-1.0, maxval=1.0)
    return jnp.where(progress < learning_starts, uniform, action)


__all__ = ["ReplayConfig", "warm_up"]
