"""``agentax presets [ALGO [NAME]] [--env ID] [--out FILE]``: the tuned presets, as run files.

Without arguments, one line per preset (the envs ``--preset auto`` picks it for, its description);
with ``ALGO NAME``, the preset as a run file (:mod:`agentax.runfile`) on stdout or in ``--out FILE``,
for ``agentax train --config FILE``. The files are generated from the preset table
(:mod:`agentax.agents.presets`), not shipped beside it: the table stays the one source of truth, so
no copy can drift from what ``--preset NAME`` trains.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import tyro


@dataclass(frozen=True)
class PresetsArgs:
    """List the presets, or write one as a run file."""

    algo: Annotated[str | None, tyro.conf.Positional] = None
    """the algorithm (all of them when left out)"""
    name: Annotated[str | None, tyro.conf.Positional] = None
    """the preset to write as a run file"""
    env: str | None = None
    """the env of the run file (default: the first env --preset auto picks this preset for)"""
    out: str | None = None
    """write the run file here instead of printing it"""


def picked_for(algo: str, name: str) -> list[str]:
    """The envs ``--preset auto`` picks preset ``name`` of ``algo`` for ("atari": every Atari id)."""
    from agentax.agents.presets import DEFAULT_PRESETS

    return [env for env, chosen in DEFAULT_PRESETS.get(algo, {}).items() if chosen == name]


def preset_env(algo: str, name: str) -> str:
    """The env a preset's run file names: RunArgs's default or the first ``--preset auto`` picks it
    for (this algorithm's, else another's preset of the same name), else RunArgs's default."""
    from agentax.agents import ALGORITHMS
    from agentax.runfile import RunArgs

    for owner in (algo, *ALGORITHMS):
        envs = picked_for(owner, name)
        if RunArgs.env in envs:
            return RunArgs.env
        if envs:
            return "ALE/Breakout-v5" if envs[0] == "atari" else envs[0]
    return RunArgs.env


def main(argv: list[str]) -> int:
    from agentax import runfile
    from agentax.agents import ALGORITHMS, presets_of
    from agentax.errors import UsageError

    args = tyro.cli(PresetsArgs, args=argv, prog="agentax presets")
    if args.name is None:
        for algo in [args.algo] if args.algo else ALGORITHMS:
            for name, preset in presets_of(algo).items():
                envs = picked_for(algo, name)
                shown = (envs[0] + (f" +{len(envs) - 1}" if len(envs) > 1 else "")) if envs else "-"
                print(f"{algo:<9} {name:<14} {shown:<26} {preset.description}")
        print("(the third column: the envs --preset auto picks it for)")
        print(
            "a preset as a run file: agentax presets ALGO NAME [--env ID] > FILE; agentax train --config FILE"
        )
        return 0
    env = args.env or preset_env(args.algo, args.name)
    name, preset = runfile.choose_preset(args.algo, env, args.name)
    header = f"preset {args.algo}/{name}: {preset.description}\ntrain it: agentax train --config THIS_FILE"
    run_args = runfile.RunArgs(env=env, preset=name)
    if args.out is None:
        print(runfile.dumps(args.algo, run_args, preset.config, header), end="")
        return 0
    try:
        runfile.write(args.out, args.algo, run_args, preset.config, header)
    except OSError as error:
        raise UsageError(f"--out {args.out}: cannot write the run file ({error.strerror})") from None
    print(f"wrote {args.out}")
    return 0
