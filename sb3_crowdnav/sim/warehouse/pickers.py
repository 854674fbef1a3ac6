"""Pickers: pedestrians that see the racks, walk routes between pick faces and stand there for a while.

Each picker's job is endless: walk to a pick slot along a roadmap route, stand for a dwell time drawn from
``dwell_time``, draw the next slot, walk on. A route goes from the slot the picker stood at to the next one (the
picker sets off from where it stands, within reach of its slot), so it depends on the two slots alone and is
planned once per layout (:class:`PickSlots`). At the start of an episode about half of the pickers are
standing at a slot (with a part of their dwell left), the others walking to their first one, so some
pickers stand still at any moment. The scene's crowd model moves them (:mod:`sb3_crowdnav.sim.crowd`), the racks and
the hall's walls its :class:`~sb3_crowdnav.sim.crowd.Walls`: with ORCA, obstacle avoidance is RVO2's own (``pyrvo``'s
``add_obstacle``: the racks, and the walls as the hall's boundary, :func:`rvo_obstacles`), and because ORCA at a large
time step can still press an agent into a thin obstacle, every step ends by pushing any picker that overlaps a rack or
a wall back out to its radius (:meth:`PickerCrowd.step`); with social force the walls push the pickers away, and the
model has its own rule for one pushed out of the walkable area.

Who sees the robot (``scene.robot_visible``): everyone or no one for a bool; for a share, each picker with that
probability, drawn at reset after the start slots, who stands, the dwells and first jobs, so that those stay the
draws of a world without it. The others are distracted: they walk as if the robot
were not there. With ORCA a picker who sees the robot has it as one more agent, at its actual position and velocity
each step (:class:`~sb3_crowdnav.sim.crowd.OrcaCrowdModel`); social force takes a bool only.

Each picker walks at its own preferred speed: ``human_v_pref`` for ``scene.human_speed="fixed"`` (nothing drawn), or
drawn from the open floor's measured distribution (:func:`~sb3_crowdnav.sim.population.draw_speeds`) after who sees
the robot, the reset's last draw (so that every other draw stays that of ``"fixed"``). The crowd model gets it
(ORCA's maximum speed, social force's desired speed), and so do the distances within which a picker has reached a
waypoint or its slot (:meth:`PickerCrowd._arrivals`).

With a fixed layout, the slots, the roadmap and the routes between slots serve every episode (the simulator keeps
its :class:`PickSlots`).
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.ops import nearest_points

from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.crowd import CrowdModel, RobotAgent, Walls, make_crowd
from sb3_crowdnav.sim.draws import uniform
from sb3_crowdnav.sim.population import People, draw_sees_robot, draw_speeds
from sb3_crowdnav.sim.warehouse import kernels
from sb3_crowdnav.sim.warehouse.boxes import in_free_space
from sb3_crowdnav.sim.warehouse.layout import WarehouseLayout
from sb3_crowdnav.sim.warehouse.roadmap import Roadmap

SLOT_OFFSET = 0.1  # [m] a standing picker keeps this much between its body and the rack face
PICKER_CLEARANCE = 0.02  # [m] the pickers' roadmap's clearance beyond their radius (their routes' waypoints near racks)
ARRIVAL = 0.25  # [m] a waypoint of a picker's route counts as reached this close


def pick_slots(layout: WarehouseLayout, scene: SceneConfig) -> np.ndarray:
    """Where a picker stands to pick: points along every rack edge, ``human_radius + SLOT_OFFSET`` out from it,
    spaced by a picker's diameter + 0.2 m, kept where a picker fits; (n, 2)."""
    radius = scene.human_radius
    spacing, offset = 2 * radius + 0.2, radius + SLOT_OFFSET
    segments = layout.rack_segments  # of the racks counter-clockwise: the normal (dy, -dx) points out
    if not len(segments):
        return np.zeros((0, 2))
    points = kernels.slot_points(segments, spacing, offset)  # (k + 0.5) * length / count along each edge, then out
    return points[in_free_space(layout, points, radius + 1e-3)]


