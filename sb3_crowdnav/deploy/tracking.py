"""The parts of :class:`~sb3_crowdnav.deploy.builder.ObservationBuilder`: its settings and a person's track.

:class:`BuilderSettings` is what a builder serves (the world's contract) and how the robot feeds it. A
:class:`Track` holds an id's detections ``(t, x, y)`` or ``(t, x, y, vx, vy)`` and, for each, the time its track
began: a gap of more than ``max_gap`` between two detections starts a new one. :meth:`Track.states` samples the
positions linearly between detections and along the last velocity past the newest; the velocities are the tracker's
(linear between detections) or the env's rule, (p(τ) - p(τ - Δt)) / Δt, 0 where the track does not reach a whole Δt
back.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from numbers import Integral
from typing import Any

import numpy as np

from sb3_crowdnav.sim.observation import ObservationSchema
from sb3_crowdnav.sim.validation import check_int, check_number

TIME_TOLERANCE = 1e-9  # [s] times this close are the same time (a grid time computed as t - kΔt and a detection's)


@dataclass(frozen=True)
class BuilderSettings:
    """What an :class:`ObservationBuilder` serves: the world's contract and the robot's choices.

    :param time_step: Δt of the env's step and of the history's grid [s]
    :param history_length: T, steps of history
    :param max_humans: M, pedestrian slots
    :param robot_radius: [m]
    :param robot_v_pref: [m/s]
    :param human_radius: the radius every person gets in the observation [m] (the env's, one for everyone)
    :param max_obstacles: S, obstacle segments in the observation (warehouse; 0 on the open floor)
    :param num_waypoints: K, route waypoints in the observation (warehouse; 0 on the open floor)
    :param sensor_range: obstacle segments farther than this are not observed [m] (warehouse)
    :param waypoint_radius: a waypoint counts as passed within this distance of the robot's centre [m] (warehouse)
    :param frame: the fixed frame every input must be given in
    :param staleness: a person, the odometry, the tracker are gone when their newest data is older than this at a
        decision [s]; None: half a step
    :param max_gap: a longer gap between two detections of an id starts a new track [s]; None: one step
    :param ids: the person ids the tracker may report (an other id is an :class:`UnknownId`); None: any int or str
    """

    time_step: float
    history_length: int
    max_humans: int
    robot_radius: float
    robot_v_pref: float
    human_radius: float
    max_obstacles: int = 0
    num_waypoints: int = 0
    sensor_range: float | None = None
    waypoint_radius: float | None = None
    frame: str = "odom"
    staleness: float | None = None
    max_gap: float | None = None
    ids: frozenset | None = None

    def __post_init__(self) -> None:
        for name in ("time_step", "robot_radius", "robot_v_pref", "human_radius"):
            check_number(name, getattr(self, name))
        check_int("history_length", self.history_length, 1)
        check_int("max_humans", self.max_humans, 1)
        check_int("max_obstacles", self.max_obstacles, 0)
        check_int("num_waypoints", self.num_waypoints, 0)
        warehouse = self.max_obstacles > 0
        if (self.num_waypoints > 0) != warehouse:
            raise ValueError(f"max_obstacles and num_waypoints must both be > 0 (the warehouse) or both 0 (the open "
                             f"floor), got {self.max_obstacles!r} and {self.num_waypoints!r}")
        for name in ("sensor_range", "waypoint_radius"):
            value = getattr(self, name)
            if warehouse:
                check_number(name, value)
            elif value is not None:
                raise ValueError(f"{name} is the warehouse's (max_obstacles > 0); on the open floor it must be None, "
                                 f"got {value!r}")
        if not isinstance(self.frame, str) or not self.frame:
            raise TypeError(f"frame must be a non-empty str, got {self.frame!r}")
        staleness = self.time_step / 2 if self.staleness is None else self.staleness
        max_gap = self.time_step if self.max_gap is None else self.max_gap
        check_number("staleness", staleness, allow_zero=True)
        check_number("max_gap", max_gap)
        object.__setattr__(self, "staleness", float(staleness))
        object.__setattr__(self, "max_gap", float(max_gap))
        if self.ids is not None:
            if isinstance(self.ids, (str, bytes)) or not isinstance(self.ids, Iterable):
                raise TypeError(f"ids must be a collection of person ids (int or str) or None, got {self.ids!r}")
            object.__setattr__(self, "ids", frozenset(person_id("ids", i) for i in self.ids))

    @property
    def schema(self) -> ObservationSchema:
        return ObservationSchema(self.history_length, self.max_humans, self.max_obstacles, self.num_waypoints)


def person_id(name: str, value: Any) -> int | str:
    """A person id (an int or a str), or ``TypeError`` naming ``name``."""
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Integral):
        raise TypeError(f"{name}: a person id must be an int or a str, got {value!r} ({type(value).__name__})")
    return int(value)


class Track:
    """One id's detections (time, x, y[, vx, vy]) and the start time of the track each belongs to."""

    def __init__(self, order: int) -> None:
        self.order = order  # when the id was first seen, for ties
        self.rows: list[tuple[float, ...]] = []  # (t, x, y[, vx, vy])
        self.starts: list[float] = []

    def add(self, t: float, row: tuple[float, ...], max_gap: float) -> None:
        gap = t - self.rows[-1][0] if self.rows else math.inf
        self.starts.append(self.starts[-1] if gap <= max_gap else t)
        self.rows.append((t, *row))

    def newest_at(self, t: float) -> int:
        """Index of the newest detection at or before t (-1: none)."""
        times = [r[0] for r in self.rows]
        return int(np.searchsorted(times, t + TIME_TOLERANCE, side="right")) - 1

    def prune(self, cutoff: float) -> None:
        """Forget detections before ``cutoff`` but the last of them (interpolation needs it)."""
        k = self.newest_at(cutoff)
        if k > 0:
            del self.rows[:k], self.starts[:k]

    def states(self, times: np.ndarray, start: float, dt: float) -> np.ndarray:
        """(len(times), 4) px, py, vx, vy at ``times`` from the track that began at ``start`` (rules: module doc)."""
        seg = np.array([r for r, s in zip(self.rows, self.starts, strict=True) if s == start])
        ts = seg[:, 0]
        times = snap(times, ts)
        pos = self._positions(seg, times, dt)
        if seg.shape[1] == 5:  # the tracker's velocities
            vel = np.stack([np.interp(times, ts, seg[:, 3]), np.interp(times, ts, seg[:, 4])], axis=-1)
        else:
            before = snap(times - dt, ts)
            behind = before >= ts[0] - TIME_TOLERANCE
            back = self._positions(seg, np.where(behind, before, ts[0]), dt)
            vel = np.where(behind[:, None], (pos - back) / dt, 0.0)
        return np.concatenate([pos, vel], axis=-1)

    @staticmethod
    def _positions(seg: np.ndarray, times: np.ndarray, dt: float) -> np.ndarray:
        ts, xy = seg[:, 0], seg[:, 1:3]
        pos = np.stack([np.interp(times, ts, xy[:, 0]), np.interp(times, ts, xy[:, 1])], axis=-1)
        ahead = times > ts[-1]
        if ahead.any():  # past the newest detection: along its velocity
            if seg.shape[1] == 5:
                v = seg[-1, 3:5]
            else:
                back = ts[-1] - dt
                v = (xy[-1] - Track._positions(seg, np.array([back]), dt)[0]) / dt if back >= ts[0] - TIME_TOLERANCE \
                    else np.zeros(2)
            pos[ahead] = xy[-1] + (times[ahead, None] - ts[-1]) * v
        return pos


def snap(times: np.ndarray, ts: np.ndarray) -> np.ndarray:
    """``times`` with each one within :data:`TIME_TOLERANCE` of a detection time set to it."""
    nearest = ts[np.abs(times[:, None] - ts[None, :]).argmin(axis=1)]
    return np.where(np.abs(times - nearest) <= TIME_TOLERANCE, nearest, times)


__all__ = ["TIME_TOLERANCE", "BuilderSettings", "Track", "person_id", "snap"]
