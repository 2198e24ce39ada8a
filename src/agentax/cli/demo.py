"""``agentax demo``: train PPO on CartPole-v1 until solved, evaluate it, write its curve and a GIF.

The lecture's basic policy (push towards the side the pole leans to) is evaluated beside it, for
scale: it averages about 42 steps; the trained agent balances the pole for all 500.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import tyro
from rich.console import Console

from agentax.errors import UsageError


@dataclass(frozen=True)
class DemoArgs:
    """Train PPO on CartPole-v1 until solved, evaluate it against the basic policy, animate it."""

    episodes: int = 100
    """evaluation episodes of the trained agent (and of the basic policy)"""
    seed: int = 0
    """random seed of training and evaluation"""
    out: str | None = None
    """run folder (default runs/demo/ppo-CartPole-v1-<time>, or <video>-run beside --video)"""
    video: str | None = None
    """where to write the animation of the trained agent (.gif or .mp4; default <run folder>/episode.gif)"""
    progress: bool = True
    """show a progress bar while training"""


def main(argv: list[str]) -> int:
    args = tyro.cli(DemoArgs, args=argv, prog="agentax demo")
    if args.episodes < 1:
        raise UsageError(f"--episodes must be at least 1, got {args.episodes}")
    from pathlib import Path

    from agentax import _xla
    from agentax.agents import config_to_dict, ppo, presets_of
    from agentax.cli.evaluate import stats_table
    from agentax.envs import make_jax
    from agentax.evaluate import evaluate
    from agentax.policies import basic_policy
    from agentax.render import check_video_path, save_episode
    from agentax.runners.compiled import RunnerConfig, compiled_program, restore_policy, train_program
    from agentax.runs import Run, default_run_dir, run_config

    _xla.enable_compilation_cache()
    env = make_jax("CartPole-v1")
    preset = presets_of("ppo")["cartpole-fast"]
    runner = RunnerConfig(
        seed=args.seed,
        updates_per_chunk=2,  # a log row (and an evaluation) every 512 env steps: a curve with points
        eval_episodes=preset.eval_episodes,
        stop_at_return=env.reward_threshold,
    )
    if args.video:
        check_video_path(args.video)
    if args.out:
        out = Path(args.out)
    elif args.video:
        out = default_run_dir("ppo", env.id, root=Path(args.video).parent)
    else:
        out = default_run_dir("ppo", env.id, root="runs/demo")
    config = run_config("ppo", env.id, "cartpole-fast", "compiled", runner, config_to_dict(preset.config))
    console = Console()
    console.print(f"[bold]Training PPO on {env.id}[/] (preset cartpole-fast) into {out}")
    start = time.perf_counter()
    algorithm = compiled_program(ppo, env, preset.config)
    description = {key: config[key] for key in ("algo", "env", "config")}  # names the stored programs
    description["freeze"] = [None, runner.freeze_episodes]  # as agentax train's, so they share programs
    run = Run.create(out, config)
    result = train_program(
        algorithm, env, runner, run, progress=args.progress, program_description=description
    )
    seconds = time.perf_counter() - start
    solved = (
        f"solved after {result.solved_env_steps:,.0f} env steps"
        if result.solved_env_steps is not None
        else f"trained {result.env_steps:,.0f} env steps without reaching {env.reward_threshold:g}"
    )
    console.print(f"{solved} in {seconds:.1f} s (compile {result.compile_seconds:.1f} s)")

    policy = restore_policy(out, algorithm, runner, seed_index=0)
    for name, candidate in (("trained PPO", policy), ("basic", basic_policy)):
        start = time.perf_counter()
        stats = evaluate(env, candidate, args.episodes, args.seed + 1)
        console.print(stats_table(env.id, name, stats, args.seed + 1, time.perf_counter() - start))
    path, episode = save_episode(env, policy, args.video or out / "episode.gif", args.seed)
    print(f"wrote {out / 'curve.png'}: the learning curve")
    print(
        f"wrote {path}: one episode of the trained agent, "
        f"return {episode.total_return:g} over {episode.length} steps"
    )
    return 0
