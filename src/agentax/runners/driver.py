"""A TF-Agents-style Driver for host environments and its observers.

A **Driver** steps an env (``agentax.envs.gym.GymnasiumEnv`` or the like: ``step`` returns a
``TimeStep`` of arrays ``[num_envs, ...]``) with a **collect policy** ``policy(obs, policy_state) ->
(action, policy_state[, info])`` and hands every transition to its **observers**, plain callables::

    driver = Driver(env, policy, observers=[replay_observer, returns, steps], max_steps=4)
    time_step, policy_state = driver.run(time_step, policy_state)
"""

from __future__ import annotations

import collections
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import numpy as np

from agentax.envs.core import TimeStep
from agentax.errors import TrainingDiverged
from agentax.replay import Transition
from agentax.replay.host import NStepAccumulator

Observer = Callable[[Transition], None]
CollectPolicy = Callable[[np.ndarray, Any], tuple]  # (obs, policy_state) -> (action, policy_state[, info])


def first_time_step(env: Any, seed: int | None = None) -> TimeStep:
    """The time step a driver starts from: the envs' first observations ``[num_envs, ...]``."""
    obs = np.asarray(env.reset(seed=seed))
    zeros = np.zeros(len(obs), bool)
    reward = np.zeros(len(obs), np.float32)
    return TimeStep(obs=obs, reward=reward, terminated=zeros, truncated=zeros, final_obs=obs)


@dataclass
class Driver:
    """Steps ``env`` with ``policy`` and calls each observer with every transition ``[num_envs]``;
    ``run`` stops after ``max_steps`` env steps (summed over envs) or ``max_episodes`` episodes,
    whichever comes first (one must be set)."""

    env: Any
    policy: CollectPolicy
    observers: Sequence[Observer] = ()
    max_steps: int | None = None
    max_episodes: int | None = None
    action_to_env: Callable[[np.ndarray], np.ndarray] | None = None
    """what the env receives for an action (PPO clips continuous ones); the transition keeps the action"""

    def __post_init__(self):
        if self.max_steps is None and self.max_episodes is None:
            raise ValueError("a Driver needs max_steps or max_episodes")

    def run(self, time_step: TimeStep, policy_state: Any) -> tuple[TimeStep, Any]:
        """Collect until a limit is reached; returns the time step and policy state to continue from."""
        steps = episodes = 0
        max_steps = np.inf if self.max_steps is None else self.max_steps
        max_episodes = np.inf if self.max_episodes is None else self.max_episodes
        while steps < max_steps and episodes < max_episodes:
            action, policy_state, *info = self.policy(time_step.obs, policy_state)
            action = np.asarray(action)
            if action.dtype.kind == "f" and not np.isfinite(action).all():
                raise TrainingDiverged(non_finite_action(time_step.obs))
            env_action = action if self.action_to_env is None else np.asarray(self.action_to_env(action))
            next_time_step = self.env.step(env_action)
            transition = Transition(
                obs=time_step.obs,
                action=action,
                reward=np.asarray(next_time_step.reward, np.float32),
                next_obs=np.asarray(next_time_step.final_obs),
                terminated=np.asarray(next_time_step.terminated, bool),
                truncated=np.asarray(next_time_step.truncated, bool),
                num_steps=np.ones(len(action), np.int32),
                info=info[0] if info else None,
            )
            for observer in self.observers:
                observer(transition)
            steps += len(action)
            episodes += int(np.sum(transition.terminated | transition.truncated))
            time_step = next_time_step
        return time_step, policy_state


# ---------------------------------------------------------------- metric observers


@dataclass
class EnvironmentSteps:
    """Env steps seen, summed over envs."""

    count: int = 0

    def __call__(self, transition: Transition) -> None:
        self.count += len(transition.reward)

    def result(self) -> int:
        return self.count


@dataclass
class NumberOfEpisodes:
    """Episodes finished (terminated or truncated)."""

    count: int = 0

    def __call__(self, transition: Transition) -> None:
        self.count += int(np.sum(transition.terminated | transition.truncated))

    def result(self) -> int:
        return self.count


@dataclass
class EpisodeAverage:
    """The mean per-episode sum of ``quantity(transition)`` over the last ``buffer_size`` episodes."""

    quantity: Callable[[Transition], np.ndarray]
    buffer_size: int | None = 10  # None: every episode
    running: np.ndarray | None = None
    finished: collections.deque = field(default_factory=collections.deque)

    def __call__(self, transition: Transition) -> None:
        if self.running is None:
            self.running = np.zeros(len(transition.reward))
            self.finished = collections.deque(maxlen=self.buffer_size)
        self.running += self.quantity(transition)
        done = transition.terminated | transition.truncated
        self.finished.extend(self.running[done].tolist())
        self.running[done] = 0.0

    def result(self) -> float:
        return float(np.mean(self.finished)) if self.finished else float("nan")


class AverageReturn(EpisodeAverage):
    """The mean return of the last ``buffer_size`` finished episodes."""

    def __init__(self, buffer_size: int = 10):
        super().__init__(quantity=lambda transition: transition.reward, buffer_size=buffer_size)


class AverageEpisodeLength(EpisodeAverage):
    """The mean length of the last ``buffer_size`` finished episodes."""

    def __init__(self, buffer_size: int = 10):
        super().__init__(quantity=lambda transition: np.ones(len(transition.reward)), buffer_size=buffer_size)


# ---------------------------------------------------------------- replay as an observer


class ReplayObserver:
    """Adds each transition ``[num_envs]`` to a host replay buffer (``buffer.add_batch``), through an
    n-step accumulator where ``n_step > 1`` and the buffer does not build them itself
    (``handles_n_step``). ``envs`` (indices or a slice; None: all) are the buffer's env streams this
    observer's envs are: an actor's share of a shared buffer."""

    def __init__(self, buffer: Any, n_step: int = 1, discount_factor: float = 0.99, envs: Any = None):
        self.buffer = buffer
        self.envs = envs
        one_step = n_step == 1 or getattr(buffer, "handles_n_step", False)
        self.accumulator = None if one_step else NStepAccumulator(n_step, discount_factor)

    def __call__(self, transition: Transition) -> None:
        transition = transition.replace(info=None)
        if self.accumulator is not None:
            transition = self.accumulator.push(transition)
            if transition is None:
                return
        self.buffer.add_batch(transition, envs=self.envs)


class TrajectoryObserver:
    """Keeps every transition it sees; ``trajectory()`` stacks them time-major ``[T, num_envs, ...]``."""

    def __init__(self):
        self.transitions: list[Transition] = []

    def __call__(self, transition: Transition) -> None:
        self.transitions.append(transition)

    def trajectory(self) -> Transition:
        trajectory = jax.tree.map(lambda *xs: np.stack(xs), *self.transitions)
        self.transitions = []
        return trajectory


class FinishedReturns(EpisodeAverage):
    """The returns of the episodes finished since the last ``drain()`` (for a runner's log rows)."""

    def __init__(self):
        super().__init__(quantity=lambda transition: transition.reward, buffer_size=None)

    def drain(self) -> list[float]:
        finished = list(self.finished)
        self.finished.clear()
        return finished


def non_finite_action(obs: np.ndarray) -> str:
    """Why a policy gave a NaN or infinite continuous action, in one line."""
    if not np.isfinite(np.asarray(obs, np.float64)).all():
        return "non-finite action from a non-finite observation: the env gave NaN or infinity"
    return "non-finite action from finite observations: lower the learning rate or clip the gradients"
