"""Write the run-folder fixtures of one format version, with whatever agentax is importable.

A run folder is a contract with later versions: ``tests/fixtures/runs/format-<N>/`` holds small run
folders that agentax of format ``N`` wrote, and ``recorded.json`` beside them what that version
said of them: each folder's evaluation (``agentax evaluate``'s, and on Gymnasium's own env), and its
greedy actions on fixed observations.
``tests/test_formats.py`` loads, evaluates and resumes every one of them with today's agentax.

The current format's fixtures, from this checkout::

    .venv/bin/python scripts/run_fixtures.py tests/fixtures/runs/format-2

An older format's, from the last commit that wrote it (format 1: e97acb0)::

    git worktree add /tmp/agentax-e97acb0 e97acb0
    PYTHONPATH=/tmp/agentax-e97acb0/src .venv/bin/python scripts/run_fixtures.py tests/fixtures/runs/format-1

Each folder keeps only its newest checkpoint (and the replay buffer saved with it), as a user's
folder does once the older ones are pruned; the script uses only the CLI and
``agentax.api.restore_policy``, which every version has.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

COMMON = ["--no-progress", "--stop-at-return", "none"]
REPLAY = ["--buffer-size", "1000"]
FIXTURES: dict[str, list[str]] = {
    "ppo-compiled-2seeds": ["ppo", "--env", "CartPole-v1", "--seeds", "2", "--total-steps", "4096"],
    "ppo-host": ["ppo", "--env", "CartPole-v1", "--runner", "host", "--total-steps", "2048"],
    "reinforce-compiled": ["reinforce", "--env", "CartPole-v1", "--total-steps", "20000", "--hidden", "16"],
    "pqn-compiled": ["pqn", "--env", "CartPole-v1", "--total-steps", "50000", "--hidden", "32", "32"],
    "dqn-compiled": [
        "dqn",
        "--env",
        "CartPole-v1",
        "--total-steps",
        "2000",
        *REPLAY,
        "--learning-starts",
        "500",
    ],
    "dqn-host-replay": [
        *("dqn", "--env", "CartPole-v1", "--runner", "host", "--total-steps", "1500"),
        *(*REPLAY, "--learning-starts", "500"),
    ],
    "sac-host-replay": [
        *("sac", "--env", "Pendulum-v1", "--runner", "host", "--total-steps", "600"),
        *(*REPLAY, "--learning-starts", "200"),
    ],
    "td3-host-replay": [
        *("td3", "--env", "Pendulum-v1", "--runner", "host", "--total-steps", "600"),
        *(*REPLAY, "--learning-starts", "200"),
    ],
}
"""Each fixture's ``agentax train`` arguments (small networks: a fixture is a few tens of kB)."""
HIDDEN = ["--hidden", "16", "16"]
EVAL_EPISODES, EVAL_SEED = 5, 0


def observations(env_id: str, n: int = 32) -> np.ndarray:
    """``n`` fixed observations ``[n, obs_dim]`` inside the env's usual range (numpy seed 0)."""
    rng = np.random.default_rng(0)
    if env_id.startswith("CartPole"):
        return (rng.uniform(-1, 1, (n, 4)) * np.array([2.0, 2.0, 0.2, 2.0])).astype(np.float32)
    if env_id.startswith("Pendulum"):
        angle, velocity = rng.uniform(-np.pi, np.pi, n), rng.uniform(-8, 8, n)
        return np.stack([np.cos(angle), np.sin(angle), velocity], axis=1).astype(np.float32)
    raise ValueError(f"no fixed observations for {env_id}")


def greedy_actions(run_dir: Path) -> list:
    """The run's greedy actions on :func:`observations` of its env."""
    import jax

    from agentax.api import restore_policy

    env_id, policy = restore_policy(run_dir)
    return np.asarray(policy(observations(env_id), jax.random.key(0))).tolist()


def gymnasium_evaluation(run_dir: Path) -> dict:
    """The run's greedy policy on Gymnasium's own env of its id (5 episodes, seed 0), stepped on
    the host: the same episodes in every version, whichever env agentax routes the id to."""
    from agentax.api import restore_policy
    from agentax.envs import GymnasiumEnv
    from agentax.evaluate import evaluate

    env_id, policy = restore_policy(run_dir)
    return vars(evaluate(GymnasiumEnv(env_id, EVAL_EPISODES), policy, EVAL_EPISODES, EVAL_SEED))


def evaluation(run_dir: Path) -> dict:
    """What ``agentax evaluate --policy DIR --episodes 5 --seed 0 --json`` prints."""
    command = [*agentax(), "evaluate", "--policy", str(run_dir), "--episodes", str(EVAL_EPISODES)]
    done = subprocess.run([*command, "--seed", str(EVAL_SEED), "--json"], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{done.stderr}")
    return {k: v for k, v in json.loads(done.stdout).items() if k not in ("policy", "env")}


def agentax() -> list[str]:
    return [sys.executable, "-c", "import sys; from agentax.cli import main; sys.exit(main())"]


def keep_newest_checkpoint(run_dir: Path) -> None:
    from agentax.runs import checkpoints, replay_beside

    for old in checkpoints(run_dir)[:-1]:
        old.unlink()
        replay_beside(old).unlink(missing_ok=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dest", type=Path, help="the folder of this format's fixtures (made anew)")
    args = parser.parse_args()
    if args.dest.exists():
        shutil.rmtree(args.dest)
    args.dest.mkdir(parents=True)
    recorded = {}
    for name, train in FIXTURES.items():
        hidden = [] if "--hidden" in train else HIDDEN
        command = [*agentax(), "train", *train, *hidden, *COMMON, "--out", name]
        print(" ".join(command[3:]), file=sys.stderr)
        subprocess.run(command, cwd=args.dest, check=True, capture_output=True)
        run_dir = args.dest / name
        keep_newest_checkpoint(run_dir)
        recorded[name] = {
            "evaluate": evaluation(run_dir),
            "gymnasium_evaluate": gymnasium_evaluation(run_dir),
            "greedy_actions": greedy_actions(run_dir),
        }
    (args.dest / "recorded.json").write_text(json.dumps(recorded, indent=1) + "\n")


if __name__ == "__main__":
    main()
