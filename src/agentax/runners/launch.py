"""From a run's description to its runner, in plain calls: what the API asks of a kind of runner.

Every runner module (a row of :data:`agentax.runners.RUNNERS`) exports ``Config`` (its settings, a
frozen dataclass saved in config.json under "runner"); ``configure(run_args, agent, preset) ->
(Config, where)`` (the settings :class:`agentax.runfile.RunArgs` asks for, every bad input refused
with a ``UsageError`` before anything is written, and the words announcing the run: "host",
"4 seeds", ...); ``train(agent, env_id, runner, run=None, *, resume=False, progress=False) ->
TrainResult``; and ``restore(run_dir, config, agent) -> Policy`` (the greedy policy of a run's best
seed). :func:`prepare` (a new run), :func:`reopen` (a run to resume) and :func:`restore` make the
agent and call them; :mod:`agentax.api` calls these three.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agentax import _xla
from agentax.agents.memory import check_learning_fits
from agentax.agents.protocol import EnvSpec
from agentax.envs import make_host_env, make_jax
from agentax.errors import UsageError
from agentax.policies import Policy
from agentax.runners import RUNNERS, kind_of
from agentax.runners.session import TrainResult
from agentax.runs import Run


@dataclass(frozen=True)
class Launch:
    """A run ready to train: its runner's settings, and how to train it."""

    runner: Any
    """the runner's config (saved in config.json under "runner")"""
    where: str
    """how the run is trained, for the line announcing it"""
    train: Callable[[Run, bool, bool], TrainResult]
    """``train(run, resume, progress) -> result`` (``result.policy`` None where the state stayed elsewhere)"""
    precision: dict[str, Any]
    """the networks' precision and why (:func:`agentax.kernel_choice.precision_choice`), kept in
    config.json for resuming, evaluating and exporting"""


def agent_maker(
    module: Any, spec: Any, cfg: Any, conv: str | None = None, precision: str = "f32"
) -> Callable[[], Any]:
    """``make()``: the algorithm's agent for ``spec``, learning in the loop this platform runs best,
    its convolutions on ``conv``, else on the backend chosen here (``AGENTAX_CONV``), its networks'
    products in ``precision`` (a picklable callable: Ray's actor processes build the agent with it)."""
    from agentax import kernel_choice, kernels

    if conv is None:  # chosen once here, before anything is traced
        conv = kernel_choice.backend_for(spec.obs_shape)
    loop = kernels.learning_loop(spec.obs_shape, conv)
    return functools.partial(
        module.make_agent, spec, cfg, loop=loop, conv=conv, precision=kernels.check_precision(precision)
    )


def precision_of(config: dict[str, Any]) -> str:
    """The precision a run's config.json records (``f32`` in a folder written before precisions were)."""
    return config.get("precision", "f32")


def network_width(cfg: Any) -> int:
    """The widest hidden layer of an algorithm's config (its fields named ``*hidden*``), 256 where it
    names none: the width ``--precision auto`` measures a learning step at."""
    widths = [
        width
        for field in dataclasses.fields(cfg)
        if "hidden" in field.name and isinstance(getattr(cfg, field.name), tuple | list)
        for width in getattr(cfg, field.name)
    ]
    return max(widths, default=256)


def parse_return(flag: str, value: str, auto: float | None) -> float | None:
    """A return flag's value (``--stop-at-return``, ``--freeze-at-return``): a number, None or ``auto``."""
    if value == "none":
        return None
    if value == "auto":
        return auto
    try:
        return float(value)
    except ValueError:
        raise UsageError(f"{flag} must be a number, 'none' or 'auto', got {value!r}") from None


def env_specs(
    kind: str,
    env_id: str,
    backend: str = "auto",
    sticky_actions: float = 0.25,
    encoders: dict[str, str] | None = None,
) -> tuple[Any, Any]:
    """``(EnvSpec, what --stop-at-return auto reads the solved threshold of)`` of ``env_id`` as the
    ``kind`` runner makes it: agentax's JAX env, else the host adapter (and Gymnasium's EnvSpec);
    its leaves encoded as ``encoders`` choose (:meth:`EnvSpec.with_encoders`)."""
    if RUNNERS[kind].envs == "jax":
        env = make_jax(env_id)
        return EnvSpec.of(env).with_encoders(encoders, env_id), env
    _xla.let_xla_use_every_cpu(warn=False)  # the host runners' client, before the probe calls jax
    probe = make_host_env(env_id, 1, backend=backend, sticky_actions=sticky_actions)
    try:
        spec = EnvSpec.of(probe).with_encoders(encoders, env_id)
        return spec, getattr(getattr(probe, "vector_env", None), "spec", None)
    finally:
        probe.close()


