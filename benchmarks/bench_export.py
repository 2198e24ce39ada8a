"""A trained policy as a file: ``agentax export`` of a PPO CartPole run to ONNX and to StableHLO.

One run of PPO's ``cartpole-fast`` preset (until solved) is exported to each format, in this
process, after the run's own greedy evaluation compiled. Each row gives the file's size, the
seconds ``Run.export`` took (the first ONNX export of a process pays for jax2onnx importing its
plugins and compiling ~70 small programs, from an empty compilation cache here), and the mean
return of 100 CartPole-v1 episodes played by the file (onnxruntime, or ``jax.export``'s
deserialized module, called back from agentax's evaluation) against the same 100 episodes played
by the trained policy in agentax, same seed: equal returns in every statistic say the file acts as
the policy does.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

EPISODES = 100


def run() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["AGENTAX_JAX_CACHE"] = str(Path(tmp) / "jax-cache")  # empty: a new machine's first export
        import agentax
        from agentax import export

        trained = agentax.train(
            "ppo", env="CartPole-v1", preset="cartpole-fast", out=Path(tmp) / "run", progress=False
        )
        own = agentax.evaluate("CartPole-v1", trained.policy, EPISODES, seed=1)
        rows = []
        for format in ("onnx", "stablehlo"):
            start = time.perf_counter()
            path = trained.export(Path(tmp) / f"policy.{format}", format)
            seconds = time.perf_counter() - start
            played = agentax.evaluate("CartPole-v1", export.as_policy(export.load(path)), EPISODES, seed=1)
            same = all(
                getattr(played, field) == getattr(own, field)
                for field in ("mean_return", "std_return", "min_return", "max_return", "mean_length")
            )
            rows.append(
                [
                    format,
                    path.stat().st_size,
                    round(seconds, 2),
                    played.mean_return,
                    own.mean_return,
                    "yes" if same else "no",
                ]
            )
    return {
        "name": "export",
        "title": "A trained PPO CartPole policy exported (ONNX, StableHLO) and played from the file",
        "headers": [
            "format",
            "file bytes",
            "export s",
            f"file's mean return ({EPISODES} episodes)",
            "the policy's, same episodes",
            "equal statistics",
        ],
        "rows": rows,
        "notes": __doc__.split("\n\n", 1)[1].strip(),
    }


if __name__ == "__main__":
    print(run())
