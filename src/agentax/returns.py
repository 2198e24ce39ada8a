"""Discounting, normalisation, GAE(λ), Q(λ) and n-step targets: pure functions on arrays.

Two families. The lecture's host forms work on one episode's rewards (or a ragged list of
episodes): ``discount_rewards([10, 0, -50], 0.8) == [-22, -40, -50]``. The masked, time-major forms
serve the compiled runner, where a rollout ``[T, ...]`` crosses episode boundaries: a reverse
``lax.scan`` carries the return back in time and ``done`` masks cut it where an episode ended.

Bootstrapping follows DESIGN.md: a time-limit truncation bootstraps from the value of the
observation really reached (``final_obs``), a termination does not.

:class:`EpisodeStats` is the bookkeeping of the episodes that finish inside a compiled rollout,
which the runner reads to log the mean return.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


def discount_rewards(rewards: Sequence[float] | np.ndarray, discount_factor: float) -> np.ndarray:
    """Discounted return of every step of one episode: ``G_t = r_t + discount_factor * G_{t+1}``.

    The lecture's example: rewards [10, 0, -50] with discount factor 0.8 give [-22, -40, -50].
    """
    rewards = np.asarray(rewards, np.float64)
    returns = np.empty_like(rewards)
    future = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        future = rewards[t] + discount_factor * future
        returns[t] = future
    return returns


def discount_and_normalize_rewards(
    all_rewards: Sequence[Sequence[float]], discount_factor: float
) -> list[np.ndarray]:
    """Discount each episode's rewards, then normalise with the mean and std over all episodes together.

    As in the lecture: the normalised returns are the advantages of REINFORCE, so actions better
    than average across the whole batch of episodes get a positive weight.
    """
    all_discounted = [discount_rewards(rewards, discount_factor) for rewards in all_rewards]
    flat = np.concatenate(all_discounted)
    mean, std = flat.mean(), flat.std()
    return [(discounted - mean) / std for discounted in all_discounted]


def discounted_returns(rewards: jax.Array, discounts: jax.Array, bootstrap: jax.Array) -> jax.Array:
    """``G_t = r_t + discount_t * G_{t+1}`` over a time-major rollout, from ``G_T = bootstrap``.

    rewards, discounts: ``[T, ...]``; bootstrap: ``[...]`` (the value after the last step, or 0).
    ``discount_t = discount_factor * (1 - done_t)`` cuts the return where an episode ended.
    """

    def step(future, reward_and_discount):
        reward_t, discount_t = reward_and_discount
        future = reward_t + discount_t * future
        return future, future

    _, returns = jax.lax.scan(step, bootstrap, (rewards, discounts), reverse=True)
    return returns


def masked_mean(x: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    """The mean of ``x`` over the entries where ``mask`` holds (all if None; 0 if none holds)."""
    if mask is None:
        return x.mean()
    mask = mask.astype(x.dtype)
    return (x * mask).sum() / jnp.maximum(mask.sum(), 1.0)


def normalize(x: jax.Array, mask: jax.Array | None = None, eps: float = 1e-8) -> jax.Array:
    """``(x - mean) / (std + eps)`` over the entries where ``mask`` holds (all if None)."""
    if mask is None:
        return (x - x.mean()) / (x.std() + eps)
    mask = mask.astype(x.dtype)
    count = jnp.maximum(mask.sum(), 1.0)
    mean = (x * mask).sum() / count
    std = jnp.sqrt((((x - mean) * mask) ** 2).sum() / count)
    return (x - mean) / (std + eps)


def gae(
    rewards: jax.Array,
    values: jax.Array,
    next_values: jax.Array,
    terminated: jax.Array,
    done: jax.Array,
    discount_factor: float | jax.Array,
    gae_lambda: float | jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimation (Schulman et al. 2016); returns ``(advantages, lambda_returns)``.

    All arrays time-major ``[T, ...]``. ``values[t] = V(s_t)``; ``next_values[t]`` is the value of
    the observation step t really reached (``V(final_obs_t)``), so a truncated step bootstraps from
    it. ``terminated`` zeroes the bootstrap; ``done`` (terminated or truncated) stops the λ-trace
    from flowing into the next episode::

        delta_t = r_t + discount_factor * (1 - terminated_t) * next_values_t - values_t
        A_t     = delta_t + discount_factor * gae_lambda * (1 - done_t) * A_{t+1}
    """
    not_terminated = 1.0 - terminated.astype(values.dtype)
    not_done = 1.0 - done.astype(values.dtype)
    deltas = rewards + discount_factor * not_terminated * next_values - values
    advantages = discounted_returns(
        deltas, discount_factor * gae_lambda * not_done, jnp.zeros_like(values[0])
    )
    return advantages, advantages + values