def prepare(module: Any, run_args: Any, cfg: Any, preset: Any, kind: str) -> Launch:
    """The ``kind`` run ``run_args`` describe (``module``: the algorithm's, ``cfg`` its config), refused
    before anything is written where it cannot train; the networks' precision chosen once, here."""
    from agentax import kernel_choice

    runner_module = RUNNERS[kind].load()
    if hasattr(runner_module, "algorithm_config"):  # a runner with actors splits the envs between them
        cfg = runner_module.algorithm_config(cfg, run_args)
    spec, solved_by = env_specs(
        kind, run_args.env, run_args.env_backend, run_args.sticky_actions, run_args.encoders
    )
    if run_args.precision == "auto" and getattr(cfg, "core", "none") != "none":
        precision = {"mode": "auto", "precision": "f32", "why": "a recurrent core learns in f32"}
    else:
        precision = kernel_choice.precision_choice(run_args.precision, network_width(cfg))
    remake = agent_maker(module, spec, cfg, precision=precision["precision"])
    agent = remake()  # refuses what the agent cannot train before anything is written
    check_memory_carried(agent, kind)
    check_learning_fits(module.make_agent(spec, cfg), spec, run_args.seeds)  # (plain: see its docstring)
    solved = getattr(solved_by, "reward_threshold", None)  # 'auto': the env's, in a solving preset
    auto = float(solved) if preset.stop_at_solved and solved is not None else None
    stop = parse_return("--stop-at-return", run_args.stop_at_return, auto)
    run_args = dataclasses.replace(run_args, stop_at_return=stop)  # what every configure reads
    runner, where = runner_module.configure(run_args, agent, preset)
    return _launch(runner_module, agent, remake, run_args.env, runner, where, precision)


def check_memory_carried(agent: Any, kind: str) -> None:
    """A ``UsageError`` for an agent with memory (a recurrent core) on a runner that does not carry
    it from step to step (:attr:`agentax.runners.Runner.carries_memory`)."""
    if agent.recurrent is not None and not RUNNERS[kind].carries_memory:
        carriers = [k for k, runner in RUNNERS.items() if runner.carries_memory and runner.envs == "any"]
        raise UsageError(
            f"a recurrent core (--core) trains only where a runner carries its memory, not on the {kind} "
            f"runner: use --runner {' or '.join(carriers)}"
        )


def run_agent_maker(config: dict, module: Any, cfg: Any, conv: str | None = None) -> Callable[[], Any]:
    """:func:`agent_maker` for the run of ``config`` (a config.json): its env as its runner makes it
    (with the host adapter's options it holds under "runner"), its encoders and its precision."""
    runner = config.get("runner", {})
    options = (runner.get("env_backend", "auto"), runner.get("sticky_actions", 0.25))
    spec, _ = env_specs(kind_of(config), config["env"], *options, config.get("encoders"))
    precision = precision_of(config)
    if conv == "xla":  # a policy for export: XLA's products only
        from agentax import kernels

        precision = kernels.exportable(precision)
    return agent_maker(module, spec, cfg, conv, precision)


def reopen(config: dict[str, Any], module: Any, cfg: Any, runner: Any) -> Launch:
    """The run of ``config`` (a config.json; ``runner``: its settings, parsed), to resume."""
    remake = run_agent_maker(config, module, cfg)
    precision = {"precision": precision_of(config), **config.get("precision_choice", {})}
    return _launch(RUNNERS[kind_of(config)].load(), remake(), remake, config["env"], runner, "", precision)


def _launch(
    runner_module: Any, agent: Any, remake: Any, env_id: str, runner: Any, where: str, precision: dict
) -> Launch:
    """``remake()`` builds ``agent`` again (in the actor processes of a runner whose actors do)."""
    options = {"make_agent": remake} if getattr(runner_module, "REMAKES_AGENT", False) else {}

    def train(run: Run, resume: bool, progress: bool) -> TrainResult:
        return runner_module.train(agent, env_id, runner, run, resume=resume, progress=progress, **options)

    return Launch(runner, where, train, precision)


def restore(run_dir: Path, config: dict[str, Any], module: Any, cfg: Any, conv: str | None = None) -> Policy:
    """The greedy policy of the run's best seed, from its newest good checkpoint (its convolutions on
    ``conv``, else on :func:`agent_maker`'s choice; its products in the run's precision)."""
    agent = run_agent_maker(config, module, cfg, conv)()
    return RUNNERS[kind_of(config)].load().restore(Path(run_dir), config, agent)
