"""agentax: reinforcement learning in JAX, from the textbook's 3-state MDP to Atari."""

from agentax import _xla

_xla.create_cpu_client_on_one_cpu()  # the cure for the XLA CPU hang (see _xla.py)

from agentax.envs import make  # noqa: E402  (registers the JAX envs in Gymnasium as agentax/ID)
from agentax.evaluate import EvalStats, HostPolicy, evaluate  # noqa: E402

__version__ = "0.1.0"

# After the envs (the package's import order). ``agentax.train(...)`` trains (agentax.api.train)
# although ``agentax.train`` is the runners' subpackage: that module is callable (see
# agentax/train/__init__.py), so it is imported here, neither shadowed nor shadowing.
from agentax import train  # noqa: E402
from agentax.api import Run, load  # noqa: E402

__all__ = ["EvalStats", "HostPolicy", "Run", "evaluate", "load", "make", "train"]
