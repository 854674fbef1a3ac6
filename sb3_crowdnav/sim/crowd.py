"""The crowd-model seam: one small protocol that moves the people of the open floor, and its models by name.

A crowd model receives the episode's :class:`~sb3_crowdnav.sim.population.People` at reset and, each step, their
preferred velocities (the population's: towards the goal at each person's speed, zero while standing) and the
robot's state; it returns the people's new positions and velocities. Who sees the robot is the population's
(``People.sees_robot``); how a person avoids it is the model's. The simulator never asks which model it has, and
nothing above the simulator sees it: the observation is the same whatever moves the people.

A new model is a class with this constructor and these two methods, its settings (``crowd_kwargs``) a frozen
dataclass in :mod:`sb3_crowdnav.sim.crowd_settings`, and a line in :data:`CROWD_MODELS`. A model that brings its own
episodes, whose people come and go (``"replay"``, :mod:`sb3_crowdnav.sim.replay`), is a :class:`RecordedCrowd`.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.crowd_settings import LinearCrowdSettings, OrcaCrowdSettings
from sb3_crowdnav.sim.orca import OrcaCrowd
from sb3_crowdnav.sim.population import People
from sb3_crowdnav.sim.replay import ReplayCrowdModel
from sb3_crowdnav.sim.scenarios import Scenario


class RobotAgent(NamedTuple):
    """The robot as the people see it [m, m/s]."""

    position: tuple[float, float]
    velocity: tuple[float, float]
    radius: float


class CrowdModel(Protocol):
    """What moves the people: built once per env from the scene (its ``crowd_kwargs``), reset per episode."""

    def reset(self, rng: np.random.Generator, people: People, robot: RobotAgent) -> None:
        """Start an episode with ``people`` at their starts, at rest; ``rng`` for a model's own randomness."""

    def step(self, preferred: list[tuple[float, float]], robot: RobotAgent) -> tuple[np.ndarray, np.ndarray]:
        """Advance one time step; the people's new positions and velocities, each (n, 2).

        :param preferred: each person's preferred velocity for this step
        :param robot: the robot's state at the start of the step
        """


@runtime_checkable
class RecordedCrowd(CrowdModel, Protocol):
    """A crowd model that brings its own episodes (a recording): it places the robot and the people at reset, and its
    people come and go. The simulator then takes the scenario from :meth:`draw_scenario` instead of drawing one, and
    after the reset and each step reads who is present; its ``n`` slots are the episode's (at most ``max_humans``),
    an absent person's slot padded (zeros, mask 0) and a slot a person arrives in starting its history anew (its
    first state repeated, as at reset)."""

    present: np.ndarray  # (n,) bool: who is present after the reset or the last step
    arrivals: np.ndarray  # (n,) bool: the slots a person took at the reset or the last step
    velocities: np.ndarray  # (n, 2) [m/s] the people's velocities at the episode's first step

    def draw_scenario(self, rng: np.random.Generator) -> Scenario:
        """The episode's places (``human_starts`` (n, 2), zeros in an empty slot); ``rng`` for its draws."""


class OrcaCrowdModel:
    """People driven by ORCA (RVO2 through pyrvo), the paper's crowd.

    Those who see the robot have it as one more ORCA agent, moved each step to its actual position and velocity;
    the others ignore it. With everyone on one side, one RVO2 simulator runs (with or without the robot); with a
    mixed crowd, two (with and without the robot), both put in the people's actual state before each step, each
    person taking its new state from the simulator of its side: ORCA computes a person's velocity from its
    neighbours' current states only, so this is each person avoiding exactly the agents it sees.
    """

    def __init__(self, scene: SceneConfig) -> None:
        self.scene = scene
        self.settings: OrcaCrowdSettings = scene.crowd_kwargs
        self.crowds: list[OrcaCrowd] = []
        self.seeing = np.zeros(0, dtype=bool)

    def reset(self, rng: np.random.Generator, people: People, robot: RobotAgent) -> None:
        radii = people.radii + self.settings.safety_space
        robot_agent = (np.array(robot.position), np.array(robot.velocity), robot.radius)
        self.seeing = people.sees_robot.copy()
        sides = [bool(s) for s in np.unique(self.seeing)]  # [False], [True] or [False, True]
        self.crowds = [OrcaCrowd(self.scene, people.starts, radii, people.v_prefs, robot_agent if side else None)
                       for side in sides]

    def step(self, preferred: list[tuple[float, float]], robot: RobotAgent) -> tuple[np.ndarray, np.ndarray]:
        robot_state = (robot.position, robot.velocity)
        if len(self.crowds) == 1:
            return self.crowds[0].step(preferred, robot_state)
        blind, seeing = self.crowds
        pos_b, vel_b = blind.step(preferred)
        pos_s, vel_s = seeing.step(preferred, robot_state)
        side = self.seeing[:, None]
        positions, velocities = np.where(side, pos_s, pos_b), np.where(side, vel_s, vel_b)
        for crowd in self.crowds:
            crowd.set_agents(positions, velocities)
        return positions, velocities


class LinearCrowdModel:
    """People who walk at their preferred velocity, seeing no one (exact integration; for tests)."""

    def __init__(self, scene: SceneConfig) -> None:
        self.time_step = scene.time_step
        self.settings: LinearCrowdSettings = scene.crowd_kwargs
        self.positions: list[list[float]] = []

    def reset(self, rng: np.random.Generator, people: People, robot: RobotAgent) -> None:
        self.positions = people.starts.tolist()

    def step(self, preferred: list[tuple[float, float]], robot: RobotAgent) -> tuple[np.ndarray, np.ndarray]:
        dt = self.time_step
        self.positions = [[x + vx * dt, y + vy * dt] for (x, y), (vx, vy) in zip(self.positions, preferred, strict=True)]
        n = len(preferred)
        return np.array(self.positions).reshape(n, 2), np.array(preferred, dtype=np.float64).reshape(n, 2)


# every crowd model by its name (the env's crowd=); CROWD_SETTINGS has their settings under the same names
CROWD_MODELS: dict[str, type] = {
    "orca": OrcaCrowdModel,
    "linear": LinearCrowdModel,
    "replay": ReplayCrowdModel,
}


def make_crowd(scene: SceneConfig) -> CrowdModel:
    """The crowd model ``scene.crowd`` with its settings ``scene.crowd_kwargs``."""
    return CROWD_MODELS[scene.crowd](scene)


__all__ = ["CROWD_MODELS", "CrowdModel", "LinearCrowdModel", "OrcaCrowdModel", "RecordedCrowd", "ReplayCrowdModel",
           "RobotAgent", "make_crowd"]
