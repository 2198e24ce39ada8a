"""Running mean and variance of a stream of batches, and inputs normalised by them: pure functions.

What SB3's ``VecNormalize`` and Gymnasium's ``NormalizeObservation`` / ``NormalizeReward`` keep as
wrapper state, here a pytree an agent carries in its own state, so that a compiled program, a
checkpoint and every policy restored from one hold the statistics it acted with.

:func:`update` merges a batch's moments into the running ones by the parallel algorithm of Chan,
Golub and LeVeque (1979), the form SB3's and Gymnasium's ``RunningMeanStd`` use. With ``n_A`` the
count so far and ``n_B`` the batch's::

    δ    = mean_B − mean_A,   n = n_A + n_B
    mean = mean_A + δ · n_B / n
    var  = (var_A · n_A + var_B · n_B + δ² · n_A · n_B / n) / n

so any split of the data into batches gives its mean and (population) variance. The statistics
start as SB3's: mean 0, variance 1, count 1e-4 (a prior of a tenth of a thousandth of a sample, which
keeps the first merge's division finite and weighs nothing once data has come in).

Rewards are scaled, not centred: divided by the standard deviation of the running discounted return
``R_t = γ · R_{t−1} + r_t`` (reset to 0 after each episode's last step), which
:func:`discounted_returns` computes along a rollout, as SB3's ``VecNormalize`` does step by step.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

EPSILON = 1e-8
"""added to the variance before its square root (SB3's and Gymnasium's)"""
INITIAL_COUNT = 1e-4
"""the count of the initial statistics (mean 0, variance 1), SB3's ``RunningMeanStd(epsilon=1e-4)``"""


@struct.dataclass
class RunningMeanStd:
    """The mean and variance of everything seen so far, per element of one sample's shape."""

    mean: jax.Array  # float32 [*shape]
    var: jax.Array  # float32 [*shape]
    count: jax.Array  # float32 []


def init(shape: tuple[int, ...] = ()) -> RunningMeanStd:
    """Statistics of samples of ``shape`` before any data: mean 0, variance 1, count 1e-4."""
    return RunningMeanStd(
        jnp.zeros(shape, jnp.float32), jnp.ones(shape, jnp.float32), jnp.float32(INITIAL_COUNT)
    )


def update(stats: RunningMeanStd, batch: jax.Array, mask: jax.Array | None = None) -> RunningMeanStd:
    """``stats`` with the samples ``batch [N, *shape]`` merged in (Chan et al.'s parallel update);
    with ``mask`` (bool ``[N]``) only the samples it marks (an all-False mask leaves ``stats`` as is)."""
    batch = batch.astype(jnp.float32)
    if batch.shape[1:] != stats.mean.shape:
        raise ValueError(f"a batch of samples {batch.shape[1:]} for statistics of {stats.mean.shape}")
    if mask is None:
        batch_count = jnp.float32(batch.shape[0])
        batch_mean, batch_var = batch.mean(axis=0), batch.var(axis=0)
    else:
        weight = mask.astype(jnp.float32).reshape(-1, *(1,) * (batch.ndim - 1))  # (N, 1, ...)
        batch_count = weight.sum()
        denominator = jnp.maximum(batch_count, 1.0)
        batch_mean = (weight * batch).sum(axis=0) / denominator
        batch_var = (weight * (batch - batch_mean) ** 2).sum(axis=0) / denominator
    delta = batch_mean - stats.mean
    count = stats.count + batch_count
    mean = stats.mean + delta * batch_count / count
    m2 = stats.var * stats.count + batch_var * batch_count + delta**2 * stats.count * batch_count / count
    return RunningMeanStd(mean, m2 / count, count)


def normalize(stats: RunningMeanStd, x: jax.Array, clip: float | jax.Array = 10.0) -> jax.Array:
    """``x`` standardised, ``(x − mean) / sqrt(var + 1e-8)``, clipped to ``[−clip, clip]``; ``x`` has
    the statistics' shape or leading axes more."""
    standardized = (x.astype(jnp.float32) - stats.mean) / jnp.sqrt(stats.var + EPSILON)
    return jnp.clip(standardized, -clip, clip)


def scale(stats: RunningMeanStd, x: jax.Array, clip: float | jax.Array = 10.0) -> jax.Array:
    """``x / sqrt(var + 1e-8)`` clipped to ``[−clip, clip]``, not centred (SB3's reward normalisation)."""
    return jnp.clip(x.astype(jnp.float32) / jnp.sqrt(stats.var + EPSILON), -clip, clip)


def discounted_returns(
    return_tm1: jax.Array, reward_t: jax.Array, done_t: jax.Array, discount: float | jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The running discounted return along a time-major rollout: ``(return after the last step [E],
    returns [T, E])`` from the return carried in ``return_tm1 [E]`` and ``reward_t``, ``done_t``
    ``[T, E]``::

        R_t = γ · R_{t−1} + r_t     (the return the reward of step t is scaled by)
        R_t ← 0 where done_t        (the next episode starts from nothing)

    SB3's ``VecNormalize``: ``returns = returns * gamma + reward``, then ``returns[dones] = 0``.
    """

    def step(return_tm1, reward_and_done):
        reward, done = reward_and_done
        return_t = discount * return_tm1 + reward
        return jnp.where(done, 0.0, return_t), return_t

    return jax.lax.scan(step, return_tm1.astype(jnp.float32), (reward_t.astype(jnp.float32), done_t))
