"""Replay buffers on disk: one compressed ``.npz`` of a buffer's ``state_dict``, written atomically
and read without pickle. The frame buffer's own ``frames.load`` reads the same files into a new buffer."""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from agentax.runs import atomic_file


def save_replay(buffer: Any, path: str | Path, compresslevel: int = 1) -> Path:
    """Write a replay buffer's ``state_dict`` (a host buffer's or the frame buffer's) to ``path`` as
    a compressed ``.npz`` (deflate, no pickle: ``np.load`` reads it with ``allow_pickle=False``),
    atomically (:func:`agentax.runs.atomic_file`). Holds the buffer's lock meanwhile (the actors
    wait). Level 1 deflate: frames compress about as well as at level 6 for a fraction of the time."""
    path = Path(path)
    with buffer.lock:
        arrays = {name: np.asanyarray(array) for name, array in buffer.state_dict().items()}
        needed = sum(array.nbytes for array in arrays.values())  # at most: the arrays uncompressed
        with atomic_file(path, needed) as f:
            with zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED, compresslevel=compresslevel) as archive:
                for name, array in arrays.items():
                    with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                        np.lib.format.write_array(member, array, allow_pickle=False)
    return path


def restore_replay(buffer: Any, path: Any) -> None:
    """Load what :func:`save_replay` wrote into ``buffer`` (made with the same settings)."""
    with np.load(path, allow_pickle=False) as data:
        buffer.load_state_dict({name: data[name] for name in data.files})
