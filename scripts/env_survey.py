"""Try agentax as a new user would, one command per environment (issue 41): ``agentax train ALGO --env
ID --total-steps N`` in a fresh process each, then a table of env, algo, exit code, and the final
evaluation or the error's one line.

    PYTHONPATH=src python scripts/env_survey.py                  # every pair below
    PYTHONPATH=src python scripts/env_survey.py --only Taxi --only own_envs --total-steps 2000

Run from the repository root: the envs of one's own are ``scripts.own_envs:ID`` (Gymnasium imports
the module named before the colon). A pair whose package is missing should end in one line naming
the extra to install, exit code 2; any traceback is a defect.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

OWN = "scripts.own_envs:"
DISCRETE_ACTIONS = ("ppo", "dqn")
BOX_ACTIONS = ("ppo", "sac")
PAIRS: list[tuple[str, str]] = [
    *((env, algo) for env in ("CartPole-v1", "Acrobot-v1", "MountainCar-v0") for algo in DISCRETE_ACTIONS),
    *((env, algo) for env in ("Pendulum-v1", "MountainCarContinuous-v0") for algo in BOX_ACTIONS),
    *(
        (env, algo)
        for env in ("Blackjack-v1", "FrozenLake-v1", "Taxi-v4", "CliffWalking-v1")
        for algo in DISCRETE_ACTIONS
    ),
    ("Taxi-v3", "ppo"),
    *((env, algo) for env in ("LunarLander-v3",) for algo in DISCRETE_ACTIONS),
    *((env, algo) for env in ("CarRacing-v3", "BipedalWalker-v3") for algo in BOX_ACTIONS),
    *((env, algo) for env in ("HalfCheetah-v5", "Hopper-v5", "InvertedPendulum-v5") for algo in BOX_ACTIONS),
    *((env, algo) for env in ("gymnax/Breakout-MinAtar", "gymnax/Catch-bsuite") for algo in DISCRETE_ACTIONS),
    ("gymnax/PointRobot-misc", "ppo"),
    ("ALE/Breakout-v5", "ppo"),
    ("ALE/Breakout-v5", "dqn"),
    *((f"{OWN}{env}", algo) for env in ("Masked-Dict-v0", "Picture48-v0") for algo in DISCRETE_ACTIONS),
    *((f"{OWN}{env}", "ppo") for env in ("Match-MultiDiscrete-v0", "Match-MultiBinary-v0")),
    *((f"{OWN}{env}", "ppo") for env in ("Bad-Graph-v0", "Bad-Text-v0", "Bad-Nested-v0", "Bad-No-Legal-v0")),
]
"""(env id, algorithm): Gymnasium's classic control, toy text, Box2D and MuJoCo, gymnax, Atari, and
envs of one's own (:mod:`own_envs`), the refused ones last."""


def one_line(text: str) -> str:
    """The last non-empty line of ``text`` (an error's own line, or a traceback's last)."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else ""


def survey(env_id: str, algo: str, total_steps: int, timeout: float, root: Path) -> dict:
    """One ``agentax train`` in a fresh process: its exit code and evaluation, or its last line."""
    out = root / f"{algo}-{env_id.replace('/', '_').replace(':', '_')}"
    command = [sys.executable, "-m", "agentax.cli", "train", algo, "--env", env_id]
    command += ["--total-steps", str(total_steps), "--out", str(out), "--no-progress"]
    start = time.perf_counter()
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        code, err = done.returncode, done.stderr
    except subprocess.TimeoutExpired:
        code, err = "timeout", f"no end after {timeout:g} s"
    seconds = time.perf_counter() - start
    if code == 0 and (out / "eval.json").is_file():
        stats = json.loads((out / "eval.json").read_text())
        result = f"{stats['mean_return']:.2f} ± {stats['std_return']:.2f} ({stats['episodes']} episodes)"
    else:
        result = one_line(err)
        if "Traceback" in err:
            result = f"TRACEBACK: {result}"
    return {"env": env_id, "algo": algo, "exit": code, "seconds": round(seconds, 1), "result": result}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--total-steps", type=int, default=2048)
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per run")
    parser.add_argument("--only", action="append", default=[], help="run the pairs whose env id has this")
    parser.add_argument("--algo", action="append", default=[], help="run only these algorithms")
    parser.add_argument("--json", help="also write the rows to this file")
    args = parser.parse_args(argv)
    pairs = [
        (env, algo)
        for env, algo in PAIRS
        if (not args.only or any(part in env for part in args.only)) and (not args.algo or algo in args.algo)
    ]
    rows = []
    with tempfile.TemporaryDirectory(prefix="agentax-survey-") as root:
        for env_id, algo in pairs:
            rows.append(survey(env_id, algo, args.total_steps, args.timeout, Path(root)))
            row = rows[-1]
            print(
                f"{row['env']:36} {row['algo']:5} {row['exit']!s:7} {row['seconds']:6}s  {row['result']}",
                flush=True,
            )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    print("\n| env | algo | exit | evaluation or error |\n| --- | --- | --- | --- |")
    for row in rows:
        print(f"| {row['env']} | {row['algo']} | {row['exit']} | {row['result'].replace('|', '/')} |")
    trained = sum(row["exit"] == 0 for row in rows)
    print(
        f"\n{trained} of {len(rows)} trained; {sum('TRACEBACK' in row['result'] for row in rows)} tracebacks"
    )
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.exit(main())
