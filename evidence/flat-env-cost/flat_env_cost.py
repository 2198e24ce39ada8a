"""Issue 41's "the flat envs cost nothing" check: an old commit's agentax against today's, one run.

Each case's command runs under both trees, interleaved (old, new, old, new, ...), each tree with its
own persistent compilation cache (warmed by one untimed run each first, so the timed runs compare
training, not compiling). Prints a table of medians and the new/old ratios, and whether the
evaluation each run prints is the same old vs new for the same seed.

    python evidence/flat-env-cost/flat_env_cost.py --old-src /tmp/old-9bc6395/src \
        --new-src /work/main/src --repeats 3 --json benchmarks/results/flat_env_cost.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CASES = {
    # name: (runner note, train arguments)
    "ppo-cartpole": ("compiled", "ppo --env CartPole-v1 --seeds 8 --total-steps 200000"),
    "dqn-cartpole": ("host", "dqn --env CartPole-v1 --runner host --total-steps 20000"),
    "pqn-breakout": ("compiled", "pqn --env gymnax/Breakout-MinAtar --total-steps 200000"),
    "ppo-cartpole-full": (
        "compiled",
        "ppo --env CartPole-v1 --seeds 8 --total-steps 200000 --stop-at-return none",
    ),
}

SUMMARY = re.compile(r"compile ([\d.]+) s, training ([\d.]+) s, total ([\d.]+) s")


def run_once(python: str, src: str, cache: str, args: str, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=src, AGENTAX_JAX_CACHE=cache)
    cmd = [python, "-m", "agentax.cli", "train", *args.split(), "--no-progress", "--out", str(out)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    text = proc.stdout + proc.stderr
    if proc.returncode != 0:
        sys.exit(f"failed ({proc.returncode}): {' '.join(cmd)}\n{text[-3000:]}")
    row = {"wall": wall, "compile": None, "training": None}
    m = SUMMARY.search(text)
    if m:
        row["compile"], row["training"] = float(m.group(1)), float(m.group(2))
    else:  # the host runner prints no summary line: its last metrics row's wall_seconds
        lines = (out / "metrics.csv").read_text().splitlines()
        head, last = lines[0].split(","), lines[-1].split(",")
        row["training"] = float(last[head.index("wall_seconds")])
    row["eval_line"] = next((l for l in text.splitlines() if l.startswith("evaluation:")), None)
    row["eval"] = json.loads((out / "eval.json").read_text())
    if "train_seconds" in row["eval"]:  # the "training X s" the CLI prints, unrounded
        row["training"] = row["eval"]["train_seconds"]
    return row


def results(row: dict) -> dict:
    """The evaluation without its timings (train_seconds, compile_seconds, solved_seconds)."""
    return {k: v for k, v in row["eval"].items() if not k.endswith("_seconds")}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--old-src", required=True)
    p.add_argument("--new-src", required=True)
    p.add_argument("--python", default=sys.executable)
    p.add_argument("--old-cache", default="/tmp/cache-old")
    p.add_argument("--new-cache", default="/tmp/cache-new")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    p.add_argument("--no-warm", action="store_true", help="skip the untimed warm-up runs")
    p.add_argument("--json", help="write every run's figures here")
    a = p.parse_args()

    trees = {"old": (a.old_src, a.old_cache), "new": (a.new_src, a.new_cache)}
    work = Path(tempfile.mkdtemp(prefix="flat-env-cost-"))
    runs: dict[str, dict[str, list]] = {c: {"old": [], "new": []} for c in a.cases}

    if not a.no_warm:
        for case in a.cases:
            for tree, (src, cache) in trees.items():
                r = run_once(a.python, src, cache, CASES[case][1], work / f"warm-{case}-{tree}")
                print(f"warm  {case:18s} {tree}: wall {r['wall']:.1f} s", flush=True)
    for i in range(a.repeats):
        for case in a.cases:
            for tree, (src, cache) in trees.items():  # old, then new
                r = run_once(a.python, src, cache, CASES[case][1], work / f"{case}-{tree}-{i}")
                runs[case][tree].append(r)
                print(f"rep {i} {case:18s} {tree}: training {r['training']:.2f} s, "
                      f"wall {r['wall']:.2f} s, compile {r['compile']}", flush=True)

    def med(rows, key):
        vals = [r[key] for r in rows if r[key] is not None]
        return statistics.median(vals) if vals else None

    def fmt(x, spec=".2f"):
        return "–" if x is None else format(x, spec)

    print()
    print("| case | runner | training old (s) | training new (s) | new/old | wall old (s) "
          "| wall new (s) | new/old | compile old (s) | compile new (s) | evaluation old = new |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for case in a.cases:
        o, n = runs[case]["old"], runs[case]["new"]
        to, tn, wo, wn = med(o, "training"), med(n, "training"), med(o, "wall"), med(n, "wall")
        same = all(results(r) == results(o[0]) for r in o + n)
        print(f"| {case} | {CASES[case][0]} | {fmt(to)} | {fmt(tn)} | {fmt(tn / to, '.3f')} "
              f"| {fmt(wo)} | {fmt(wn)} | {fmt(wn / wo, '.3f')} | {fmt(med(o, 'compile'))} "
              f"| {fmt(med(n, 'compile'))} | {'yes' if same else 'NO'} |")
    print()
    for case in a.cases:
        lines = {r["eval_line"] for t in ("old", "new") for r in runs[case][t]}
        print(f"{case}: " + (" / ".join(sorted(lines))))
    if a.json:
        Path(a.json).write_text(json.dumps({"cases": {c: CASES[c][1] for c in a.cases},
                                            "repeats": a.repeats, "runs": runs}, indent=1) + "\n")


if __name__ == "__main__":
    main()
