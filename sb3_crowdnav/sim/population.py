"""The people of an episode: who they are (speeds, who sees the robot, who stops and when), drawn at reset.

The population is the crowd model's input, whatever the model: :func:`draw_people` draws it from the scene's settings
and the scenario's starts and goals, :func:`preferred_velocities` says where each person wants to go at each step
(towards its goal at its preferred speed, or nowhere while it stands). The model (``sim/crowd.py``) moves them.

Nothing is drawn for a setting at its default (the paper's crowd), so the default episodes stay those of the paper's
env; otherwise the draws follow the scenario's in a fixed order: speeds, visibility, stops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from sb3_crowdnav.sim.config import MEASURED_SPEED, SceneConfig


@dataclass(frozen=True, eq=False)
class People:
    """The people of one episode (world frame), as a crowd model receives them at reset."""

    starts: np.ndarray  # (n, 2) [m]
    goals: np.ndarray  # (n, 2) [m]
    radii: np.ndarray  # (n,) [m]
    v_prefs: np.ndarray  # (n,) [m/s] preferred speeds
    sees_robot: np.ndarray  # (n,) bool: the robot is one of the agents this person avoids
    stop_start: np.ndarray  # (n,) [s] when the person stops (inf: never)
    stop_end: np.ndarray  # (n,) [s] when it walks on

    @property
    def n(self) -> int:
        return len(self.starts)


def draw_people(scene: SceneConfig, starts: np.ndarray, goals: np.ndarray, rng: np.random.Generator) -> People:
    """The population of ``scene`` for these starts and goals (n, 2), drawn from ``rng``."""
    n = len(starts)
    v_prefs = draw_speeds(scene, n, rng)
    sees = draw_sees_robot(scene.robot_visible, n, rng)
    stop_start, stop_end = np.full(n, math.inf), np.full(n, math.inf)
    if scene.stop_probability > 0:
        stops = rng.random(n) < scene.stop_probability
        walk_time = np.linalg.norm(goals - starts, axis=-1) / v_prefs  # [s] straight to the goal
        when = rng.uniform(0.0, 1.0, n) * walk_time
        duration = rng.uniform(*scene.stop_duration, n)
        stop_start = np.where(stops, when, math.inf)
        stop_end = np.where(stops, when + duration, math.inf)
    return People(np.asarray(starts, dtype=np.float64).reshape(n, 2), np.asarray(goals, dtype=np.float64).reshape(n, 2),
                  np.full(n, scene.human_radius), v_prefs, sees, stop_start, stop_end)


def draw_speeds(scene: SceneConfig, n: int, rng: np.random.Generator) -> np.ndarray:
    """The preferred speeds of ``n`` people, (n,) [m/s]: everyone at ``human_v_pref`` for ``human_speed="fixed"``
    (nothing drawn), else each from :data:`~sb3_crowdnav.sim.config.MEASURED_SPEED`, one ``rng.normal`` draw of n in
    the people's order, clipped (the open floor's people and the warehouse's pickers alike)."""
    if scene.human_speed == "measured":
        mean, sd, low, high = MEASURED_SPEED
        return np.clip(rng.normal(mean, sd, n), low, high)
    return np.full(n, scene.human_v_pref)


def draw_sees_robot(robot_visible: bool | float, n: int, rng: np.random.Generator) -> np.ndarray:
    """Who of ``n`` people sees the robot, (n,) bool: everyone or no one for a bool (nothing drawn), else each person
    with probability ``robot_visible`` (a share in (0, 1)), one ``rng.random(n)`` draw in the people's order."""
    if isinstance(robot_visible, bool):
        return np.full(n, robot_visible)
    return rng.random(n) < robot_visible


class PreferredVelocities:
    """Each person's preferred velocity at a time: towards its goal, of length its preferred speed and shorter only
    within that distance of the goal (so that people slow down there), zero while it stands.

    In Python floats: on N <= 10 people NumPy's per-call overhead costs more than the arithmetic (the numpy form is
    :func:`sb3_crowdnav.sim.orca.preferred_velocity`).
    """

    def __init__(self, people: People) -> None:
        self.goals = people.goals.tolist()
        self.v_prefs = people.v_prefs.tolist()
        self.stops = list(zip(people.stop_start.tolist(), people.stop_end.tolist(), strict=True))
        self.any_stop = bool(np.isfinite(people.stop_start).any())

    def at(self, positions: list[list[float]], time: float) -> list[tuple[float, float]]:
        """The preferred velocities of the people at ``positions`` (n x [x, y]) at ``time`` [s]."""
        out = []
        for (x, y), (gx, gy), v_pref in zip(positions, self.goals, self.v_prefs, strict=True):
            dx, dy = gx - x, gy - y
            norm = math.sqrt(dx * dx + dy * dy)
            if norm > v_pref:
                dx, dy = dx / max(norm, 1e-12) * v_pref, dy / max(norm, 1e-12) * v_pref
            out.append((dx, dy))
        if self.any_stop:
            out = [(0.0, 0.0) if start <= time < end else v for v, (start, end) in zip(out, self.stops, strict=True)]
        return out


MEASURED_POPULATION = MappingProxyType({
    "human_speed": "measured",
    "stop_probability": 0.2,
    "stop_duration": (2.0, 8.0),
    "robot_visible": 0.5,
})
"""The measured-speed population, the env keyword arguments of one preset (``gym.make("CrowdNav-v0",
**MEASURED_POPULATION)``): preferred speeds drawn per person from :data:`~sb3_crowdnav.sim.config.MEASURED_SPEED`
(Normal(1.34, 0.26) m/s clipped to [0.5, 2.0]), one person in five stopping once for 2-8 s [s], and each person
seeing the robot with probability 0.5. The speeds are measured; the stops and the share who see the robot are a
stated choice, not a measurement (``docs/decisions.md``). The generalisation table's "measured-speed population"."""

__all__ = ["MEASURED_POPULATION", "People", "PreferredVelocities", "draw_people", "draw_sees_robot", "draw_speeds"]
