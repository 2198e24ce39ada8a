"""The host family's launcher (see :mod:`agentax.runners.launch`): the runners that train one seed
per process and share :class:`~agentax.runners.host.HostRunnerConfig`'s settings (``host``,
``parallel``, ``ray``, ``compiled-atari``, ``compiled-mujoco``). Each adds its own settings with
the ``configure`` its :class:`~agentax.runners.RunnerSpec` names."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from agentax.errors import UsageError
from agentax.policies import Policy
from agentax.runners import RUNNERS, kind_of
from agentax.runners.launch import Launch, agent_maker, parse_stop


def host_env_spec(env_id: str, backend: str, sticky_actions: float) -> tuple[Any, Any]:
    """``(EnvSpec, Gymnasium's EnvSpec or None)`` of ``env_id`` as the host runners make it."""
    from agentax.agents.protocol import EnvSpec
    from agentax.envs import make_host_env

    probe = make_host_env(env_id, 1, backend=backend, sticky_actions=sticky_actions)
    specs = EnvSpec.of(probe), getattr(getattr(probe, "vector_env", None), "spec", None)
    probe.close()
    return specs


def prepare(algo: str, module: Any, run_args: Any, cfg: Any, preset: Any, kind: str) -> Launch:
    """The ``kind`` run ``run_args`` describe; what the runner or the agent cannot train is refused
    here, before anything is written."""
    spec = RUNNERS[kind]
    if (run_args.workers or 1) > 1:
        raise UsageError(
            f"--workers splits the compiled runner's seeds over processes; the {kind} runner trains one "
            "seed (train a JAX env with --runner compiled, or drop the flag)"
        )
    run_args.freeze(preset, kind)
    if run_args.seeds != 1 and spec.envs == "any":  # (the compiled EnvPool runner's check says why)
        raise UsageError(
            f"the {kind} runner trains one seed per process (--seeds 1); --seeds N is compiled-only"
        )
    if spec.actors and run_args.envs_per_actor is not None:
        from agentax.runners.parallel import envs_per_actor

        cfg = envs_per_actor(cfg, run_args)
    env_spec, gym_spec = host_env_spec(run_args.env, run_args.env_backend, run_args.sticky_actions)
    remake = agent_maker(module, env_spec, cfg)
    agent = remake()  # refuses what the agent cannot train before anything is written
    common = {
        "seed": run_args.seed,
        "eval_episodes": preset.eval_episodes,
        "stop_at_return": parse_stop(run_args.stop_at_return, preset, gym_spec),
        "checkpoint_replay": run_args.checkpoint_replay,
        "env_backend": run_args.env_backend,
        "sticky_actions": run_args.sticky_actions,
    }
    runner, where = spec.configurer()(run_args, agent, common)
    return _launch(kind, agent, remake, runner, where)


def configure_in_program(run_args: Any, agent: Any, common: dict[str, Any]) -> tuple[Any, str]:
    """The compiled EnvPool runners' settings (the host runner's), refused where the program
    cannot step the env or train the agent."""
    from agentax.runners import compiled_atari

    runner = compiled_atari.PoolRunnerConfig(**common, policy_lag=run_args.policy_lag)
    compiled_atari.check(agent, run_args.env, runner, run_args.seeds)
    return runner, f"compiled, EnvPool inside the program, policy lag {runner.policy_lag}"


def reopen(config: dict[str, Any], module: Any, cfg: Any, runner: Any) -> Launch:
    """The run of ``config`` (a config.json), to resume."""
    env_spec, _ = host_env_spec(config["env"], runner.env_backend, runner.sticky_actions)
    remake = agent_maker(module, env_spec, cfg)
    return _launch(kind_of(config), remake(), remake, runner, "")


def _launch(kind: str, agent: Any, remake: Any, runner: Any, where: str) -> Launch:
    """``remake()`` builds ``agent`` again (in the actor processes of a runner that has them)."""
    spec = RUNNERS[kind]

    def train(run: Any, resume: bool, progress: bool) -> tuple[Any, Policy]:
        options = {"resume": resume, "progress": progress}
        if spec.remakes_agent:
            options["make_agent"] = remake
        result = spec.load().train(agent, run.config["env"], runner, run, **options)
        return result, agent.greedy_policy(result.state)

    return Launch(runner, where, train)


def restore(run_dir: Path, config: dict[str, Any], module: Any, cfg: Any) -> Policy:
    """The greedy policy of the run's newest checkpoint."""
    from agentax.runners.host import restore_policy

    runner = config.get("runner", {})
    env_spec, _ = host_env_spec(
        config["env"], runner.get("env_backend", "auto"), runner.get("sticky_actions", 0.25)
    )
    return restore_policy(run_dir, module.make_agent(env_spec, cfg))
