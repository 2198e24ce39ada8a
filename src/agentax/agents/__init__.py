"""Learning agents, one module per algorithm family: pure ``init`` / ``act`` / ``learn`` functions.

``reinforce`` (the lecture's policy gradient, with an optional learned baseline), ``ppo``
(clipped policy optimisation with GAE), ``dqn`` (deep Q-learning and its variants). Each exposes
``make_train(env, cfg)`` for the compiled runner and ``load_policy(run_dir, config)`` for
``agentax.runs.load_policy``.
"""
