"""agentax: reinforcement learning in JAX, from the textbook's 3-state MDP to Atari."""

from agentax.evaluate import EvalStats, evaluate

__version__ = "0.1.0"
__all__ = ["EvalStats", "evaluate"]
