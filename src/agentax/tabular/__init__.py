"""Tabular RL: planning with a known model (value and Q-value iteration) and learning from samples
(TD(0), Q-learning, SARSA, Expected SARSA, Double Q-learning, the exploration function)."""

from agentax.tabular.planning import (
    PlanningResult,
    greedy_policy,
    q_backup,
    q_value_iterates,
    q_value_iteration,
    state_values,
    value_iteration,
)
from agentax.tabular.qlearning import (
    ALGORITHMS,
    QLearningConfig,
    QLearningResult,
    epsilon_greedy_probabilities,
    exploration_values,
    q_learning,
)
from agentax.tabular.td import TDConfig, TDResult, episode_returns, td_error, td_learning, uniform_policy

__all__ = [
    "ALGORITHMS",
    "PlanningResult",
    "QLearningConfig",
    "QLearningResult",
    "TDConfig",
    "TDResult",
    "episode_returns",
    "epsilon_greedy_probabilities",
    "exploration_values",
    "greedy_policy",
    "q_backup",
    "q_learning",
    "q_value_iterates",
    "q_value_iteration",
    "state_values",
    "td_error",
    "td_learning",
    "uniform_policy",
    "value_iteration",
]
