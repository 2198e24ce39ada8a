"""``agentax play``: one episode of a policy, written as a GIF or MP4.

An Atari game is played whole (every life, until game over or the 108,000-frame cap) in the
evaluation view, filmed from the emulator's full-resolution screen, and its true score printed.
"""

from __future__ import annotations

from dataclasses import dataclass

import tyro

from agentax.cli.evaluate import policy_label
from agentax.cli.policies import env_description, resolve_policy
from agentax.envs import AtariEnv
from agentax.render import ATARI_FPS, check_video_path, record_atari_game, save_episode


@dataclass(frozen=True)
class PlayArgs:
    """Play one episode of a policy and write it as an animation (.gif or .mp4)."""

    env: str | None = None
    """environment id (agentax envs lists them); optional when --policy is a trained run's folder"""
    policy: str = "basic"
    """basic (the lecture's CartPole policy), random, or a trained run's folder"""
    video: str | None = None
    """where to write the animation, ending in .gif or .mp4 (default runs/play/ENV-POLICY.gif; Atari: .mp4)"""
    seed: int = 0
    """random seed of the episode and of the policy"""
    scale: int = 3
    """Atari: how many times larger than the 210x160 screen the video is (nearest neighbour)"""
    env_backend: str | None = None
    """Atari: envpool, ale or auto (default: the run's, else auto)"""
    sticky_actions: float | None = None
    """Atari: probability that the emulator repeats the last action (default: the run's, else 0.25)"""


def main(argv: list[str]) -> int:
    args = tyro.cli(PlayArgs, args=argv, prog="agentax play")
    if args.video is not None:
        check_video_path(args.video)
    env_id, env, policy = resolve_policy(
        args.policy, args.env, env_backend=args.env_backend, sticky_actions=args.sticky_actions
    )
    label = policy_label(args.policy)
    default_video = f"runs/play/{env_id.replace('/', '_')}-{label}"
    if isinstance(env, AtariEnv):
        try:
            path, game = record_atari_game(
                env, policy, args.video or f"{default_video}.mp4", args.seed, args.scale
            )
        finally:
            env.close()
        ending = "truncated at the frame cap" if game.truncated else "game over"
        print(
            f"wrote {path}: {label} policy on {env_id} ({env_description(env)}), seed {args.seed}: "
            f"score {game.score:g} over {game.length} steps ({4 * game.length} frames, {ending}); "
            f"video {game.video_frames} frames at {ATARI_FPS:g} fps"
        )
        return 0
    path, episode = save_episode(env, policy, args.video or f"{default_video}.gif", args.seed)
    print(
        f"wrote {path}: {label} policy on {env_id}, seed {args.seed}: "
        f"return {episode.total_return:g} over {episode.length} steps"
    )
    return 0
