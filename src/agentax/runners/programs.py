"""Lowered training programs kept on disk (``jax.export``), so a repeated run skips tracing too.

The persistent compilation cache (:mod:`agentax._xla`) lets a repeated run skip XLA's compile,
but jax looks a compiled program up only after tracing the Python code and lowering it to
StableHLO — about 1 s for PPO's chunk on this 2-core CPU, a third of a warm ``agentax train``.
:func:`jit` keeps the lowered program itself (``jax.export``'s serialized StableHLO: a flatbuffer,
never a pickle) under a fingerprint, and the next run calls the stored program without tracing.

The fingerprint covers everything that shapes the program: the caller's description of it (which
algorithm, env, config and schedule), the arguments' shapes and dtypes, jax's version and backend,
and the source of every agentax module — edit any of them and the program is traced afresh. Only
programs whose arguments and results are plain containers (lists, tuples, dicts) of arrays can be
kept; anything that fails to load or to export is traced as usual, since this is only a cache.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax

from agentax import _xla, kernels

KEEP = 256
"""Programs kept: past this many, the least recently used go (each is ~0.1-1 MB)."""


def program_dir() -> Path | None:
    """Where lowered programs are kept: beside the compiled ones (None when that cache is off)."""
    root = _xla.compilation_cache_dir()
    return None if root is None else root / "agentax-programs"


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
        "conv": kernels.known_backend(),  # XLA's convolutions or oneDNN's: another program
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:32]


def jit(
    fn: Callable,
    example_args: Sequence[Any],
    description: dict[str, Any] | None,
    donate_argnums: int | tuple[int, ...] = (),
) -> Callable:
    """``jax.jit(fn)``, or the stored lowering of ``fn`` at ``example_args`` when ``description`` names it.

    ``example_args`` may hold ``jax.ShapeDtypeStruct`` leaves. With ``description=None`` (or the
    cache off) this is plain ``jax.jit``.
    """
    directory = program_dir()
    if description is None or directory is None:
        return jax.jit(fn, donate_argnums=donate_argnums)
    from jax import export

    from agentax.runs import write_atomic

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
            _forget_oldest(directory)
        except (OSError, ImportError):  # a read-only cache, or no flatbuffers: use it, unsaved
            pass
    return jax.jit(exported.call, donate_argnums=donate_argnums)


def _forget_oldest(directory: Path) -> None:
    stored = sorted(directory.glob("*.jaxexport"), key=lambda path: path.stat().st_mtime)
    for path in stored[:-KEEP]:
        path.unlink(missing_ok=True)
