"""agentax: reinforcement learning in JAX, from the textbook's 3-state MDP to Atari."""

from agentax import _xla

_xla.pin_cpu()  # before jax starts its CPU client: the cure for the XLA CPU hang (see _xla.py)

from agentax.evaluate import EvalStats, evaluate  # noqa: E402

__version__ = "0.1.0"
__all__ = ["EvalStats", "evaluate"]