def rvo_obstacles(layout: WarehouseLayout) -> list[np.ndarray]:
    """The layout's obstacles for RVO2: the racks (counter-clockwise) and the hall's walls as one clockwise boundary
    polygon (RVO2's way of keeping agents inside; the walls' inner faces without the edges no picker ever faces)."""
    return [*layout.rack_vertices, layout.hall_vertices[::-1].copy()]


class PickSlots:
    """The pick slots of a layout, the pickers' roadmap and the routes between slots, each planned once.

    :param layout: the layout
    :param scene: the picker's radius (the slots' offset from the racks)
    :param clearance: the roadmap's clearance [m]
    """

    def __init__(self, layout: WarehouseLayout, scene: SceneConfig, clearance: float) -> None:
        self.layout = layout
        self.walls = Walls(layout.hall_vertices, tuple(layout.rack_vertices))  # (rvo_vertices: rvo_obstacles(layout))
        self.points = pick_slots(layout, scene)
        self.roadmap = Roadmap(layout, clearance)
        self._point_list = self.points.tolist()
        self._routes: dict[tuple[int, int], list[list[float]] | None] = {}

    def route(self, i: int, j: int) -> list[list[float]] | None:
        """The waypoints from slot ``i`` to slot ``j`` in floats, slot ``i`` left out (the roadmap's shortest route,
        remembered); None when there is none."""
        key = (i, j)
        if key not in self._routes:
            try:
                self._routes[key] = self.roadmap.waypoints(self._point_list[i], self._point_list[j])[1:]
            except ValueError:
                self._routes[key] = None
        return self._routes[key]


