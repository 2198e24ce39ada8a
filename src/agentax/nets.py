"""Flax modules shared by every agent: MLP torso and the heads of the lecture.

Parameters are plain pytrees (``module.init`` / ``module.apply``), so they scan, vmap over seeds
and checkpoint cleanly. Every policy network returns action *logits* ``[..., num_actions]``;
the lecture's one-sigmoid-output network for two actions is the categorical with logits
``[z, 0]``, since ``softmax([z, 0])[0] == sigmoid(z)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

ACTIVATIONS = {"elu": nn.elu, "relu": nn.relu, "tanh": nn.tanh, "gelu": nn.gelu, "swish": nn.swish}


class MLP(nn.Module):
    """Dense layers with one activation: ``[..., in] -> [..., hidden[-1]]`` (or ``out`` if given)."""

    hidden: Sequence[int]
    activation: str = "elu"
    out: int | None = None

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = ACTIVATIONS[self.activation]
        for width in self.hidden:
            x = act(nn.Dense(width)(x))
        if self.out is not None:
            x = nn.Dense(self.out)(x)
        return x


class NatureCNN(nn.Module):
    """The DQN Nature paper's torso (Mnih et al., 2015): ``[..., 4, 84, 84]`` frames → ``[..., 512]``.

    Conv 32 8×8 stride 4, conv 64 4×4 stride 2, conv 64 3×3 stride 1, dense 512, ReLU after each.
    Observations stay uint8 (channel-first stacks, as EnvPool and the frame replay give them) until
    here: the network divides by 255.
    """

    @nn.compact
    def __call__(self, frames: jax.Array) -> jax.Array:
        batch_shape = frames.shape[:-3]
        x = frames.reshape(-1, *frames.shape[-3:]).astype(jnp.float32) / 255.0
        x = jnp.transpose(x, (0, 2, 3, 1))  # [N, C, H, W] -> [N, H, W, C]
        init = nn.initializers.orthogonal(jnp.sqrt(2.0))
        for features, size, stride in ((32, 8, 4), (64, 4, 2), (64, 3, 1)):
            x = nn.relu(
                nn.Conv(features, (size, size), (stride, stride), padding="VALID", kernel_init=init)(x)
            )
        x = nn.relu(nn.Dense(512, kernel_init=init)(x.reshape(x.shape[0], -1)))
        return x.reshape(*batch_shape, 512)


def is_image(obs_shape: Sequence[int]) -> bool:
    """Whether observations of this shape are stacked frames ``[C, H, W]`` (the Nature CNN's input)."""
    return len(obs_shape) == 3


class PolicyNet(nn.Module):
    """Action logits ``[..., num_actions]`` from observations ``[..., obs_dim]``.

    ``sigmoid_head=True`` (two actions only) is the lecture's network: one output ``z`` with
    ``P(action 0) = sigmoid(z)``, returned as logits ``[z, 0]``.
    """

    num_actions: int
    hidden: Sequence[int] = (5,)
    activation: str = "elu"
    sigmoid_head: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = MLP(self.hidden, self.activation)(obs)
        if self.sigmoid_head:
            z = nn.Dense(1)(x)
            return jnp.concatenate([z, jnp.zeros_like(z)], axis=-1)
        return nn.Dense(self.num_actions)(x)


class QNetwork(nn.Module):
    """Q-values ``[..., num_actions]``; ``dueling`` = "max" (the lecture) or "mean" splits V and A.

    Dueling: ``Q = V + (A - max A)`` or ``Q = V + (A - mean A)``.
    """

    num_actions: int
    hidden: Sequence[int] = (32, 32)
    activation: str = "elu"
    dueling: str | None = None
    cnn: bool = False
    """the Nature CNN torso (image observations) instead of the MLP"""

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = NatureCNN()(obs) if self.cnn else MLP(self.hidden, self.activation)(obs.astype(jnp.float32))
        if self.dueling is None:
            return nn.Dense(self.num_actions)(x)
        value = nn.Dense(1)(x)  # (..., 1)
        advantage = nn.Dense(self.num_actions)(x)  # (..., num_actions)
        return dueling_aggregate(value, advantage, self.dueling)


def dueling_aggregate(value: jax.Array, advantage: jax.Array, mode: str) -> jax.Array:
    """``V + (A - max A)`` (mode "max") or ``V + (A - mean A)`` (mode "mean")."""
    if mode == "max":
        baseline = advantage.max(axis=-1, keepdims=True)
    elif mode == "mean":
        baseline = advantage.mean(axis=-1, keepdims=True)
    else:
        raise ValueError(f"unknown dueling mode {mode!r}; choose from max, mean")
    return value + advantage - baseline


def sample_action(key: jax.Array, logits: jax.Array) -> jax.Array:
    """Sample actions ``[...]`` from logits ``[..., num_actions]`` (explore)."""
    return jax.random.categorical(key, logits, axis=-1)


def greedy_action(logits: jax.Array) -> jax.Array:
    """The most probable action ``[...]`` (exploit)."""
    return jnp.argmax(logits, axis=-1)


def log_prob(logits: jax.Array, action: jax.Array) -> jax.Array:
    """``log pi(action | s)`` ``[...]`` from logits ``[..., num_actions]`` and integer actions ``[...]``."""
    log_probs = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(log_probs, action[..., None].astype(jnp.int32), axis=-1)[..., 0]


def entropy(logits: jax.Array) -> jax.Array:
    """Entropy ``[...]`` of the categorical given by logits ``[..., num_actions]``."""
    log_probs = jax.nn.log_softmax(logits, axis=-1)
    return -(jnp.exp(log_probs) * log_probs).sum(axis=-1)


class ActorCritic(nn.Module):
    """Separate actor and critic MLPs (PPO): ``obs [..., obs_dim] -> (actor_out, value [...])``.

    Discrete actions: ``actor_out`` is the logits ``[..., action_dim]``. Continuous actions
    (``continuous=True``): ``actor_out`` is ``(mean, log_std)``, each ``[..., action_dim]``, a
    diagonal Gaussian whose ``log_std`` is a learned parameter independent of the state.
    Orthogonal initialisation (gain √2 hidden, 0.01 policy head, 1 value head) as in the PPO paper's code.
    With ``cnn`` both heads sit on one shared Nature CNN.
    """

    action_dim: int
    continuous: bool = False
    hidden: Sequence[int] = (64, 64)
    activation: str = "tanh"
    cnn: bool = False
    """one Nature CNN torso shared by actor and critic (image observations), as CleanRL's Atari PPO"""

    @nn.compact
    def __call__(self, obs: jax.Array):
        act = ACTIVATIONS[self.activation]
        hidden_init = nn.initializers.orthogonal(jnp.sqrt(2.0))
        actor = critic = NatureCNN()(obs) if self.cnn else obs.astype(jnp.float32)
        for width in () if self.cnn else self.hidden:
            actor = act(nn.Dense(width, kernel_init=hidden_init)(actor))
            critic = act(nn.Dense(width, kernel_init=hidden_init)(critic))
        actor_out = nn.Dense(self.action_dim, kernel_init=nn.initializers.orthogonal(0.01))(actor)
        value = nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0))(critic)[..., 0]
        if self.continuous:
            log_std = self.param("log_std", nn.initializers.zeros, (self.action_dim,))
            return (actor_out, jnp.broadcast_to(log_std, actor_out.shape)), value
        return actor_out, value


def gaussian_log_prob(mean: jax.Array, log_std: jax.Array, action: jax.Array) -> jax.Array:
    """``log N(action; mean, exp(log_std)^2)`` summed over the action dimensions: ``[..., d] -> [...]``."""
    z = (action - mean) * jnp.exp(-log_std)
    return (-0.5 * z**2 - log_std - 0.5 * jnp.log(2 * jnp.pi)).sum(axis=-1)


def gaussian_entropy(log_std: jax.Array) -> jax.Array:
    """Entropy of a diagonal Gaussian, summed over the action dimensions: ``[..., d] -> [...]``."""
    return (log_std + 0.5 * jnp.log(2 * jnp.pi * jnp.e)).sum(axis=-1)
