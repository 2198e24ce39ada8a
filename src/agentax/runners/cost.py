"""What a compiled program costs: the floating-point operations of one seed's whole training from
XLA's cost analysis, every loop's trip count put back (:func:`flops`), which decide whether its
seeds are worth spreading over the cores (:func:`agentax.runners.workers.default_for`).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import jax
from jax.extend import core


def xla_flops(closed: core.ClosedJaxpr) -> float:
    """XLA's count of the flops of ``closed`` (lowered, not compiled; each loop body counted once)."""
    args = [jax.ShapeDtypeStruct(v.aval.shape, v.aval.dtype) for v in closed.jaxpr.invars]
    lowered = jax.jit(core.jaxpr_as_fun(closed)).lower(*args)
    return float(lowered.cost_analysis().get("flops", 0.0))


def _inner(eqn: Any) -> Iterator[core.ClosedJaxpr]:
    """The jaxprs an equation holds (a call's, a conditional's branches, a custom derivative's)."""
    for value in eqn.params.values():
        for item in value if isinstance(value, tuple | list) else (value,):
            if isinstance(item, core.ClosedJaxpr):
                yield item
            elif isinstance(item, core.Jaxpr):
                yield core.ClosedJaxpr(item, ())


def outer_scans(jaxpr: core.Jaxpr) -> Iterator[tuple[int, core.ClosedJaxpr]]:
    """``(length, body)`` of every scan of ``jaxpr`` not inside another scan of it."""
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "scan":
            yield eqn.params["length"], eqn.params["jaxpr"]
        else:
            for inner in _inner(eqn):
                yield from outer_scans(inner.jaxpr)


def flops(closed: core.ClosedJaxpr) -> float:
    """The floating-point operations of ``closed`` with every scan's trip count: XLA's count, plus
    ``length · flops(body) − xla_flops(body)`` for each outermost scan (a ``while`` loop, whose trip
    count is unknown, stays counted once)."""
    total = xla_flops(closed)
    for length, body in outer_scans(closed.jaxpr):
        total += length * flops(body) - xla_flops(body)
    return total


def program_flops(program: Any) -> float:
    """One seed's whole training (an :class:`agentax.runners.rollout.Program`): ``num_updates``
    times the flops of one ``update`` (traced at ``init``'s shapes, nothing run or compiled)."""
    carry = jax.eval_shape(program.init, jax.random.key(0))
    return program.num_updates * flops(jax.make_jaxpr(program.update)(carry))
