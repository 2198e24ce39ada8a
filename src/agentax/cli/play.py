"""``agentax play``: one episode of a policy, written as a GIF or MP4."""

from __future__ import annotations

from dataclasses import dataclass

import tyro

from agentax.cli.evaluate import policy_label
from agentax.cli.policies import resolve_policy
from agentax.render import check_video_path, save_episode


@dataclass(frozen=True)
class PlayArgs:
    """Play one episode of a policy and write it as an animation (.gif or .mp4)."""

    env: str | None = None
    """environment id (agentax envs lists them); optional when --policy is a trained run's folder"""
    policy: str = "basic"
    """basic (the lecture's CartPole policy), random, or a trained run's folder"""
    video: str | None = None
    """where to write the animation, ending in .gif or .mp4 (default runs/play/ENV-POLICY.gif)"""
    seed: int = 0
    """random seed of the episode and of the policy"""


def main(argv: list[str]) -> int:
    args = tyro.cli(PlayArgs, args=argv, prog="agentax play")
    if args.video is not None:
        check_video_path(args.video)
    env_id, env, policy = resolve_policy(args.policy, args.env)
    label = policy_label(args.policy)
    path, episode = save_episode(env, policy, args.video or f"runs/play/{env_id}-{label}.gif", args.seed)
    print(
        f"wrote {path}: {label} policy on {env_id}, seed {args.seed}: "
        f"return {episode.total_return:g} over {episode.length} steps"
    )
    return 0
