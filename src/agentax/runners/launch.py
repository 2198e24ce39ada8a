"""What every runner's launcher shares: the :class:`Launch` it hands the API, and the pieces both
families build a run from (the agent's maker, the stop-at-return setting).

A launcher (the module a :class:`~agentax.runners.RunnerSpec` names in ``launcher``) provides

- ``prepare(algo, module, run_args, cfg, preset, kind) -> Launch``: the run a description asks for
  (``run_args``, duck-typed like :class:`agentax.runfile.RunArgs`; the algorithm's ``module``, its
  ``cfg`` and ``preset``), every bad input refused with a ``UsageError`` before anything is written;
- ``reopen(config, module, cfg, runner) -> Launch``: the run of a config.json (``runner``: its
  settings, already parsed), to resume;
- ``restore(run_dir, config, module, cfg) -> Policy``: the greedy policy of a run's best seed.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from agentax.errors import UsageError
from agentax.policies import Policy
from agentax.runners.session import TrainResult
from agentax.runs import Run


@dataclass(frozen=True)
class Launch:
    """A run ready to train: its runner's settings, and how to train it."""

    runner: Any
    """the runner's config (saved in config.json under "runner")"""
    where: str
    """how the run is trained, for the line announcing it ("host", "4 seed(s)", "2 actors", ...)"""
    train: Callable[[Run, bool, bool], tuple[TrainResult, Policy | None]]
    """``train(run, resume, progress) -> (result, greedy policy of the best seed, or None where the
    state stayed in other processes)``"""


def agent_maker(module: Any, spec: Any, cfg: Any) -> Callable[[], Any]:
    """``make()``: the algorithm's agent for ``spec``, learning in the loop this platform runs best
    (a picklable callable: Ray's actor processes build the agent with it)."""
    from agentax import kernels

    return functools.partial(module.make_agent, spec, cfg, loop=kernels.learning_loop(spec.obs_shape))


def parse_stop(value: str, preset: Any, env: Any) -> float | None:
    """``--stop-at-return``: a number, 'none', or 'auto' (the env's solved threshold in a solving
    preset)."""
    if value == "none":
        return None
    if value == "auto":
        solved = getattr(env, "reward_threshold", None)
        return float(solved) if preset.stop_at_solved and solved is not None else None
    try:
        return float(value)
    except ValueError:
        raise UsageError(f"--stop-at-return must be a number, 'none' or 'auto', got {value!r}") from None
