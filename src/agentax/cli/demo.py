"""``agentax demo``: the lecture's basic policy on CartPole-v1, evaluated and animated."""

from __future__ import annotations

import time
from dataclasses import dataclass

import tyro
from rich.console import Console

from agentax.cli.evaluate import stats_table
from agentax.envs import make
from agentax.evaluate import evaluate
from agentax.policies import basic_policy
from agentax.render import save_episode


@dataclass(frozen=True)
class DemoArgs:
    """Evaluate the lecture's basic CartPole policy over 500 episodes and animate one episode."""

    episodes: int = 500
    """number of episodes to evaluate"""
    video: str = "runs/demo/cartpole-basic.gif"
    """where to write the animation (.gif or .mp4)"""
    seed: int = 0
    """random seed"""


def main(argv: list[str]) -> int:
    args = tyro.cli(DemoArgs, args=argv, prog="agentax demo")
    env = make("CartPole-v1")
    start = time.perf_counter()
    stats = evaluate(env, basic_policy, args.episodes, args.seed)
    Console().print(stats_table(env.id, "basic", stats, args.seed, time.perf_counter() - start))
    path, episode = save_episode(env, basic_policy, args.video, args.seed)
    print(f"wrote {path}: one episode, return {episode.total_return:g} over {episode.length} steps")
    return 0
