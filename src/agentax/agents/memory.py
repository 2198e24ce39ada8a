"""The memory one learning step takes, refused up front where the machine has less (a one-line
``UsageError`` instead of XLA's ``RESOURCE_EXHAUSTED`` traceback mid-run).

What ``agent.learn`` receives is sized by the agent's settings: a replay sample of ``batch_size``
transitions (DQN, SAC, TD3), a rollout of ``num_envs × num_steps`` steps (PPO, PQN: its minibatches
are slices of it) or ``num_envs`` episodes of ``max_steps`` (REINFORCE). The estimate traces
``learn`` on abstract arrays of those shapes (``jax.make_jaxpr``: nothing compiled, nothing run) and
counts the experience and the outputs of its matrix products and convolutions, the activations a
backward pass keeps. Measured against XLA's own ``memory_analysis`` of the compiled step (its
arguments and temporaries), it lies within half to twice what XLA allocates (SAC at batch 10^6 1.7x,
DQN 1.3x, PPO 2x, REINFORCE and the Nature-CNN DQN 0.6x). Rejected: compiling ``learn`` to ask XLA
(seconds a run), and a formula per network (a new torso would go uncounted). It costs a trace,
0.1-0.6 s a run here.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp

from agentax.agents.protocol import Agent, EnvSpec, Episodes, OffPolicy
from agentax.errors import UsageError
from agentax.replay import ReplaySample, Transition
from agentax.replay.frames import available_memory

ACTIVATIONS = ("dot_general", "conv_general_dilated")
"""The primitives whose outputs a learning step keeps for its backward pass."""


def abstract(shape: tuple[int, ...], dtype: Any) -> jax.ShapeDtypeStruct:
    """An array of this shape and dtype, without its values."""
    return jax.ShapeDtypeStruct(tuple(shape), jnp.dtype(dtype))


def transition_shaped(lead: tuple[int, ...], spec: EnvSpec, action: Any, info: Any) -> Transition:
    """An abstract :class:`Transition` with leading axes ``lead``: ``action`` and ``info`` hold one
    step's (one env's action, ``info`` as given), the rest follows ``spec``."""
    obs = abstract((*lead, *spec.obs_shape), spec.obs_dtype)
    return Transition(
        obs=obs,
        action=abstract((*lead, *action.shape), action.dtype),
        reward=abstract(lead, jnp.float32),
        next_obs=obs,
        terminated=abstract(lead, bool),
        truncated=abstract(lead, bool),
        num_steps=abstract(lead, jnp.int32),
        info=info,
    )


def a_key() -> jax.ShapeDtypeStruct:
    """A random key, abstract (a concrete one would make jax's CPU client before the runner chose how)."""
    return jax.eval_shape(lambda: jax.random.key(0))


def learn_input(agent: Agent, spec: EnvSpec) -> tuple[Any, Any]:
    """``(state, experience)``, abstract: what one ``agent.learn`` call receives for its settings."""
    state = jax.eval_shape(agent.init, a_key())
    experience = agent.experience
    obs = abstract((experience.num_envs, *spec.obs_shape), spec.obs_dtype)
    if agent.recurrent is None:
        action, info = jax.eval_shape(agent.act, state, obs, a_key(), abstract((), jnp.int32))
    else:
        memory = jax.eval_shape(lambda: agent.recurrent.initial(experience.num_envs))
        first = abstract((experience.num_envs,), bool)
        _, action, info = jax.eval_shape(
            agent.recurrent.act, state, memory, obs, first, a_key(), abstract((), jnp.int32)
        )
    one_action = abstract(
        action.shape[1:], jnp.float32 if jnp.issubdtype(action.dtype, jnp.floating) else jnp.int32
    )
    if isinstance(experience, OffPolicy):
        batch = experience.batch_size
        transition = transition_shaped((batch,), spec, one_action, None)
        return state, ReplaySample(transition, abstract((batch,), jnp.int32), abstract((batch,), jnp.float32))
    steps = experience.max_steps if isinstance(experience, Episodes) else experience.num_steps
    info = jax.tree.map(lambda x: abstract((steps, *x.shape), x.dtype), info)
    if isinstance(experience, Episodes):
        info = {**info, "valid": abstract((steps, experience.num_envs), bool)}
    return state, transition_shaped(
        (steps, experience.num_envs), spec, abstract(action.shape[1:], action.dtype), info
    )


def nbytes(aval: Any) -> int:
    """The bytes of an abstract array (0 for what is none)."""
    return math.prod(aval.shape) * jnp.dtype(aval.dtype).itemsize if hasattr(aval, "shape") else 0


def activation_bytes(jaxpr: jax.extend.core.Jaxpr) -> int:
    """The bytes of every matrix product's and convolution's output in ``jaxpr`` and the jaxprs inside
    it (a loop's body once: its iterations reuse the buffers)."""
    total = 0
    for eqn in jaxpr.eqns:
        if eqn.primitive.name in ACTIVATIONS:
            total += sum(nbytes(var.aval) for var in eqn.outvars)
        for param in eqn.params.values():
            for inner in param if isinstance(param, tuple | list) else (param,):
                inner = getattr(inner, "jaxpr", inner)
                if hasattr(inner, "eqns"):
                    total += activation_bytes(inner)
    return total


def learning_bytes(agent: Agent, spec: EnvSpec) -> int:
    """About the bytes one ``agent.learn`` call holds at once: its experience and its activations
    (the experience alone where it has more rows than int32 indexes reach, which ``learn`` cannot trace)."""
    state, experience = learn_input(agent, spec)
    held = sum(nbytes(x) for x in jax.tree.leaves(experience))
    try:
        closed = jax.make_jaxpr(agent.learn)(state, experience, a_key())
    except OverflowError:
        return held
    return held + activation_bytes(closed.jaxpr)


def sized_by(agent: Agent) -> tuple[str, int, str]:
    """The setting that sizes a learning step as its flags read, the count it gives, and of what."""
    experience = agent.experience
    if isinstance(experience, OffPolicy):
        return f"--batch-size {experience.batch_size:,}", experience.batch_size, "transitions"
    if isinstance(experience, Episodes):
        flags = f"--episodes-per-update {experience.num_envs:,} × --max-steps {experience.max_steps:,}"
        return flags, experience.num_envs * experience.max_steps, "steps"
    flags = f"--num-envs {experience.num_envs:,} × --num-steps {experience.num_steps:,}"
    return flags, experience.num_envs * experience.num_steps, "steps"


def check_learning_fits(agent: Agent, spec: EnvSpec, seeds: int = 1) -> None:
    """A ``UsageError`` naming the setting, the bytes and the memory available when one learning step
    needs more memory than this machine has: the setting that sizes it (one seed's step already too
    big), else ``--seeds`` (the step of every seed vmapped side by side).

    ``agent`` as ``make_agent(spec, cfg)`` makes it, not with the runner's loop: that loop asks jax
    for its backend while it traces, which would make jax's CPU client before the runner chose how
    (:func:`agentax._xla.let_xla_use_every_cpu`); the memory is the same."""
    have = available_memory()
    if have is None:
        return
    one = learning_bytes(agent, spec)
    if one > have:
        setting, count, unit = sized_by(agent)
        raise UsageError(
            f"{setting} needs about {one / 1e9:,.1f} GB for one learning step ({one / count:,.0f} bytes per "
            f"{unit[:-1]}), but only {have / 1e9:.1f} GB of memory is available; lower it to about "
            f"{int(have * count // one):,} {unit} at most"
        )
    check_seeds_fit(seeds, one, "their learning steps side by side")


def check_seeds_fit(seeds: int, per_seed: int, what: str, agents: int | None = None) -> None:
    """A ``UsageError`` naming ``--seeds`` and how many fit when ``agents`` (default: ``seeds``; a
    sweep's settings × seeds) need more memory than is available, ``per_seed`` bytes each for ``what``."""
    have, need = available_memory(), per_seed * (seeds if agents is None else agents)
    if have is not None and need > have:
        raise UsageError(
            f"--seeds {seeds:,} needs about {need / 1e9:,.1f} GB for {what} ({per_seed:,} bytes a seed), but "
            f"only {have / 1e9:.1f} GB of memory is available; at most about {have // per_seed:,} seeds fit"
        )
