"""The compiled runner's programs: built from an agent's program, and kept on disk.

:func:`build` makes the two programs of a run, vmapped over seeds: ``init`` and the ``chunk`` that
scans ``updates_per_chunk`` updates and then evaluates the greedy policy when asked (on keys of the
evaluation-seed rule, :data:`agentax.runners.session.EVAL_KEY_OFFSET`), both taking and giving the
carry as the flat list of its arrays. :func:`jit` keeps a lowered program (``jax.export``'s
serialized StableHLO, never a pickle) under a fingerprint of everything that shapes it, so a
repeated run calls it without tracing; anything that fails to load or export is traced as usual.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import export

from agentax import _xla, kernel_choice, kernels
from agentax.envs.core import Environment, episode_returns
from agentax.runners.rollout import SEED_AXIS, Program
from agentax.runners.session import EVAL_KEY_OFFSET
from agentax.runs import write_atomic

INIT_COMPILER_OPTIONS = {"xla_backend_optimization_level": 0}
CHUNK_COMPILER_OPTIONS = {"xla_backend_optimization_level": 1}
"""LLVM optimisation levels of the two programs (XLA's default is 3): the one-off ``init`` compiles
fastest at 0, the chunk at 1 compiles faster than at 3 and runs as fast (docs/design.md)."""


KEEP = 256
"""Programs kept: past this many, the least recently used go (each is ~0.1-1 MB)."""


@functools.cache
def source_digest() -> str:
    """A hash of every agentax source file: any edit gives new fingerprints."""
    package = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        digest.update(str(path.relative_to(package)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def fingerprint(description: dict[str, Any], example_args: Any) -> str:
    """The name of a program: its description, argument shapes, jax and agentax's source, hashed."""
    shapes = [f"{x.dtype}{list(x.shape)}" for x in jax.tree.leaves(jax.eval_shape(lambda a: a, example_args))]
    payload = {
        "description": description,
        "shapes": shapes,
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "x64": bool(jax.config.jax_enable_x64),
        "agentax": source_digest(),
        "conv": kernel_choice.known_backend(),  # XLA's convolutions or oneDNN's: another program
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:32]


def jit(
    fn: Callable,
    example_args: Sequence[Any],
    description: dict[str, Any] | None,
    donate_argnums: int | tuple[int, ...] = (),
) -> Callable:
    """``jax.jit(fn)``, or where ``description`` names it (and the cache is on) the stored lowering of
    ``fn`` at ``example_args`` (which may hold ``jax.ShapeDtypeStruct`` leaves)."""
    root = _xla.compilation_cache_dir()  # None when that cache is off
    if description is None or root is None:
        return jax.jit(fn, donate_argnums=donate_argnums)
    directory = root / "agentax-programs"  # beside the compiled programs
    name = f"{description.get('name', 'program')}-{fingerprint(description, example_args)}"
    path = directory / f"{name}.jaxexport"
    exported = None
    if path.is_file():
        try:
            exported = export.deserialize(bytearray(path.read_bytes()))
            os.utime(path)  # recently used: kept longest
        except Exception:  # a damaged or foreign file: trace afresh and replace it
            path.unlink(missing_ok=True)
    if exported is None:
        try:
            # oneDNN's convolutions are custom calls, allowed here: kernels registers them first
            allowed = [export.DisabledSafetyCheck.custom_call(target) for target in kernels.TARGETS]
            exported = export.export(jax.jit(fn), disabled_checks=allowed)(*example_args)
        except Exception:  # not exportable (e.g. a custom pytree in the results): just trace
            return jax.jit(fn, donate_argnums=donate_argnums)
        try:
            directory.mkdir(parents=True, exist_ok=True)
            write_atomic(path, bytes(exported.serialize()))
            stored = sorted(directory.glob("*.jaxexport"), key=lambda kept: kept.stat().st_mtime)
            for oldest in stored[:-KEEP]:
                oldest.unlink(missing_ok=True)
        except (OSError, ImportError):  # a read-only cache, or no flatbuffers: use it, unsaved
            pass
    return jax.jit(exported.call, donate_argnums=donate_argnums)


def init_from_seeds(algorithm: Program) -> Callable[[jax.Array], Any]:
    """``seeds [S] -> carry`` with a leading seed axis: ``algorithm.init(jax.random.key(seed))`` each."""
    return jax.vmap(lambda seed: algorithm.init(jax.random.key(seed)), axis_name=SEED_AXIS)


def make_chunk(algorithm: Program, env: Environment, updates_per_chunk: int, eval_episodes: int):
    """One seed's ``chunk(state, num_active, do_eval, seed_key, evaluation) -> (state, metrics, returns,
    lengths)``: the first ``num_active`` of ``updates_per_chunk`` updates kept, ``metrics`` their means,
    then if ``do_eval`` (else zeros) the evaluation keyed by ``fold_in(seed_key, EVAL_KEY_OFFSET +
    evaluation)``. Vmapped with ``in_axes=(0, None, None, 0, None)``, the ``cond`` stays a branch."""

    def chunk(state, num_active, do_eval, seed_key, evaluation):
        eval_key = jax.random.fold_in(seed_key, EVAL_KEY_OFFSET + evaluation)

        def body(state, i):
            new_state, metrics = algorithm.update(state)
            keep = i < num_active  # unbatched: a select of whole arrays, no per-seed branching
            return jax.tree.map(lambda new, old: jnp.where(keep, new, old), new_state, state), metrics

        state, metrics = jax.lax.scan(body, state, jnp.arange(updates_per_chunk))
        weight = (jnp.arange(updates_per_chunk) < num_active).astype(jnp.float32)
        metrics = jax.tree.map(lambda m: (m * weight).sum() / jnp.maximum(weight.sum(), 1.0), metrics)

        def evaluate(state):
            return episode_returns(env, algorithm.greedy_policy(state), eval_key, eval_episodes)

        def skip(state):
            return jnp.zeros(eval_episodes, jnp.float32), jnp.zeros(eval_episodes, jnp.int32)

        returns, lengths = jax.lax.cond(do_eval, evaluate, skip, state)
        return state, metrics, returns, lengths

    return chunk


def agent_bytes(carry_shapes: Any) -> int:
    """Bytes of one seed's agent state (parameters, optimizer moments, targets) in a carry's shapes
    ``[S, ...]``: its ``agent`` (a sweep's inside its ``inner``), else the whole carry."""
    carry = getattr(carry_shapes, "inner", carry_shapes)
    leaves = jax.tree.leaves(getattr(carry, "agent", carry))
    seeds = max(leaves[0].shape[0], 1) if leaves and leaves[0].shape else 1
    return sum(math.prod(x.shape) * np.dtype(x.dtype).itemsize for x in leaves) // seeds


def seed_group(num_seeds: int, per_seed: int) -> int:
    """How many seeds one vmapped step takes (the chunk runs the groups one after the other,
    :func:`in_groups`): on a CPU, all of them while their agents fit in a core's L2 cache together,
    else the largest divisor of ``num_seeds`` whose agents do (at least 1); ``AGENTAX_SEED_GROUP``
    sets it."""
    if jax.default_backend() != "cpu":
        return num_seeds  # an accelerator wants every seed in one batch
    if os.environ.get("AGENTAX_SEED_GROUP"):
        wanted = max(1, min(num_seeds, int(os.environ["AGENTAX_SEED_GROUP"])))
    else:
        wanted = max(1, _xla.l2_cache_bytes() // max(per_seed, 1))
    return max(g for g in range(1, num_seeds + 1) if num_seeds % g == 0 and g <= wanted)


def in_groups(chunk: Callable, group: int) -> Callable:
    """``chunk`` (vmapped over seeds, ``in_axes=(0, None, None, 0, None)``) run on ``group`` seeds at a
    time by ``lax.map``: the same numbers for each seed, its agents' arrays kept in cache."""

    def grouped(state, num_active, do_eval, keys, evaluation):
        split = lambda x: x.reshape(x.shape[0] // group, group, *x.shape[1:])  # noqa: E731
        merge = lambda x: x.reshape(x.shape[0] * group, *x.shape[2:])  # noqa: E731
        out = jax.lax.map(
            lambda part: chunk(part[0], num_active, do_eval, part[1], evaluation),
            (jax.tree.map(split, state), split(keys)),
        )
        return jax.tree.map(merge, out)

    return grouped


def build(
    algorithm: Program, env: Environment, runner: Any, seeds: np.ndarray, description: dict[str, Any] | None
) -> tuple[Any, Callable, Callable]:
    """``(shapes, init, chunk)``: the carry's shapes and the runner's two programs, vmapped over seeds,
    the carry a flat list of arrays (plain lists export): ``init(seeds) -> leaves`` and
    ``chunk(leaves, num_active, do_eval, seeds, evaluation) -> (leaves, metrics, returns, lengths)``;
    kept by :func:`jit` under a ``description``."""
    traced_init = jax.jit(init_from_seeds(algorithm)).trace(seeds)
    shapes = traced_init.out_info
    state_tree = jax.tree.structure(shapes)
    chunk = jax.vmap(
        make_chunk(algorithm, env, runner.updates_per_chunk, runner.eval_episodes),
        in_axes=(0, None, None, 0, None),
        axis_name=SEED_AXIS,
    )
    group = seed_group(len(seeds), agent_bytes(shapes))
    if group < len(seeds):
        chunk = in_groups(chunk, group)

    def flat_init(seeds):
        return jax.tree.leaves(init_from_seeds(algorithm)(seeds))

    def flat_chunk(leaves, num_active, do_eval, seeds, evaluation):
        keys = jax.vmap(jax.random.key)(seeds)
        state, metrics, returns, lengths = chunk(
            jax.tree.unflatten(state_tree, leaves), num_active, do_eval, keys, evaluation
        )
        return jax.tree.leaves(state), metrics, returns, lengths

    if description is None:
        init = traced_init.lower().compile(INIT_COMPILER_OPTIONS)
        return shapes, lambda seeds: jax.tree.leaves(init(seeds)), jax.jit(flat_chunk, donate_argnums=0)
    shaping = {
        **description,
        "num_seeds": runner.num_seeds,
        "updates_per_chunk": runner.updates_per_chunk,
        "eval_episodes": runner.eval_episodes,
        "seed_group": group,  # seeds in groups: another program
    }
    init = jit(flat_init, (seeds,), {**shaping, "name": "init"}).lower(seeds).compile(INIT_COMPILER_OPTIONS)
    example = (jax.tree.leaves(shapes), 0, True, seeds, 0)
    return shapes, init, jit(flat_chunk, example, {**shaping, "name": "chunk"}, donate_argnums=0)