def q_lambda_returns(
    rewards: jax.Array,
    next_q: jax.Array,
    terminated: jax.Array,
    done: jax.Array,
    discount_factor: float | jax.Array,
    q_lambda: float | jax.Array,
) -> jax.Array:
    """Peng's Q(λ) targets over a rollout, as PQN learns from them (Gallici et al., 2025): ``[T, ...]``.

    ``next_q[t] = max_a Q(s'_t, a)`` of the observation step t really reached (its final
    observation at a truncation, so a truncated step bootstraps from it); ``terminated`` zeroes the
    bootstrap, ``done`` (terminated or truncated) keeps the λ-trace inside the episode, and the last
    step bootstraps from its own ``next_q``::

        G_t = r_t + γ (1 − terminated_t) [q'_t + λ (1 − done_t) (G_{t+1} − q'_t)],   G_T = q'_{T−1}

    λ = 0 gives one-step Q-learning targets, λ = 1 the Monte-Carlo return within each episode.
    Since (1 − terminated)(1 − done) = 1 − done, this is a discounted return of
    ``r_t + γ (1 − terminated_t)(1 − λ (1 − done_t)) q'_t`` with discount ``γ λ (1 − done_t)``.
    """
    not_terminated = 1.0 - terminated.astype(next_q.dtype)
    not_done = 1.0 - done.astype(next_q.dtype)
    one_step = rewards + discount_factor * not_terminated * (1.0 - q_lambda * not_done) * next_q
    return discounted_returns(one_step, discount_factor * q_lambda * not_done, next_q[-1])


def n_step_return(
    reward: jax.Array, terminated: jax.Array, truncated: jax.Array, discount_factor: float
) -> tuple[jax.Array, jax.Array]:
    """The n-step return of a window of ``n`` consecutive steps of one env, and its length ``k``.

    ``r_0 + γ r_1 + … + γ^(k−1) r_(k−1)``, summed up to and including the first step whose episode
    ended (``k = n`` if none did): the return DQN bootstraps from with ``γ^k`` (unless that step
    terminated). ``reward``, ``terminated``, ``truncated``: ``[n]``. Vmap over envs.
    """
    done = jnp.logical_or(terminated, truncated)
    ended_before = jnp.cumsum(done) - done  # [n]: an episode ended strictly before step i
    alive = ended_before == 0
    discount = discount_factor ** jnp.arange(reward.shape[0], dtype=jnp.float32)
    return jnp.sum(alive * discount * reward), jnp.sum(alive).astype(jnp.int32)


def bootstrap_discount(terminated: jax.Array, num_steps: jax.Array, discount_factor: float) -> jax.Array:
    """``γ^k · (1 − terminated)`` ``[batch]`` for transitions of ``k = num_steps`` steps (replay's
    n-step ones): the weight of the bootstrap value in ``r + γ^k (1 − terminated) V(s′)``. A truncated
    transition bootstraps, a terminated one does not."""
    return (discount_factor ** num_steps.astype(jnp.float32)) * (1.0 - terminated)


@struct.dataclass
class EpisodeStats:
    """Returns of the episodes of ``num_envs`` envs, updated step by step inside ``jit``.

    The compiled runner reads ``completed`` and ``return_sum`` before and after a chunk of updates:
    their differences give the mean return of the episodes finished in the chunk.
    """

    episode_return: jax.Array  # [num_envs] return so far of the running episode
    last_return: jax.Array  # [num_envs] return of each env's last finished episode
    completed: jax.Array  # [] int32 episodes finished so far
    return_sum: jax.Array  # [] float32 sum of the returns of the finished episodes
    env_steps: jax.Array  # [] int32 env steps taken so far

    @classmethod
    def create(cls, num_envs: int) -> EpisodeStats:
        """No episode yet (each field its own buffer, so a jitted call may donate them)."""
        episode_return, last_return = jnp.zeros(num_envs, jnp.float32), jnp.zeros(num_envs, jnp.float32)
        return cls(episode_return, last_return, jnp.int32(0), jnp.float32(0), jnp.int32(0))

    def record(self, reward: jax.Array, done: jax.Array, valid: jax.Array | None = None) -> EpisodeStats:
        """Add one step of each env (``reward``, ``done``: ``[num_envs]``); ``valid`` masks skipped steps."""
        valid = jnp.ones_like(done) if valid is None else valid
        episode_return = self.episode_return + reward * valid
        finished = done & valid
        return EpisodeStats(
            episode_return=jnp.where(finished, 0.0, episode_return),
            last_return=jnp.where(finished, episode_return, self.last_return),
            completed=self.completed + finished.sum(dtype=jnp.int32),
            return_sum=self.return_sum + jnp.where(finished, episode_return, 0.0).sum(),
            env_steps=self.env_steps + valid.sum(dtype=jnp.int32),
        )
