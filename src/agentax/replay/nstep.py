"""The n-step accumulator: turns a stream of one-step transitions into n-step transitions.

It keeps the last ``n`` one-step transitions of each env in a window ``[n, num_envs]``; once the
window is full, every push emits the n-step transition that starts at its oldest entry::

    reward     = r_0 + γ r_1 + … + γ^(k−1) r_(k−1)
    next_obs   = the observation reached after step k − 1
    num_steps  = k            (k = n, or fewer if the episode ended inside the window)

so a learner bootstraps with ``γ^k · max_a Q(next_obs, a)`` unless the k-th step ``terminated``
(a truncation still bootstraps, from the observation it really reached). Each transition is emitted
exactly once, n − 1 pushes after it arrived. With ``n = 1`` it is the identity.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from agentax.replay.core import Transition
from agentax.returns import n_step_return


@struct.dataclass
class NStepState:
    window: Transition  # one-step transitions, fields [n, num_envs, ...], oldest first
    count: jax.Array  # int32 []: pushes so far (the window is full once count >= n)


def init(n: int, example_batch: Transition) -> NStepState:
    """An empty window of ``n`` steps for transitions shaped like ``example_batch`` ``[num_envs, ...]``."""
    if n < 1:
        raise ValueError(f"n-step returns need n >= 1, got {n}")
    window = jax.tree.map(lambda x: jnp.zeros((n, *x.shape), x.dtype), example_batch)
    return NStepState(window=window, count=jnp.int32(0))


def _n_step_transition(window: Transition, discount_factor: float) -> Transition:
    """The n-step transition starting at the oldest entry of one env's window (fields ``[n, ...]``)."""
    reward, num_steps = n_step_return(window.reward, window.terminated, window.truncated, discount_factor)
    last = num_steps - 1
    return Transition(
        obs=window.obs[0],
        action=window.action[0],
        reward=reward,
        next_obs=window.next_obs[last],
        terminated=window.terminated[last],
        truncated=window.truncated[last],
        num_steps=num_steps,
    )


def push(
    state: NStepState, batch: Transition, discount_factor: float
) -> tuple[NStepState, Transition, jax.Array]:
    """Push one-step ``batch`` ``[num_envs]``; returns the new state, the n-step transitions
    ``[num_envs]`` that start ``n − 1`` steps back, and whether they are real (the window was full)."""
    window = jax.tree.map(lambda w, x: jnp.concatenate([w[1:], x[None]], axis=0), state.window, batch)
    count = state.count + 1
    n = state.window.reward.shape[0]
    emitted = jax.vmap(_n_step_transition, in_axes=(1, None))(window, discount_factor)
    return NStepState(window=window, count=count), emitted, count >= n
