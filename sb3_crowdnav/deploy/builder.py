"""``ObservationBuilder``: a robot's tracker output, odometry and goal as exactly the observation the env would give.

Inputs are in one fixed frame (``frame``, default ``"odom"``; each call names its frame and another one is refused),
in m, m/s, rad and s. The rules, each the env's (:mod:`~sb3_crowdnav.sim.sensing`, :mod:`~sb3_crowdnav.sim.replay`):

* **the grid**: the history of a decision at t holds the people at t - (T-1)Δt, ..., t - Δt, t (oldest first),
  sampled from each track: linear between its detections, along its last velocity past its newest one. A gap of more
  than ``max_gap`` between two detections of an id ends its track there: a new one starts.
* **who is seen**: a person is seen at t when their newest detection at or before t is at most ``staleness`` old;
  the others' slots are padded over the whole window (zeros, mask 0). A person seen at t who was not in a slot at
  the previous decision (or whose track restarted since) starts a new history: their state at t repeated over the
  window, as at an env's reset. The history is sampled again at every decision, so a late detection refines the past.
* **velocities**: the tracker's when it gives them (linear between detections), else the env's rule, the velocity
  of the last step: (p(τ) - p(τ - Δt)) / Δt, and 0 where the track does not reach a whole Δt back (at first
  sight the env's people stand at rest, as at its reset).
* **slots**: a person keeps their slot while seen; new people take the lowest free slots in the order their tracks
  began. With more people seen than slots, the slots hold the ``max_humans`` nearest (centre distance, ties in the
  order the tracks began) to the robot one Δt before t (at its first odometry if later): replay's
  ``tracked="nearest"``, the rule the shipped models were evaluated with on recorded crowds; new ones nearest first.
* **the robot row** ``px, py, vx, vy, radius, gx, gy, v_pref, heading``: the odometry at t (linear between samples,
  heading along the shorter arc and wrapped to (-π, π]; past the newest sample along its velocity, heading kept, for
  at most ``staleness``), the goal, and the contract's radius and v_pref. Odometry velocities are in the fixed frame.
* **the warehouse**: the obstacle segments by :func:`~sb3_crowdnav.sim.warehouse.kernels.sense` at the robot's
  position (the env's stable order), the waypoints by
  :func:`~sb3_crowdnav.sim.warehouse.simulator.next_waypoints`: a route given by :meth:`ObservationBuilder.route` is
  observed from its first waypoint at the next decision, and waypoints passed are dropped at each decision after it.

Refused, each with its named :class:`BuilderError` (a ``ValueError``): times that go back (:class:`TimeOrderError`,
per input stream), NaN or infinity anywhere (:class:`NonFiniteInput`), an id outside the declared ``ids``
(:class:`UnknownId`), another frame (:class:`FrameMismatch`), an observation without its inputs, or with stale
odometry or a silent tracker (:class:`MissingInput`: no people frame within ``staleness`` is not an empty room).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from numbers import Real
from pathlib import Path
from typing import Any

import numpy as np

from sb3_crowdnav.deploy.tracking import TIME_TOLERANCE, BuilderSettings, Track, person_id
from sb3_crowdnav.sim.actions import wrap
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.observation import HUMAN_DIM, ROBOT_DIM, Robot
from sb3_crowdnav.sim.warehouse import kernels
from sb3_crowdnav.sim.warehouse.config import WarehouseConfig
from sb3_crowdnav.sim.warehouse.layout import WarehouseLayout
from sb3_crowdnav.sim.warehouse.simulator import next_waypoints

ROBOT_SIDE = ("frame", "staleness", "max_gap", "ids")  # the settings a robot chooses; the rest is the world's


class BuilderError(ValueError):
    """An input the :class:`ObservationBuilder` refuses."""


class TimeOrderError(BuilderError):
    """A time earlier than (or, for a frame or a sample, equal to) the previous one of the same input."""


class NonFiniteInput(BuilderError):
    """NaN or infinity in an input."""


class UnknownId(BuilderError):
    """A person id outside the builder's declared ``ids``."""


class FrameMismatch(BuilderError):
    """An input given in another frame than the builder's."""


class MissingInput(BuilderError):
    """An observation asked before its inputs, or with odometry or people older than ``staleness``."""


