"""Replay buffers: a jittable uniform ring buffer, a prioritized one on a sum-tree, NumPy twins.

Every buffer is a small namespace of pure functions over a state pytree::

    state = uniform.init(capacity, example_transition)   # storage with a leading [capacity] axis
    state = uniform.add(state, batch)                     # batch: leading [batch] axis, wraps around
    sample = uniform.sample(state, key, batch_size)       # ReplaySample(transition, indices, weights)

``prioritized`` adds ``update_priorities(state, indices, td_error)`` and a ``beta`` argument to
``sample``; ``host`` holds NumPy versions with the same functions for runners that step host
environments (``key`` is then a ``numpy.random.Generator``); ``nstep`` accumulates one-step transitions
into n-step ones before they are added. ``uniform.sample`` returns weights of
one, so a learner consumes either buffer's samples the same way.
"""

from agentax.replay import host, nstep, prioritized, uniform
from agentax.replay.core import ReplaySample, Transition, example_transition

__all__ = ["ReplaySample", "Transition", "example_transition", "host", "nstep", "prioritized", "uniform"]
