"""Runners: where and when an algorithm's pure functions run.

``compiled`` trains JAX envs inside one jitted, vmapped-over-seeds program; ``host`` steps
Gymnasium envs on the host and calls the same jitted ``act`` and ``learn``.
"""
