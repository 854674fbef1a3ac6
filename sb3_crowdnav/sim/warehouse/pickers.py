"""Pickers: ORCA pedestrians that see the racks, walk routes between pick faces and stand there for a while.

Each picker's job is endless: walk to a pick slot along a roadmap route, stand for a dwell time drawn from
``dwell_time``, draw the next slot, walk on. At the start of an episode about half of the pickers are
standing at a slot (with a part of their dwell left), the others walking to their first one, so some
pickers stand still at any moment. Obstacle avoidance is RVO2's own (``pyrvo``'s ``add_obstacle``);
because ORCA at a large time step can still press an agent into a thin obstacle, every step ends by
pushing any picker that overlaps a rack or a wall back out to its radius (:meth:`PickerCrowd.step`).
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.ops import nearest_points

from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.geometry import polygon_segments
from sb3_crowdnav.sim.orca import OrcaCrowd
from sb3_crowdnav.sim.warehouse.boxes import BAND, in_free_space, point_clearance
from sb3_crowdnav.sim.warehouse.layout import Roadmap, WarehouseLayout

SLOT_OFFSET = 0.1  # [m] a standing picker keeps this much between its body and the rack face
ARRIVAL = 0.25  # [m] a waypoint of a picker's route counts as reached this close


def pick_slots(layout: WarehouseLayout, scene: SceneConfig) -> np.ndarray:
    """Where a picker stands to pick: points along every rack edge, ``human_radius + SLOT_OFFSET`` out from it,
    spaced by a picker's diameter + 0.2 m, kept where a picker fits; (n, 2)."""
    radius = scene.human_radius
    spacing = 2 * radius + 0.2
    racks = layout.polygons[: len(layout.racks)]  # counter-clockwise: the normal (dy, -dx) points out
    if not racks:
        return np.zeros((0, 2))
    segments = polygon_segments(racks)
    a, edge = segments[:, :2], segments[:, 2:] - segments[:, :2]
    length = np.hypot(edge[:, 0], edge[:, 1])
    count = np.array([int(n // spacing) if n >= spacing else 0 for n in length.tolist()], dtype=np.int64)
    of = np.repeat(np.arange(len(a)), count)  # the edge of each slot, and its number k along that edge
    k = np.arange(len(of)) - np.repeat(np.cumsum(count) - count, count)
    length, edge = length[of], edge[of]
    t = (k + 0.5) * length / count[of]
    normal = np.stack([edge[:, 1], -edge[:, 0]], axis=1) / length[:, None]
    points = a[of] + edge * (t / length)[:, None] + normal * (radius + SLOT_OFFSET)
    return points[in_free_space(layout, points, radius + 1e-3)]


class PickerCrowd:
    """The pickers of one episode: their ORCA simulator, routes and dwell times.

    :param scene: radii, speeds, time step and ORCA parameters
    :param layout: the episode's layout (its obstacles are given to ORCA)
    :param slots: the pick slots pickers may use this episode (n, 2)
    :param roadmap: routes for a picker's clearance
    :param starts: start slot index of each picker
    :param rng: the episode's generator (dwell times, next slots)
    :param dwell_time: (min, max) [s]
    """

    def __init__(self, scene: SceneConfig, layout: WarehouseLayout, slots: np.ndarray, roadmap: Roadmap,
                 starts: np.ndarray, rng: np.random.Generator, dwell_time: tuple[float, float]) -> None:
        self.scene, self.slots, self.roadmap, self.rng, self.dwell_time = scene, slots, roadmap, rng, dwell_time
        n = len(starts)
        self.n = n
        self._layout = layout
        self._boxes = None if layout.boxes is None else layout.boxes.tolist()
        self._clear = self._clear_region()
        self.orca = OrcaCrowd(scene, slots[starts], np.full(n, scene.human_radius), np.full(n, scene.human_v_pref),
                              None, obstacles=layout.polygons)
        self.slot = np.array(starts, dtype=np.int64)  # a copy: the caller keeps the start slots
        self.routes: list[np.ndarray] = [slots[s][None] for s in starts]
        self._route_points = [r.tolist() for r in self.routes]  # the routes in floats, for the per-step loops
        self.waypoint = [0] * n
        self.dwell = [0.0] * n  # [s] left standing at the slot; 0 while walking
        standing = rng.random(n) < 0.5
        for i in range(n):
            if standing[i]:
                self.dwell[i] = rng.uniform(*dwell_time) * rng.random()
            else:
                self._next_job(i, slots[starts[i]])

    @property
    def standing(self) -> np.ndarray:
        """(n,) bool: the pickers standing at a pick face now."""
        return np.array(self.dwell, dtype=np.float64).reshape(self.n) > 0

    def _next_job(self, i: int, position: np.ndarray) -> None:
        """Send picker ``i`` to another slot along the roadmap (its dwell is over)."""
        if len(self.slots) > 1:  # any other slot, uniformly: rng.choice of the others, drawn the same way
            k = int(self.rng.integers(0, len(self.slots) - 1))
            self.slot[i] = k + (k >= self.slot[i])
        try:
            self.routes[i] = self.roadmap.route(position, self.slots[self.slot[i]])[1:]
        except ValueError:  # cornered by the others' clearance: stay and pick here once more
            self.routes[i] = self.slots[self.slot[i]][None]
        self._route_points[i] = self.routes[i].tolist()
        self.waypoint[i] = 0

    def preferred_velocities(self, positions: np.ndarray) -> list[tuple[float, float]]:
        """Towards the current waypoint at v_pref (slowing into the last one); zero while standing."""
        v_pref, out = self.scene.human_v_pref, []
        for i, (x, y) in enumerate(positions.tolist()):
            if self.dwell[i] > 0:
                out.append((0.0, 0.0))
                continue
            route, w = self._route_points[i], self.waypoint[i]
            while w < len(route) - 1 and math.dist((x, y), route[w]) < ARRIVAL:
                w += 1
            self.waypoint[i] = w
            gx, gy = route[w]
            dx, dy = gx - x, gy - y
            norm = math.hypot(dx, dy)
            if norm > v_pref or (w < len(route) - 1 and norm > 1e-9):
                dx, dy = dx / norm * v_pref, dy / norm * v_pref
            out.append((dx, dy))
        return out

    def step(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One ORCA step from ``positions`` (n, 2); new positions and velocities, each (n, 2)."""
        dt = self.scene.time_step
        pos, vel = self.orca.step(self.preferred_velocities(positions))
        for i in np.flatnonzero(self._pressed(pos)):  # never seen at Δt <= 0.5 s; a guard
            p = self._outside(pos[i])
            if p is not None:
                self.orca.move_agent(int(i), p)
                pos[i] = p
        dwell, waypoint, routes = self.dwell, self.waypoint, self._route_points
        for i, (x, y) in enumerate(pos.tolist()):
            if dwell[i] > 0:
                dwell[i] = max(0.0, dwell[i] - dt)
                if dwell[i] == 0:
                    self._next_job(i, pos[i])
            elif waypoint[i] == len(routes[i]) - 1 and math.dist((x, y), routes[i][-1]) < ARRIVAL:
                dwell[i] = max(self.rng.uniform(*self.dwell_time), dt)
        return pos, vel

    def _pressed(self, positions: np.ndarray) -> np.ndarray:
        """(n,) bool: the pickers whose centre is closer than their radius (- 1 µm) to a rack or a wall, i.e. outside
        ``layout.free_space(human_radius - 1e-6)``. With boxes for racks: by the exact distance, asked only of the
        pickers within ``BAND`` more than that of a rack or a wall along x or y (rare), unless it is within ``BAND``
        of the radius (then by shapely's polygon)."""
        radius = self.scene.human_radius - 1e-6
        if self._clear is None:
            return ~in_free_space(self._layout, positions, radius)
        pressed = ~shapely.contains_xy(self._clear, positions[:, 0], positions[:, 1])
        if pressed.any():
            hall = (self._layout.width / 2, self._layout.height / 2)
            for i in np.flatnonzero(pressed).tolist():
                d = point_clearance(*positions[i].tolist(), self._boxes, hall)
                pressed[i] = d < radius if abs(d - radius) > BAND else \
                    not in_free_space(self._layout, positions[i][None], radius)[0]
        return pressed

    def _clear_region(self) -> shapely.Polygon | None:
        """Where a picker's centre is certainly clear of racks and walls (prepared): the hall and the racks, boxes,
        shrunk and grown by the radius + ``BAND`` (square corners); None unless the grown racks stay apart."""
        if self._boxes is None or self.roadmap.grown is None:  # the roadmap's clearance is wider: apart there, apart here
            return None
        c, w, h = self.scene.human_radius + BAND, self._layout.width / 2, self._layout.height / 2
        holes = [[(x0 - c, y0 - c), (x1 + c, y0 - c), (x1 + c, y1 + c), (x0 - c, y1 + c)] for x0, y0, x1, y1 in self._boxes]
        region = shapely.Polygon([(-w + c, -h + c), (w - c, -h + c), (w - c, h - c), (-w + c, h - c)], holes)
        shapely.prepare(region)
        return region

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