def _finite(name: str, value: Any) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real):
        raise TypeError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    if not math.isfinite(value):
        raise NonFiniteInput(f"{name} must be finite, got {value!r}")
    return float(value)


class ObservationBuilder:
    """A robot's data as the observation the env would give (the rules: this module's docstring).

    :param kwargs: :class:`BuilderSettings`' fields; or build it from the world it serves with :meth:`from_env` or
        :meth:`from_policy`
    """

    def __init__(self, **kwargs: Any) -> None:
        self.settings = BuilderSettings(**kwargs)
        self.schema = self.settings.schema
        self._segments: np.ndarray | None = None
        self.reset()

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> ObservationBuilder:
        """The builder of an env's observation (a crowd env, wrapped or not); ``kwargs``: ``frame``, ``staleness``,
        ``max_gap``, ``ids``."""
        base = getattr(env, "unwrapped", env)
        if not all(hasattr(base, name) for name in ("scene", "schema", "world")):
            raise TypeError(f"env must be a sb3_crowdnav env (with scene, schema and world), got {type(env).__name__}")
        scene, schema = base.scene, base.schema
        warehouse = getattr(base, "warehouse", None)
        world = dict(time_step=scene.time_step, history_length=schema.history_length, max_humans=schema.max_humans,
                     robot_radius=scene.robot_radius, robot_v_pref=scene.robot_v_pref, human_radius=scene.human_radius,
                     max_obstacles=schema.max_obstacles, num_waypoints=schema.num_waypoints,
                     sensor_range=warehouse.sensor_range if warehouse is not None else None,
                     waypoint_radius=base.world.waypoint_radius)
        return cls(**world, **_robot_side(kwargs))

    @classmethod
    def from_policy(cls, policy: Any, human_radius: float = SceneConfig.human_radius,
                    sensor_range: float | None = None, **kwargs: Any) -> ObservationBuilder:
        """The builder of an exported graph's observation, from its embedded contract (an ``OnnxPolicy`` or its
        :class:`~sb3_crowdnav.deploy.metadata.GraphMetadata`): Δt, T, M, S, K, the robot's radius and v_pref, the
        waypoint radius. ``human_radius`` [m] and, in the warehouse, the obstacles' ``sensor_range`` [m] are not in
        the contract: the env's defaults (0.3 m, 4 m) unless given. ``kwargs``: ``frame``, ``staleness``, ``max_gap``,
        ``ids``."""
        meta = getattr(policy, "metadata", policy)
        if not all(hasattr(meta, name) for name in ("world", "schema", "robot_radius", "robot_v_pref")):
            raise TypeError(f"policy must be an OnnxPolicy or a GraphMetadata, got {type(policy).__name__}")
        schema, world = meta.schema, meta.world
        return cls(time_step=world.time_step, history_length=schema.history_length, max_humans=schema.max_humans,
                   robot_radius=meta.robot_radius, robot_v_pref=meta.robot_v_pref, human_radius=human_radius,
                   max_obstacles=schema.max_obstacles, num_waypoints=schema.num_waypoints,
                   sensor_range=WarehouseConfig.sensor_range if sensor_range is None and schema.max_obstacles
                   else sensor_range, waypoint_radius=world.waypoint_radius,
                   **_robot_side(kwargs))

    def reset(self) -> None:
        """Forget every input but the layout (a new run; times may start again)."""
        self._tracks: dict[int | str, Track] = {}
        self._created = 0
        self._velocities: bool | None = None  # whether the tracker gives velocities (fixed by its first detection)
        self._people_time = -math.inf
        self._odometry: list[tuple[float, ...]] = []  # (t, x, y, heading, vx, vy)
        self._goal: tuple[float, float] | None = None
        self._route: np.ndarray | None = None
        self._route_fresh = False
        self._slots: list[int | str | None] = [None] * self.settings.max_humans
        self._since: dict[int | str, float] = {}  # when each slot's person began its history
        self._decision = -math.inf

    # ------------------------------------------------------------------ inputs
    def _frame(self, what: str, frame: Any) -> None:
        if frame != self.settings.frame:
            raise FrameMismatch(f"{what}: given in frame {frame!r}; this builder takes every input in "
                                f"{self.settings.frame!r} (transform it first, or build with frame={frame!r})")

    def people(self, t: float, detections: Iterable[Sequence[Any]], *, frame: str) -> None:
        """A tracker's frame at time ``t`` [s]: ``(id, x, y)`` or, with its velocity estimate, ``(id, x, y, vx, vy)``
        per person (m, m/s); an empty frame when it sees no one. Refused whole when any detection is."""
        self._frame("people", frame)
        t = _finite("people: t", t)
        if t <= self._people_time:
            raise TimeOrderError(f"people: t={t!r} s is not after the previous frame's {self._people_time!r} s")
        rows: dict[int | str, tuple[float, ...]] = {}
        kinds = set()
        names = ("x", "y", "vx", "vy")
        for k, detection in enumerate(detections):
            if isinstance(detection, np.ndarray):
                detection = tuple(detection.tolist())
            if isinstance(detection, (str, bytes)) or not isinstance(detection, Sequence) or len(detection) not in (3, 5):
                raise BuilderError(f"people: detection {k} must be (id, x, y) or (id, x, y, vx, vy), got {detection!r}")
            pid = person_id(f"people: detection {k}", detection[0])
            if self.settings.ids is not None and pid not in self.settings.ids:
                raise UnknownId(f"people: id {pid!r} is not one of the declared ids {sorted(map(str, self.settings.ids))}")
            if pid in rows:
                raise BuilderError(f"people: id {pid!r} appears twice in the frame at t={t!r} s")
            rows[pid] = tuple(_finite(f"people: {names[j]} of id {pid!r}", v) for j, v in enumerate(detection[1:]))
            kinds.add(len(detection) == 5)
        if len(kinds) > 1 or (kinds and self._velocities is not None and kinds != {self._velocities}):
            raise BuilderError("people: every detection must have the same form, (id, x, y) or (id, x, y, vx, vy) "
                               "for the whole run (a tracker gives velocities or does not)")
        if kinds:
            self._velocities = kinds.pop()
        for pid, row in rows.items():
            if pid not in self._tracks:
                self._tracks[pid] = Track(self._created)
                self._created += 1
            self._tracks[pid].add(t, row, self.settings.max_gap)
        self._people_time = t

    def odometry(self, t: float, x: float, y: float, heading: float, vx: float, vy: float, *, frame: str) -> None:
        """The robot at time ``t`` [s]: position [m], heading [rad], velocity [m/s] in the fixed frame."""
        self._frame("odometry", frame)
        values = [_finite(f"odometry: {n}", v) for n, v in zip(("t", "x", "y", "heading", "vx", "vy"),
                                                                 (t, x, y, heading, vx, vy), strict=True)]
        if not -math.pi < values[3] <= math.pi:  # (an angle already in range is kept bit for bit)
            values[3] = wrap(values[3])
        if self._odometry and values[0] <= self._odometry[-1][0]:
            raise TimeOrderError(f"odometry: t={values[0]!r} s is not after the previous sample's "
                                 f"{self._odometry[-1][0]!r} s")
        self._odometry.append(tuple(values))

    def goal(self, x: float, y: float, *, frame: str) -> None:
        """The robot's goal [m] (on the open floor; in the warehouse the route's last waypoint is the goal)."""
        self._frame("goal", frame)
        if self.settings.num_waypoints:
            raise BuilderError("goal: in the warehouse the goal is the route's last waypoint: give route()")
        self._goal = (_finite("goal: x", x), _finite("goal: y", y))

    def layout(self, layout: WarehouseLayout | str | Path, *, frame: str) -> None:
        """The warehouse's layout: a ``WarehouseLayout`` or its ``.json``/``.yaml`` file (``WarehouseLayout.from_file``)."""
        self._frame("layout", frame)
        if not self.settings.max_obstacles:
            raise BuilderError("layout: this builder's observation has no obstacles (max_obstacles=0, the open floor)")
        if not isinstance(layout, WarehouseLayout):
            layout = WarehouseLayout.from_file(layout)
        self._segments = np.ascontiguousarray(layout.segments, dtype=np.float64)

    def route(self, waypoints: Any, *, frame: str) -> None:
        """The robot's route (R, 2) [m] from its current waypoint to the goal, its last point (warehouse): observed
        from its first waypoint at the next decision (as the env observes a route it has just planned)."""
        self._frame("route", frame)
        if not self.settings.num_waypoints:
            raise BuilderError("route: this builder's observation has no waypoints (num_waypoints=0, the open floor)")
        route = np.array(waypoints, dtype=np.float64)
        if route.ndim != 2 or route.shape[1] != 2 or not len(route):
            raise BuilderError(f"route: waypoints must be (R, 2) with R >= 1, got shape {route.shape}")
        if not np.isfinite(route).all():
            raise NonFiniteInput(f"route: waypoints must be finite, got {waypoints!r}")
        self._route, self._route_fresh = route, True
        self._goal = (float(route[-1, 0]), float(route[-1, 1]))

    @property
    def slots(self) -> dict[int | str, int]:
        """The slot of every person in the last observation, by id."""
        return {pid: s for s, pid in enumerate(self._slots) if pid is not None}

    # ------------------------------------------------------------------ the observation
    def _robot_at(self, t: float, what: str = "observation") -> np.ndarray:
        """(t, x, y, heading, vx, vy) of the robot at ``t`` (rules: module doc)."""
        odo = self._odometry
        if not odo:
            raise MissingInput(f"{what}: no odometry yet: call odometry() first")
        k = int(np.searchsorted([o[0] for o in odo], t + TIME_TOLERANCE, side="right")) - 1
        if k < 0:
            raise MissingInput(f"{what}: the first odometry is at {odo[0][0]!r} s, after t={t!r} s")
        a = np.array(odo[k])
        if abs(t - a[0]) <= TIME_TOLERANCE:
            return a
        if k + 1 < len(odo):
            b = np.array(odo[k + 1])
            w = (t - a[0]) / (b[0] - a[0])
            out = a + w * (b - a)
            out[3] = wrap(a[3] + w * wrap(b[3] - a[3]))
            return out
        if t - a[0] > self.settings.staleness:
            raise MissingInput(f"{what}: the newest odometry is {t - a[0]:.3g} s older than t={t!r} s (staleness "
                               f"{self.settings.staleness} s)")
        out = a.copy()
        out[1:3] += (t - a[0]) * a[4:6]
        return out

    def _seen(self, t: float) -> dict[int | str, float]:
        """The people seen at ``t``, each with the start time of their current track."""
        seen = {}
        for pid, track in self._tracks.items():
            k = track.newest_at(t)
            if k >= 0 and t - track.rows[k][0] <= self.settings.staleness + TIME_TOLERANCE:
                seen[pid] = track.starts[k]
        return seen

    def _choose(self, t: float, seen: dict[int | str, float]) -> list[int | str]:
        """Who gets a slot, in the order entrants take the free ones (rules: module doc)."""
        chosen = sorted(seen, key=lambda pid: self._tracks[pid].order)
        m = self.settings.max_humans
        if len(chosen) > m:
            dt = self.settings.time_step
            robot = self._robot_at(max(t - dt, self._odometry[0][0]))[1:3]
            here = np.array([self._tracks[p].states(np.array([t]), seen[p], dt)[0, :2] for p in chosen])
            order = np.argsort(np.linalg.norm(here - robot, axis=-1), kind="stable")
            chosen = [chosen[i] for i in order[:m].tolist()]
        return chosen

    def _assign(self, t: float, seen: dict[int | str, float]) -> None:
        chosen = self._choose(t, seen)
        keep = set(chosen)
        slots = [pid if pid in keep else None for pid in self._slots]
        held = set(slots)
        for pid in chosen:
            if pid in held and seen[pid] <= self._decision + TIME_TOLERANCE:
                continue  # in a slot at the previous decision, on the same track: its history goes on
            if pid not in held:
                slots[slots.index(None)] = pid
            self._since[pid] = t
        self._slots = slots
        self._since = {pid: self._since[pid] for pid in slots if pid is not None}

    def _history(self, t: float, seen: dict[int | str, float]) -> tuple[np.ndarray, np.ndarray]:
        s = self.settings
        history = np.zeros((s.history_length, s.max_humans, HUMAN_DIM))
        mask = np.zeros(s.max_humans, dtype=bool)
        grid = t - np.arange(s.history_length - 1, -1, -1) * s.time_step  # oldest first
        for slot, pid in enumerate(self._slots):
            if pid is not None:
                times = np.maximum(grid, self._since[pid])  # before the history began: its first state
                history[:, slot, :4] = self._tracks[pid].states(times, seen[pid], s.time_step)
                history[:, slot, 4] = s.human_radius
                mask[slot] = True
        return history, mask

    def _static(self, x: float, y: float) -> dict[str, np.ndarray]:
        """The warehouse's obstacles and waypoints at the robot's position (x, y)."""
        s = self.settings
        if self._segments is None or self._route is None:
            raise MissingInput(f"observation: the warehouse needs {'layout()' if self._segments is None else 'route()'}")
        n = len(self._segments)
        _, segments, mask = kernels.sense(self._segments, x, y, x, y, s.robot_radius, s.robot_radius, s.sensor_range,
                                          s.max_obstacles, np.zeros(n), np.zeros(n, dtype=np.int64))
        if not self._route_fresh:
            self._route = next_waypoints(self._route, np.array([x, y]), s.waypoint_radius)
        self._route_fresh = False
        k = s.num_waypoints
        ahead = self._route[:k]
        waypoints = np.concatenate([ahead, np.repeat(self._route[-1:], k - len(ahead), axis=0)])
        return {"obstacles": segments, "obstacles_mask": mask, "waypoints": waypoints}

    def observation(self, t: float) -> dict[str, np.ndarray]:
        """The env's observation (float32, its keys, shapes and order) for a decision at time ``t`` [s]."""
        t = _finite("observation: t", t)
        s = self.settings
        if t < self._decision:
            raise TimeOrderError(f"observation: t={t!r} s is before the previous decision's {self._decision!r} s")
        if self._goal is None:
            raise MissingInput(f"observation: no goal yet: call {'route' if s.num_waypoints else 'goal'}() first")
        _, x, y, heading, vx, vy = self._robot_at(t).tolist()
        if self._people_time == -math.inf:
            raise MissingInput("observation: no people frame yet: call people() first (an empty frame when the "
                               "tracker sees no one)")
        if t - self._people_time > s.staleness + TIME_TOLERANCE:
            raise MissingInput(f"observation: the newest people frame is at {self._people_time!r} s, more than "
                               f"staleness={s.staleness} s before t={t!r} s (a silent tracker is not an empty room)")
        static = self._static(x, y) if s.num_waypoints else {}
        seen = self._seen(t)
        self._assign(t, seen)
        history, mask = self._history(t, seen)
        self._decision = t
        self._forget(t)
        robot = np.zeros(ROBOT_DIM)
        robot[Robot.POS] = x, y
        robot[Robot.VEL] = vx, vy
        robot[Robot.RADIUS] = s.robot_radius
        robot[Robot.GOAL] = self._goal
        robot[Robot.V_PREF] = s.robot_v_pref
        robot[Robot.HEADING] = heading
        return self.schema.observation(robot, history, mask, **static)

    def _forget(self, t: float) -> None:
        """Drop what no later decision reads: detections and odometry older than the window and a step."""
        s = self.settings
        cutoff = t - (s.history_length + 1) * s.time_step
        for pid in [p for p, track in self._tracks.items() if track.rows[-1][0] < cutoff - s.max_gap]:
            del self._tracks[pid]  # a later detection of the id starts a new track anyway
        for track in self._tracks.values():
            track.prune(cutoff)
        k = int(np.searchsorted([o[0] for o in self._odometry], t - 2 * s.time_step, side="right")) - 1
        if k > 0:
            del self._odometry[:k]


def _robot_side(kwargs: dict[str, Any]) -> dict[str, Any]:
    unknown = sorted(set(kwargs) - set(ROBOT_SIDE))
    if unknown:
        raise TypeError(f"unknown keyword arguments {unknown}: the world's settings come from the env or the graph; "
                        f"the robot's are {list(ROBOT_SIDE)}")
    return kwargs


__all__ = ["BuilderError", "FrameMismatch", "MissingInput", "NonFiniteInput", "ObservationBuilder",
           "TimeOrderError", "UnknownId"]
