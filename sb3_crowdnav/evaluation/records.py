"""What an evaluation episode leaves: its :class:`EpisodeRecord` and, on request, its :class:`Trajectory`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from sb3_crowdnav.sim.config import SceneConfig


@dataclass(frozen=True, eq=False)
class Trajectory:
    """The states of one episode (``env.unwrapped.trajectory`` as arrays).

    :param robot: (steps + 1, 9) robot states [px, py, vx, vy, radius, gx, gy, v_pref, heading]
    :param humans: (steps + 1, n_humans, 5) pedestrian states [px, py, vx, vy, radius]
    :param human_goals: (n_humans, 2) [m]
    :param scene: the env's scene configuration (time step, geometry)
    :param obstacles: the static obstacles (racks, walls) as (k, 2) vertex arrays; empty on the open floor
    """

    robot: np.ndarray
    humans: np.ndarray
    human_goals: np.ndarray
    scene: SceneConfig
    obstacles: tuple[np.ndarray, ...] = ()

    @property
    def times(self) -> np.ndarray:
        """Time [s] of each state, (steps + 1,)."""
        return np.arange(len(self.robot)) * self.scene.time_step

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Trajectory):
            return NotImplemented
        return (self.scene == other.scene and np.array_equal(self.robot, other.robot)
                and np.array_equal(self.humans, other.humans)
                and np.array_equal(self.human_goals, other.human_goals, equal_nan=True)
                and len(self.obstacles) == len(other.obstacles)
                and all(np.array_equal(a, b) for a, b in zip(self.obstacles, other.obstacles, strict=True)))

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class EpisodeRecord:
    """One evaluation episode (units: s, m, rad).

    ``episode_return`` is the undiscounted sum of rewards; ``discounted_return`` is
    Σ_t gamma^(t·Δt·v_pref)·r_t as computed by the env (the "return" of the paper's Table 3).
    ``min_separation`` is the smallest surface distance to any pedestrian (the env's finite
    ``no_one_distance`` when no one was present, ≤ 0 after a collision), ``steps_with_people`` the steps
    with someone present (0: no one was, though a recorded scene's window may give ``num_humans`` > 0);
    ``discomfort_frequency`` the share of this episode's steps with a pedestrian closer than the
    discomfort distance (0.2 m).
    ``discomfort_separation`` and ``comfort_zone_separation`` are the mean over this episode's
    discomfort steps, respectively its steps inside a pedestrian's comfort ellipse, of the
    step's minimum surface distance to any pedestrian (``nan`` when there is no such step); the
    first is the field's "average min separate distance in danger". ``sharp_turns`` counts the
    steps whose heading change reaches the env's ``angular_penalty_threshold`` (π/2 by default; the
    turns Eq. 13 penalises), whatever reward the episode ran under.

    The safety figures come from the people's true state, whatever the robot observed
    (:meth:`~sb3_crowdnav.envs.statistics.EpisodeStatistics.summary`): ``min_time_to_collision``
    the smallest constant-velocity time-to-collision at the steps' end states, capped at 10 s (the cap
    without anyone on a collision course); ``near_misses`` the steps whose minimum surface distance
    to a person lies in (0, 0.2) m; ``speed_near_people`` the robot's mean speed over its
    ``steps_near_people`` (a person's surface within 1 m); ``peak_acceleration`` and
    ``peak_turn_rate`` the largest change of the velocity vector and of the heading per second;
    ``min_clearance`` (the warehouse) the smallest distance from the robot's disc to a rack or wall,
    its steps swept (below 0 after an obstacle collision).
    """

    seed: int
    outcome: str
    steps: int
    navigation_time: float
    path_length: float
    episode_return: float
    discounted_return: float
    min_separation: float
    discomfort_frequency: float
    comfort_zone_time: float
    heading_change: float
    num_humans: int
    discomfort_separation: float = math.nan
    comfort_zone_separation: float = math.nan
    sharp_turns: int = 0
    # steps with someone present (-1: not recorded, e.g. a record read from a file written before it): a recorded
    # scene's window can have people (num_humans) none of whom is present while the robot drives
    steps_with_people: int = -1
    collision_with: str = ""  # "human" or "obstacle" (a rack or wall, in the warehouse) after a collision
    route_length: float = math.nan  # [m] the warehouse robot's planned route from start to goal
    # the safety figures (nan: not recorded, e.g. a record built by hand)
    min_time_to_collision: float = math.nan  # [s] capped at TTC_HORIZON (10 s), 0 after touching a person
    near_misses: int = 0  # steps with 0 < surface distance to a person < 0.2 m
    steps_near_people: int = 0  # steps with a person's surface within 1 m
    speed_near_people: float = math.nan  # [m/s] the robot's mean speed over those steps (nan: none)
    peak_acceleration: float = math.nan  # [m/s²] max |v_t - v_{t-1}| / Δt
    peak_turn_rate: float = math.nan  # [rad/s] max |wrap(θ_t - θ_{t-1})| / Δt
    min_clearance: float = math.nan  # [m] to racks and walls (the warehouse; nan on the open floor)
    trajectory: Trajectory | None = field(default=None, repr=False)

    @classmethod
    def from_stats(cls, seed: int, steps: int, episode_return: float, stats: dict[str, Any],
                   trajectory: Trajectory | None = None) -> EpisodeRecord:
        """The record of an episode from the env's ``info["episode_stats"]`` at its end: every other field is read
        from ``stats`` and converted to its declared type; only :data:`STATS_OPTIONAL` may be missing (the default)."""
        values: dict[str, Any] = {}
        for f in fields(cls):
            if f.name in ("seed", "steps", "episode_return", "trajectory"):
                continue
            if f.name not in stats and f.name in STATS_OPTIONAL:
                continue
            values[f.name] = _CONVERT[f.type](stats[f.name])
        return cls(seed=int(seed), steps=int(steps), episode_return=float(episode_return), trajectory=trajectory,
                   **values)

    def to_dict(self) -> dict[str, Any]:
        """The scalar fields (no trajectory), e.g. for a CSV row."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "trajectory"}

    def __eq__(self, other: object) -> bool:
        """Field by field, with ``nan == nan`` (an episode without discomfort steps has a ``nan`` separation)."""
        if not isinstance(other, EpisodeRecord):
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))


STATS_OPTIONAL = ("collision_with", "route_length", "min_clearance")  # episode stats only some envs report
_CONVERT = {"int": int, "float": float, "str": str}


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


RECORD_FIELDS = tuple(f.name for f in fields(EpisodeRecord) if f.name != "trajectory")


__all__ = ["RECORD_FIELDS", "STATS_OPTIONAL", "EpisodeRecord", "Trajectory"]
