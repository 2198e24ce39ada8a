"""Hyperparameters as an axis of the compiled program: a sweep's settings × seeds in one vmap.

:func:`sweep_program` makes a program whose agent ``i`` (its position on the runner's seed axis)
builds its agent from the config with row ``i`` of a table of values in place, *traced*
(:func:`with_values`), so one compiled program trains every setting. A value that sets a shape or a
branch needs a program of its own: :func:`traceable` tells which is which by tracing.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from agentax.runners.rollout import SEED_AXIS, Program


def with_values(cfg: Any, values: dict[str, Any]) -> Any:
    """A copy of the frozen config ``cfg`` with ``values`` in place, without validating them again
    (traced values cannot be compared; every concrete setting was validated before)."""
    changed = copy.copy(cfg)
    for name, value in values.items():
        object.__setattr__(changed, name, value)
    return changed


@struct.dataclass
class SweepCarry:
    """One agent of a sweep: its setting (scalars) and the carry of its own program."""

    values: dict[str, jax.Array]
    inner: Any

    @property
    def episodes(self):  # what the runner reads for its rows
        return self.inner.episodes


def sweep_program(make_program: Callable[[Any], Program], cfg: Any, table: dict[str, np.ndarray]) -> Program:
    """The program of a sweep: ``make_program(config) -> Program`` for one agent, ``cfg`` the
    config every setting shares, ``table`` one column ``[agents]`` per traced name (float32)."""
    base = make_program(cfg)
    columns = {name: jnp.asarray(column, jnp.float32) for name, column in table.items()}

    def program_of(values: dict[str, jax.Array]) -> Program:
        return make_program(with_values(cfg, values))

    def init(key: jax.Array) -> SweepCarry:
        agent = jax.lax.axis_index(SEED_AXIS)
        values = {name: column[agent] for name, column in columns.items()}
        return SweepCarry(values, program_of(values).init(key))

    def update(carry: SweepCarry) -> tuple[SweepCarry, dict[str, jax.Array]]:
        inner, metrics = program_of(carry.values).update(carry.inner)
        return carry.replace(inner=inner), metrics

    def greedy_policy(carry: SweepCarry):
        return program_of(carry.values).greedy_policy(carry.inner)

    return Program(init, update, base.num_updates, base.steps_per_update, greedy_policy)


def traceable(make_program: Callable[[Any], Program], cfg: Any, name: str) -> bool:
    """Whether ``name``, a float field of ``cfg``, can be a traced value of one program (tracing
    one update with it traced, nothing run)."""
    if not isinstance(getattr(cfg, name), float):
        return False
    program = sweep_program(make_program, cfg, {name: np.full(1, getattr(cfg, name), np.float32)})
    init = jax.vmap(program.init, axis_name=SEED_AXIS)
    try:
        carry = jax.eval_shape(init, jax.random.split(jax.random.key(0), 1))
        jax.eval_shape(jax.vmap(program.update, axis_name=SEED_AXIS), carry)
    except (TypeError, ValueError, jax.errors.UnexpectedTracerError):  # a shape, a branch, static data
        return False
    return True


def float_fields(cfg: Any) -> list[str]:
    """The fields of ``cfg`` holding a float (the candidates for tracing)."""
    return [f.name for f in dataclasses.fields(cfg) if type(getattr(cfg, f.name)) is float]