class PickerCrowd:
    """The pickers of one episode: their crowd model, routes and dwell times.

    :param scene: radii, speeds, time step, the crowd model and its parameters
    :param slots: the layout's slots and routes (its walls are given to the crowd model)
    :param usable: the indices of the slots pickers may use this episode (n,)
    :param starts: start slot of each picker, an index into ``usable``
    :param rng: the episode's generator (dwell times, next slots)
    :param dwell_time: (min, max) [s]
    :param robot: ``(position (2,), velocity (2,), radius)`` of the robot at the start when some pickers see it
        (``scene.robot_visible`` True or a share; with ORCA it is then one more agent of those who see it, moved each
        step to the robot's actual position and velocity); None: the robot is invisible to all
    :param crowd: the crowd model that moves them (kept by the simulator across episodes); None: a new one of
        ``scene.crowd``
    """

    def __init__(self, scene: SceneConfig, slots: PickSlots, usable: np.ndarray, starts: np.ndarray,
                 rng: np.random.Generator, dwell_time: tuple[float, float],
                 robot: tuple[np.ndarray, np.ndarray, float] | None = None, crowd: CrowdModel | None = None) -> None:
        self.scene, self.rng, self.dwell_time = scene, rng, dwell_time
        self.slots = slots.points[usable]  # (u, 2): the usable slots
        self._map, self._ids = slots, np.asarray(usable).tolist()
        n = len(starts)
        self.n = n
        layout = self._layout = slots.layout
        c, w, h = scene.human_radius - 1e-6, layout.width / 2, layout.height / 2
        self._room, self._hall = np.array([-w + c, -h + c, w - c, h - c]), (w, h)  # inside it, outside the grown boxes:
        self._grown = None if layout.boxes is None else layout.boxes + np.array([-c, -c, c, c])  # clear of every rack
        self._preferences = np.zeros((n, 2))  # filled by kernels.picker_preferences
        self.crowd = crowd if crowd is not None else make_crowd(scene)
        # a model that can put a person at a position (ORCA) gets the overlap guard of step; social force's walls
        # push the pickers off the racks and it has its own rule for one pushed out of the walkable area
        self._place = getattr(self.crowd, "move_person", None)
        here = self.slots[starts]
        self.slot = np.array(starts, dtype=np.int64)  # a copy: the caller keeps the start slots
        self.routes: list[list[list[float]]] = [[p] for p in self.slots[starts].tolist()]  # waypoints, in floats
        # the same waypoints for the kernels: row i holds the first _route_lengths[i] of (n, K, 2)
        self._route_array, self._route_lengths = np.zeros((n, 8, 2)), np.ones(n, dtype=np.int64)
        self._route_array[:, 0] = self.slots[starts]
        self.waypoint = np.zeros(n, dtype=np.int64)  # the index of each picker's current waypoint
        self.dwell = np.zeros(n)  # [s] left standing at the slot; 0 while walking
        standing = rng.random(n) < 0.5
        for i in range(n):
            if standing[i]:
                self.dwell[i] = uniform(rng, *dwell_time) * rng.random()
            else:
                self._next_job(i)
        # who sees the robot: drawn after the jobs (so that a share leaves the draws above as they were), one
        # rng.random(n) in the pickers' order for a share, nothing for a bool
        self.sees_robot = draw_sees_robot(scene.robot_visible, n, rng) if robot is not None else np.zeros(n, dtype=bool)
        # each picker's preferred speed [m/s], drawn last (human_speed="measured"; nothing drawn for "fixed")
        self.v_prefs = draw_speeds(scene, n, rng)
        self.waypoint_arrival, self.slot_arrival = self._arrivals()
        people = People(here, here, np.full(n, scene.human_radius), self.v_prefs,
                        self.sees_robot, np.full(n, np.inf), np.full(n, np.inf))
        seen = robot if robot is not None else (np.zeros(2), np.zeros(2), scene.robot_radius)
        self.crowd.reset(rng, people, RobotAgent(tuple(np.asarray(seen[0], dtype=np.float64).tolist()),
                                                 tuple(np.asarray(seen[1], dtype=np.float64).tolist()), float(seen[2])),
                         slots.walls)

    def _arrivals(self) -> tuple[np.ndarray, np.ndarray]:
        """How close [m] each picker (n,) must come to a waypoint of its route, and to its slot, to have reached it.

        A model whose walls push (social force) holds a picker heading for a waypoint near a rack (PICKER_CLEARANCE
        off it) or slowing into its slot short of it, where the push balances its driving force (``stops_short``):
        it reaches one within ARRIVAL of where it comes to rest. The drive grows with the picker's preferred speed,
        so the balance is each picker's own (docs/decisions.md, "Pickers at measured walking speeds"). Without a push
        (ORCA), within ARRIVAL of it.
        """
        stops_short = getattr(self.crowd, "stops_short", None)
        if stops_short is None:
            return np.full(self.n, ARRIVAL), np.full(self.n, ARRIVAL)
        speeds = np.unique(self.v_prefs).tolist()  # (one balance per speed: one for human_speed="fixed")
        waypoint = {v: ARRIVAL + stops_short(PICKER_CLEARANCE, v, slowing=False) for v in speeds}
        slot = {v: ARRIVAL + stops_short(SLOT_OFFSET, v) for v in speeds}
        v_prefs = self.v_prefs.tolist()
        return np.array([waypoint[v] for v in v_prefs]), np.array([slot[v] for v in v_prefs])

    @property
    def standing(self) -> np.ndarray:
        """(n,) bool: the pickers standing at a pick face now."""
        return self.dwell > 0

    def _next_job(self, i: int) -> None:
        """Send picker ``i`` from its slot to another one along the slots' route (its dwell is over)."""
        here = int(self.slot[i])
        if len(self.slots) > 1:  # any other slot, uniformly: rng.choice of the others, drawn the same way
            k = int(self.rng.integers(0, len(self.slots) - 1))
            self.slot[i] = k + (k >= here)
        route = self._map.route(self._ids[here], self._ids[self.slot[i]])
        self.routes[i] = route = route if route is not None else [self.slots[self.slot[i]].tolist()]
        if len(route) > self._route_array.shape[1]:  # (room for longer routes)
            grown = np.zeros((self.n, 2 * len(route), 2))
            grown[:, : self._route_array.shape[1]] = self._route_array
            self._route_array = grown
        self._route_array[i, : len(route)], self._route_lengths[i] = route, len(route)
        self.waypoint[i] = 0

    def preferred_velocities(self, positions: np.ndarray) -> list[list[float]]:
        """Towards the current waypoint at the picker's preferred speed (slowing into the last one); zero while
        standing (:func:`~sb3_crowdnav.sim.warehouse.kernels.picker_preferences`; passes the waypoints within reach)."""
        kernels.picker_preferences(positions, self.dwell, self.waypoint, self._route_array, self._route_lengths,
                                   self.v_prefs, self.waypoint_arrival, self._preferences)
        return self._preferences.tolist()

    def step(self, positions: np.ndarray, robot: RobotAgent) -> tuple[np.ndarray, np.ndarray]:
        """One crowd step from ``positions`` (n, 2); new positions and velocities, each (n, 2).

        :param robot: the robot at the start of the step (and where its move ends); read only when the pickers see it
        """
        dt = self.scene.time_step
        positions, velocities = self.crowd.step(self.preferred_velocities(positions), robot)
        # the overlap guard, then the dwells count down; a picker whose dwell is over gets its next job, one at the
        # last waypoint of its route stands for a dwell drawn now (in the pickers' order: the same draws)
        progress = (self.dwell, self.waypoint, self._route_array, self._route_lengths, dt, self.slot_arrival)
        if self._grown is not None:  # (one kernel for both when no picker is pressed)
            (w, h), radius = self._hall, self.scene.human_radius - 1e-6
            pressed, which, what = kernels.picker_after_step_fields(positions, self._room, self._grown,
                                                                    self._layout.boxes, w, h, radius, *progress)
            pressed = pressed.tolist() if pressed.shape[0] else []
            events = zip(which.tolist(), what.tolist(), strict=True) if which.shape[0] else ()
        else:
            pressed, events = self._pressed_indices(positions), None
        if self._place is None:
            pressed = []
        for i in pressed:  # never seen at Δt <= 0.5 s; a guard
            p = self._outside(positions[i].copy())
            if p is not None:
                self._place(i, p)
                positions[i] = p
        if events is None or pressed:
            which, what = kernels.picker_progress(positions, *progress)
            events = zip(which.tolist(), what.tolist(), strict=True)
        for i, event in events:  # (picker, 1: its dwell is over, 2: it reached its slot), in the pickers' order
            if event == 1:
                self._next_job(i)
            else:
                self.dwell[i] = max(uniform(self.rng, *self.dwell_time), dt)
        return positions, velocities

    def _pressed(self, positions: np.ndarray) -> np.ndarray:
        """(n,) bool: the pickers at ``positions`` (n, 2) pressed into a rack or a wall (see :meth:`_pressed_indices`)."""
        pressed = np.zeros(len(positions), dtype=bool)
        pressed[self._pressed_indices(np.asarray(positions, dtype=np.float64))] = True
        return pressed

    def _pressed_indices(self, state: np.ndarray) -> list[int]:
        """The pickers (``state`` (n, >= 2): x, y first) whose centre is closer than their radius (- 1 µm) to a rack or
        a wall. With boxes for racks by the exact distance (:func:`~sb3_crowdnav.sim.warehouse.kernels.pressed`),
        asked only of the pickers inside a rack grown by that much (square corners) or outside the hall shrunk by it;
        otherwise outside ``layout.free_space(radius - 1e-6)``."""
        radius = self.scene.human_radius - 1e-6
        if self._grown is None:
            return np.flatnonzero(~in_free_space(self._layout, state[:, :2], radius)).tolist()
        (w, h), boxes = self._hall, self._layout.boxes
        return kernels.pressed(state, self._room, self._grown, boxes, w, h, radius).tolist()

    def _outside(self, position: np.ndarray) -> np.ndarray | None:
        """Where to put a picker centred at ``position`` that overlaps an obstacle (None: it does not)."""
        radius = self.scene.human_radius
        point = Point(position)
        if not hasattr(self, "obstacles"):  # built on the first push only (never needed at Δt <= 0.5 s so far)
            self.obstacles = shapely.union_all([shapely.geometry.Polygon(p) for p in self._layout.polygons])
        if self.obstacles.distance(point) >= radius - 1e-6:
            return None
        inside = self.obstacles.contains(point)
        edge = nearest_points(self.obstacles.boundary, point)[0]
        away = np.asarray(position) - np.array(edge.coords[0])
        if inside:
            away = -away
        norm = float(np.hypot(*away))
        if norm < 1e-9:
            return None
        return np.array(edge.coords[0]) + away / norm * (radius + 1e-3)
