"""Runners: where and when an algorithm's pure functions run.

``compiled`` trains JAX envs inside one jitted, vmapped-over-seeds program (and PPO on Atari with
EnvPool's step inside the program, ``compiled_atari``); ``host`` steps any env on the host with a
Driver, one step after the other; ``parallel`` runs the host runner's actors in threads beside a
learner, ``ray`` in Ray actor processes on any node of a cluster. ``agentax.train`` (in
:mod:`agentax.api`) chooses one; :func:`agentax.api.restore_policy` reads any run back.
"""

RUNNERS = ("compiled", "host", "parallel", "ray")
