"""agentax: reinforcement learning in JAX, from the textbook's 3-state MDP to Atari."""

from agentax import _xla

_xla.create_cpu_client_on_one_cpu()  # the cure for the XLA CPU hang (see _xla.py)

from agentax.api import Run, load, train  # noqa: E402
from agentax.envs import make  # noqa: E402  (registers the JAX envs in Gymnasium as agentax/ID)
from agentax.evaluate import EvalStats, HostPolicy, evaluate  # noqa: E402

__version__ = "0.1.0"

__all__ = ["EvalStats", "HostPolicy", "Run", "evaluate", "load", "make", "train"]
