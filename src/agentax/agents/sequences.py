"""What the agents with a recurrent core share (PPO and PQN; REINFORCE, learning on whole episodes,
the core's kind and size): the core's settings checked once, and a rollout ``[T, E, ...]`` cut into
whole env sequences, each with the memory stored where it starts, for backpropagation through time.

A rollout of ``num_steps`` steps per env is learned on as sequences of ``bptt`` steps (or the whole
rollout): minibatches are made of whole sequences, never of shuffled steps, so the core runs
through each from its stored memory (R2D2's stored state; PureJaxRL's ``ppo_rnn`` with the whole
rollout). A block beside the algorithms, not an algorithm: no algorithm imports another.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from agentax.agents.protocol import EnvSpec, check_fields, image_shape_for
from agentax.errors import UsageError
from agentax.nets import CORES, Memory, is_image, zero_memory


def sequence_length(cfg: Any) -> int:
    """Steps of each sequence the core learns on: ``cfg.bptt``, or the whole rollout of ``num_steps``."""
    return cfg.bptt or cfg.num_steps


def num_sequences(cfg: Any) -> int:
    """The sequences of one rollout: ``num_envs × num_steps / sequence_length``."""
    return cfg.num_envs * (cfg.num_steps // sequence_length(cfg))


def initial_memory(cfg: Any, batch_shape: tuple[int, ...] = ()) -> Memory:
    """The core ``cfg.core``'s memory at an episode's start, zeros ``[*batch_shape, cfg.core_size]``
    (LSTM: a pair)."""
    return zero_memory(cfg.core, cfg.core_size, batch_shape)


def recurrent_net_fields(cfg: Any, spec: EnvSpec, conv: str) -> dict[str, Any]:
    """What a recurrent network (:class:`~agentax.nets.RecurrentActorCritic`,
    :class:`~agentax.nets.RecurrentQNetwork`) takes from ``cfg`` and ``spec`` besides its heads:
    the torso (the MLP of ``cfg.hidden`` or the CNN of the image), the core and the convolution backend."""
    return {
        "hidden": tuple(cfg.hidden),
        "activation": cfg.activation,
        "core": cfg.core,
        "core_size": cfg.core_size,
        "cnn": is_image(spec.obs_shape),
        "image_shape": image_shape_for(cfg.conv_torso, spec),
        "conv": conv,
    }


def validate_core_kind(cfg: Any) -> None:
    """A known ``cfg.core`` and a positive ``cfg.core_size`` (a ``UsageError`` otherwise)."""
    if cfg.core not in CORES:
        raise UsageError(f"unknown core {cfg.core!r}; choose from {', '.join(CORES)}")
    check_fields(cfg, positive=("core_size",))


def validate_core(cfg: Any) -> None:
    """The core's settings of a config with ``core``, ``core_size``, ``bptt``, ``num_envs``,
    ``num_steps`` and ``num_minibatches``: a known core, a positive size, sequences that split the
    rollout and minibatches of whole sequences (a ``UsageError`` naming the first bad one)."""
    validate_core_kind(cfg)
    check_fields(cfg, non_negative=("bptt",))
    if cfg.bptt and cfg.num_steps % cfg.bptt:
        raise UsageError(f"--bptt {cfg.bptt} does not split num_steps {cfg.num_steps} into sequences")
    if num_sequences(cfg) % cfg.num_minibatches:
        raise UsageError(
            f"the {num_sequences(cfg)} sequences of a rollout (num_envs × num_steps / bptt) do not split "
            f"into {cfg.num_minibatches} minibatches of whole sequences; lower --num-minibatches"
        )


def as_sequences(x: jax.Array, length: int) -> jax.Array:
    """A rollout's ``[T, E, ...]`` cut into ``N = E·T/length`` sequences ``[N, length, ...]``,
    sequence ``k·E + e`` being env ``e``'s steps ``k·length ... (k + 1)·length − 1``."""
    steps, envs = x.shape[:2]
    chunks = x.reshape(steps // length, length, envs, *x.shape[2:])  # (T/length, length, E, ...)
    return jnp.moveaxis(chunks, 2, 1).reshape(-1, length, *x.shape[2:])


def sequence_starts(stored: Memory, length: int) -> Memory:
    """The memory each sequence of :func:`as_sequences` starts from, ``[N, ...]``, of the memory
    every step received ``[T, E, ...]`` (``info["memory"]``)."""
    return jax.tree.map(lambda m: m[::length].reshape(-1, *m.shape[2:]), stored)


def whole_sequences(steps: dict[str, jax.Array], stored: Memory, length: int) -> dict[str, Any]:
    """What a learner's minibatches are cut from: each of ``steps``' leaves ``[T, E, ...]`` as
    sequences ``[N, length, ...]``, and under ``"memory"`` the memory each starts from ``[N, ...]``."""
    data: dict[str, Any] = jax.tree.map(lambda x: as_sequences(x, length), steps)
    data["memory"] = sequence_starts(stored, length)
    return data


def time_major(batch: dict[str, Any]) -> dict[str, jax.Array]:
    """A minibatch of sequences ``[B, L, ...]`` time first ``[L, B, ...]``, its ``"memory"`` left out
    (the core's start, ``[B, ...]``, read apart)."""
    return {k: jnp.swapaxes(v, 0, 1) for k, v in batch.items() if k != "memory"}


__all__ = [
    "as_sequences",
    "num_sequences",
    "sequence_length",
    "sequence_starts",
    "time_major",
    "validate_core",
    "validate_core_kind",
    "whole_sequences",
]
