"""Small Gymnasium envs of one's own with the spaces a practitioner brings (issue 41), registered on
import: ``agentax train ppo --env scripts.own_envs:Match-MultiDiscrete-v0`` from the repository root
(Gymnasium's ``module:id`` imports the module first), or ``import scripts.own_envs`` in Python.

Each rewards the agent for matching a part of its observation, so the optimum is known: 1 a step,
``EPISODE`` steps an episode. The survey (``scripts/env_survey.py``) and ``tests/test_host_spaces.py``
train on them; ``BAD`` are spaces agentax refuses in one line.
"""

from __future__ import annotations

import abc

import gymnasium
import numpy as np
from gymnasium import spaces

EPISODE = 8
"""Steps of an episode: the best return of every env here."""


class _Matching(gymnasium.Env, abc.ABC):
    """A target drawn each step; reward 1 where the action matches it, else 0."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, render_mode=None):
        self.render_mode, self._steps = render_mode, 0

    def render(self):
        """The target's entries as lit cells of a strip, 16 pixels each."""
        cells = np.asarray(self.target, np.int64).reshape(-1)
        if cells.size == 1:
            cells = np.eye(self.action_space.n)[int(cells[0])]
        strip = np.repeat(np.repeat(np.minimum(cells[None, :, None] * 80 + 40, 255), 16, 0), 16, 1)
        return np.broadcast_to(strip, (*strip.shape[:2], 3)).astype(np.uint8)

    @abc.abstractmethod
    def _target(self) -> None:
        """Draw ``self.target``, what the next action must match."""

    @abc.abstractmethod
    def _obs(self):
        """The observation that shows ``self.target``."""

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._steps = 0
        self._target()
        return self._obs(), self._info()

    def _info(self) -> dict:
        return {}

    def _reward(self, action) -> float:
        return float(np.array_equal(np.asarray(action).reshape(-1), np.asarray(self.target).reshape(-1)))

    def step(self, action):
        reward = self._reward(action)
        self._steps += 1
        self._target()
        return self._obs(), reward, False, self._steps >= EPISODE, self._info()


class MaskedDict(_Matching):
    """A Dict observation: the target's one-hot ``cue`` [4] and a ``position`` in [0, 1], with an
    ``action_mask`` (MultiBinary(4)) of the legal actions: the target and one other, drawn. A policy
    that ignores the mask still finds the target; an illegal action pays -1."""

    observation_space = spaces.Dict(
        {
            "cue": spaces.Box(0.0, 1.0, (4,), np.float32),
            "position": spaces.Box(0.0, 1.0, (1,), np.float32),
            "action_mask": spaces.MultiBinary(4),
        }
    )
    action_space = spaces.Discrete(4)

    def _target(self):
        self.target = int(self.np_random.integers(4))
        self.other = int((self.target + 1 + self.np_random.integers(3)) % 4)

    def _obs(self):
        mask = np.zeros(4, np.int8)
        mask[[self.target, self.other]] = 1
        cue = np.eye(4, dtype=np.float32)[self.target]
        return {"cue": cue, "position": np.array([self._steps / EPISODE], np.float32), "action_mask": mask}

    def _reward(self, action):
        if int(action) not in (self.target, self.other):
            return -1.0
        return float(int(action) == self.target)


class MatchMultiDiscrete(_Matching):
    """A MultiDiscrete observation [3, 4] and action: play the observation back."""

    observation_space = spaces.MultiDiscrete([3, 4])
    action_space = spaces.MultiDiscrete([3, 4])

    def _target(self):
        self.target = self.observation_space.sample()

    def _obs(self):
        return np.asarray(self.target, np.int64)


class MatchMultiBinary(_Matching):
    """A MultiBinary(4) observation and action: play the switches back."""

    observation_space = spaces.MultiBinary(4)
    action_space = spaces.MultiBinary(4)

    def _target(self):
        self.target = self.np_random.integers(0, 2, 4).astype(np.int8)

    def _obs(self):
        return self.target.copy()


class Picture(_Matching):
    """48×48 RGB pictures ``[H, W, C]`` uint8: one of three colour channels lit; name it."""

    observation_space = spaces.Box(0, 255, (48, 48, 3), np.uint8)
    action_space = spaces.Discrete(3)

    def _target(self):
        self.target = int(self.np_random.integers(3))

    def _obs(self):
        image = np.zeros((48, 48, 3), np.uint8)
        image[..., self.target] = 255
        return image


class Spaces(gymnasium.Env):
    """An env whose observation (and action) spaces are given: for spaces agentax refuses."""

    def __init__(self, observation_space=None, action_space=None, info=None):
        self.observation_space = observation_space or spaces.Box(0.0, 1.0, (2,), np.float32)
        self.action_space = action_space or spaces.Discrete(2)
        self.info = info or {}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return self.observation_space.sample(), dict(self.info)

    def step(self, action):
        return self.observation_space.sample(), 0.0, False, False, dict(self.info)


BAD = {
    "Bad-Graph-v0": dict(
        observation_space=spaces.Graph(spaces.Box(0.0, 1.0, (2,)), spaces.Discrete(2)),
    ),
    "Bad-Text-v0": dict(observation_space=spaces.Text(8)),
    "Bad-Sequence-v0": dict(observation_space=spaces.Sequence(spaces.Box(0.0, 1.0, (2,)))),
    "Bad-Nested-v0": dict(
        observation_space=spaces.Dict({"arm": spaces.Dict({"joints": spaces.Box(0.0, 1.0, (2,))})}),
    ),
    "Bad-Text-Actions-v0": dict(action_space=spaces.Text(4)),
    "Bad-No-Legal-v0": dict(info={"action_mask": np.zeros(2, np.int8)}),
}
"""Envs of spaces agentax refuses: id → the ``Spaces`` keywords."""

OWN = {
    "Masked-Dict-v0": MaskedDict,
    "Match-MultiDiscrete-v0": MatchMultiDiscrete,
    "Match-MultiBinary-v0": MatchMultiBinary,
    "Picture48-v0": Picture,
}
"""The envs that train: id → class."""

for _id, _cls in OWN.items():
    if _id not in gymnasium.registry:
        gymnasium.register(_id, entry_point=_cls, max_episode_steps=EPISODE)
for _id, _kwargs in BAD.items():
    if _id not in gymnasium.registry:
        gymnasium.register(_id, entry_point=Spaces, kwargs=_kwargs, max_episode_steps=EPISODE)
