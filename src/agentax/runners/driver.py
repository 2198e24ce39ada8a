"""A TF-Agents-style Driver for host environments and its observers.

The vocabulary is TF-Agents' (see the lecture's last part): a **Driver** steps an environment with
a **collect policy** and hands every transition to its **observers** — plain callables such as the
replay buffer's add and the metrics ``EnvironmentSteps``, ``NumberOfEpisodes``, ``AverageReturn``,
``AverageEpisodeLength``. The driver knows nothing of learning; collection state goes in and out::

    driver = Driver(env, policy, observers=[replay_observer, returns, steps], max_steps=4)
    time_step, policy_state = driver.run(time_step, policy_state)

``env`` is an ``agentax.envs.gym.GymnasiumEnv`` (any Gymnasium env or vector env; its ``step`` returns
agentax's ``TimeStep`` with NumPy arrays ``[num_envs, ...]``) or anything with the same ``reset`` /
``step``. ``policy(obs, policy_state) -> (action, policy_state)`` acts on the batch of observations;
a policy may also return ``(action, policy_state, info)``, TF-Agents' policy info (PPO's
log-probabilities and values), which reaches the observers as ``transition.info``.

The runners (``agentax.runners.host``, ``agentax.runners.parallel``) build their loops from these.
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
    """Steps ``env`` with ``policy`` and calls each observer with every transition ``[num_envs]``.

    ``run`` stops after ``max_steps`` env steps (summed over envs) or ``max_episodes`` finished
    episodes, whichever comes first (at least one must be set), as TF-Agents' step and episode drivers.
    """

    env: Any
    policy: CollectPolicy
    observers: Sequence[Observer] = ()
    max_steps: int | None = None
    max_episodes: int | None = None
    action_to_env: Callable[[np.ndarray], np.ndarray] | None = None
    """what the env receives for the policy's action (PPO clips continuous actions); the
    transition keeps the action itself"""

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
    """The mean of a per-episode sum of ``quantity(transition)`` over the last ``buffer_size``
    finished episodes (NaN before the first)."""

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
    """Adds each transition ``[num_envs]`` to a host replay buffer (``buffer.add_batch``, as
    :class:`agentax.replay.host.ReplayBuffer`), through the n-step accumulator when ``n_step > 1``
    (:class:`agentax.replay.host.NStepAccumulator`, the NumPy twin of the compiled runner's) unless
    the buffer builds n-step transitions itself (``handles_n_step``, as
    :class:`agentax.replay.frames.FrameReplayBuffer`): it is then given one-step transitions.

    ``envs`` (an int array or a slice; None: all) names the buffer's env streams this observer's
    envs are, in order: an actor that steps a share of the envs of a shared buffer passes its share
    (``add_batch(transition, envs=envs)``; a buffer of whole transitions ignores it)."""

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
    """The line for a policy that gave a NaN or infinite continuous action, saying where it came from."""
    if not np.isfinite(np.asarray(obs, np.float64)).all():
        return "non-finite action from a non-finite observation: the env gave NaN or infinity"
    return "non-finite action from finite observations: lower the learning rate or clip the gradients"
