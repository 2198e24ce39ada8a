"""``agentax kernels``: which convolutions and dense products the Nature CNN runs on here, and why."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import tyro

from agentax import kernel_choice


@dataclass(frozen=True)
class KernelsArgs:
    """Show the CPU, the backends ``AGENTAX_CONV=auto`` chooses from with their measured ms per
    Nature-CNN DQN update, the one chosen and why, and the file that keeps the choice. The first
    call on a machine measures (~10 s); later ones read the file."""

    measure: bool = False
    """measure the candidates again and keep the new choice"""
    json: bool = False
    """print the choice as one JSON object"""


def describe(about: dict[str, Any], flags: frozenset[str]) -> list[str]:
    """The choice (:func:`agentax.kernel_choice.choice`) as lines for the terminal."""
    bf16 = ", ".join(sorted(flags & set(kernel_choice.BF16_FLAGS))) or "none"
    lines = [f"CPU: {about['cpu']} (bfloat16 flags: {bf16})"]
    lines.append(f"AGENTAX_CONV={about['mode']} -> {about['backend']}: {about['why']}")
    ms, errors = about.get("ms", {}), about.get("errors", {})
    if ms or errors:
        lines.append(f"ms per update, {about['fields']['shape']}:")
        width = max(map(len, [*ms, *errors]))
        for name in about["candidates"]:
            figure = f"{ms[name]:8.2f}" if name in ms else f"   failed: {errors.get(name, 'not timed')}"
            lines.append(f"  {name:<{width}} {figure}{'  <- chosen' if name == about['backend'] else ''}")
    for name, why in about.get("excluded", {}).items():
        lines.append(f"not a candidate: {name} ({why})")
    if about.get("source"):
        kept = (
            f"kept in {about['cache']}" if about["cache"] else "kept in no file (AGENTAX_KERNELS_CACHE=none)"
        )
        now = " now" if about["source"] == "measured" else ""
        lines.append(f"measured{now} ({about['measured']}), {kept}")
    return lines


def main(argv: list[str]) -> int:
    args = tyro.cli(KernelsArgs, args=argv, prog="agentax kernels")
    about = kernel_choice.choice(again=args.measure)
    if args.json:
        print(json.dumps(about))
    else:
        print("\n".join(describe(about, kernel_choice.cpu_info()[1])))
    return 0
