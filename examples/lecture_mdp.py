"""The lecture's Markov decision processes section, step by step (Hands-On ML, chapter 18).

Run: ``python examples/lecture_mdp.py`` (writes ``lecture_mdp.png``). Each block prints what the
lecture shows: a Markov chain's sampled paths, Q-value iteration's table and best actions, TD(0)
and Q-learning from sampled transitions, and the exploration function on a chain.
"""

import jax
import numpy as np

from agentax.cli.solve import SolveArgs, plot
from agentax.envs.mdp import chain_mdp, lecture_markov_chain, lecture_mdp
from agentax.tabular import (
    QLearningConfig,
    TDConfig,
    greedy_policy,
    q_learning,
    q_value_iteration,
    td_learning,
)

np.set_printoptions(precision=2, suppress=True)

# Markov chain: 4 states, s3 terminal; a few sampled paths of at most 20 steps.
chain = lecture_markov_chain()
for seed in range(3):
    print("path:", np.asarray(chain.simulate(jax.random.key(seed), 0, 20)))

# Q-value iteration on the 3-state MDP (discount factor 0.90): Q(s0, ·) ≈ [18.92, 17.03, 13.62].
mdp = lecture_mdp()
planned = q_value_iteration(mdp, discount_factor=0.90)
print(f"Q-value iteration, {int(planned.num_iterations)} iterations to a residual below 1e-6:")
print(np.asarray(planned.values))
print("best actions:", np.asarray(greedy_policy(planned.values)))  # [0 0 1]

# TD(0) under the uniformly random exploration policy learns that policy's values.
print("TD(0) V of the random policy:", np.asarray(td_learning(jax.random.key(0), mdp, TDConfig()).values))

# Q-learning with the book's settings: α0 = 0.05, decay 0.005, 10,000 random steps; 8 seeds at once.
keys = jax.random.split(jax.random.key(42), 8)
learned = jax.vmap(lambda key: q_learning(key, mdp, QLearningConfig()))(keys)
print("Q-learning, mean over 8 seeds:")
print(np.asarray(learned.q_values).mean(0))

# Exploration: on a 20-state corridor with the reward at the far end, the exploration function
# f(Q, N) = Q + κ / (1 + N) gets there long before random exploration does.
corridor = chain_mdp(20)
for name, config in [
    ("random (ε = 1)", QLearningConfig(num_steps=4_000)),
    ("exploration function", QLearningConfig(num_steps=4_000, exploration="exploration-function")),
]:
    next_states = np.asarray(q_learning(jax.random.key(0), corridor, config).next_states)
    print(f"{name}: first reached the far end after {int(np.argmax(next_states == 19)) + 1} steps")

# The lecture's picture: Q-value iteration converges in < 20 iterations, Q-learning in thousands of steps.
plot(mdp, SolveArgs(mdp="lecture", method="q-learning"), "lecture_mdp.png")
print("wrote lecture_mdp.png")
