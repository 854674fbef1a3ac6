"""What the failure analysis (:mod:`sb3_crowdnav.evaluation.failures`) records of an episode beside its trajectory."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_crowdnav.evaluation.records import Trajectory
from sb3_crowdnav.sim.geometry import SEGMENT_DIM


@dataclass(frozen=True, eq=False)
class EpisodeLog:
    """What the analysis reads of an episode beside its :class:`Trajectory`, per state (the reset's first) and slot.

    :param seen: (steps + 1, n) bool, set in that observation's ``humans_mask``
    :param present: (steps + 1, n) bool, the simulator's presence mask
    :param arrivals: (steps + 1, n) bool, a new person took the slot at that state (a replay's people who come and go)
    :param actions: (steps,) the actions taken
    :param segments: (S, 4) the edges of the racks and walls (none on the open floor)
    :param sees_robot: (n,) bool, the people who see the robot (drawn at the reset for the episode; none given: nobody)
    """

    trajectory: Trajectory
    seen: np.ndarray
    present: np.ndarray
    arrivals: np.ndarray
    actions: np.ndarray
    segments: np.ndarray = field(default_factory=lambda: np.zeros((0, SEGMENT_DIM)))
    sees_robot: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.sees_robot is None:  # (frozen: set through object's own setter)
            object.__setattr__(self, "sees_robot", np.zeros(self.seen.shape[1], dtype=bool))


class EpisodeRecorder(gym.Wrapper):
    """An env wrapper that keeps the :class:`EpisodeLog` of the current episode (:meth:`log`); the episode is the
    wrapped env's, unchanged."""

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        self._rows, self._actions = [], []
        self._sees_robot = np.asarray(self.env.unwrapped.sim.sees_robot, dtype=bool).copy()
        self._keep(obs)
        return obs, info

    def step(self, action):
        result = self.env.step(action)
        self._actions.append(int(action))
        self._keep(result[0])
        return result

    def _keep(self, obs: Mapping[str, np.ndarray]) -> None:
        sim = self.env.unwrapped.sim
        n = sim.num_humans
        arrivals = np.array(sim.crowd.arrivals[:n], dtype=bool) if sim.recorded else np.zeros(n, dtype=bool)
        self._rows.append((sim.seen_people, sim.mask[:n].copy(), arrivals))  # (the people in obs["humans_mask"])

    def log(self, trajectory: Trajectory) -> EpisodeLog:
        """The log of the episode just played, with its ``trajectory`` (the runner's, ``keep_trajectory=True``)."""
        seen, present, arrivals = (np.stack(column) for column in zip(*self._rows, strict=True))
        segments = np.reshape(getattr(self.env.unwrapped.sim, "segments", np.zeros((0, SEGMENT_DIM))), (-1, SEGMENT_DIM))
        return EpisodeLog(trajectory, seen, present, arrivals, np.array(self._actions, dtype=np.int64), segments,
                          self._sees_robot)


__all__ = ["EpisodeLog", "EpisodeRecorder"]
