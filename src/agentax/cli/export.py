"""``agentax export RUN_DIR --format onnx|stablehlo [--out FILE] [--stochastic]``: a trained run's
policy as one file that runs without agentax, its model card beside it (``FILE.json``).

The file maps observations ``obs [N, *obs_shape]``, as agentax's env gives them, to the env's actions
``action [N]`` or ``[N, action_dim]`` (see :mod:`agentax.export`); a recurrent run's (``--core``) also
takes and returns its core's state, ``(obs, state [N, S]) -> (action, next_state)``, zeros at an
episode's start. ``agentax evaluate --policy FILE`` plays it on the env.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from agentax.errors import UsageError


@dataclass(frozen=True)
class ExportArgs:
    """Write a trained run's policy as an ONNX file or a StableHLO module, with its model card."""

    run_dir: Annotated[str, tyro.conf.Positional]
    """the run folder written by agentax train"""
    format: str = "onnx"
    """onnx (run it with onnxruntime; needs pip install 'agentax[export]') or stablehlo (run it with
    jax.export.deserialize)"""
    out: str | None = None
    """the file to write (default RUN_DIR/policy.onnx or RUN_DIR/policy.stablehlo); the model card
    goes beside it as FILE.json"""
    stochastic: bool = False
    """the sampling head, with a key input (uint32[2]), instead of the greedy action (stablehlo only)"""


def main(argv: list[str]) -> int:
    args = tyro.cli(ExportArgs, args=argv, prog="agentax export")
    from agentax.api import load
    from agentax.export import card_path, check_format

    check_format(args.format, args.stochastic)  # before the run is read
    if not Path(args.run_dir).is_dir():
        raise UsageError(f"no run folder at {args.run_dir!r}; give a folder written by agentax train")
    start = time.perf_counter()
    path = load(args.run_dir).export(args.out, args.format, stochastic=args.stochastic)
    seconds = time.perf_counter() - start
    print(f"wrote {path} ({path.stat().st_size:,} bytes) and {card_path(path)} in {seconds:.1f} s")
    return 0
