"""Pickers: ORCA pedestrians that see the racks, walk routes between pick faces and stand there for a while.

Each picker's job is endless: walk to a pick slot along a roadmap route, stand for a dwell time drawn from
``dwell_time``, draw the next slot, walk on. At the start of an episode about half of the pickers are
standing at a slot (with a part of their dwell left), the others walking to their first one, so some
pickers stand still at any moment. Obstacle avoidance is RVO2's own (``pyrvo``'s ``add_obstacle``);
because ORCA at a large time step can still press an agent into a thin obstacle, every step ends by
pushing any picker that overlaps a rack or a wall back out to its radius (:meth:`PickerCrowd.step`).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.ops import nearest_points

from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.orca import OrcaCrowd
from sb3_crowdnav.sim.warehouse.layout import Roadmap, WarehouseLayout

SLOT_OFFSET = 0.1  # [m] a standing picker keeps this much between its body and the rack face
ARRIVAL = 0.25  # [m] a waypoint of a picker's route counts as reached this close


def pick_slots(layout: WarehouseLayout, scene: SceneConfig) -> np.ndarray:
    """Where a picker stands to pick: points along every rack edge, ``human_radius + SLOT_OFFSET`` out from it,
    spaced by a picker's diameter + 0.2 m, kept where a picker fits; (n, 2)."""
    radius = scene.human_radius
    free = layout.free_space(radius + 1e-3)
    shapely.prepare(free)
    spacing = 2 * radius + 0.2
    points = []
    for rack in layout.racks:
        ring = shapely.geometry.polygon.orient(shapely.geometry.Polygon(rack))
        coords = np.asarray(ring.exterior.coords)
        for a, b in itertools.pairwise(coords):
            edge = b - a
            length = float(np.hypot(*edge))
            if length < spacing:
                continue
            normal = np.array([edge[1], -edge[0]]) / length  # outward for a counter-clockwise ring
            count = int(length // spacing)
            for k in range(count):
                t = (k + 0.5) * length / count
                points.append(a + edge * (t / length) + normal * (radius + SLOT_OFFSET))
    if not points:
        return np.zeros((0, 2))
    points = np.asarray(points)
    return points[shapely.contains_xy(free, points[:, 0], points[:, 1])]


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
        self._room = layout.free_space(scene.human_radius - 1e-6)  # a centre outside it overlaps a rack or wall
        shapely.prepare(self._room)
        self.orca = OrcaCrowd(scene, slots[starts], np.full(n, scene.human_radius), np.full(n, scene.human_v_pref),
                              None, obstacles=layout.polygons)
        self.slot = np.array(starts, dtype=np.int64)  # a copy: the caller keeps the start slots
        self.routes: list[np.ndarray] = [slots[s][None] for s in starts]
        self.waypoint = np.zeros(n, dtype=np.int64)
        self.dwell = np.zeros(n)
        standing = rng.random(n) < 0.5
        for i in range(n):
            if standing[i]:
                self.dwell[i] = rng.uniform(*dwell_time) * rng.random()
            else:
                self._next_job(i, slots[starts[i]])

    @property
    def standing(self) -> np.ndarray:
        """(n,) bool: the pickers standing at a pick face now."""
        return self.dwell > 0

    def _next_job(self, i: int, position: np.ndarray) -> None:
        """Send picker ``i`` to another slot along the roadmap (its dwell is over)."""
        choices = np.flatnonzero(np.arange(len(self.slots)) != self.slot[i])
        self.slot[i] = int(self.rng.choice(choices)) if len(choices) else self.slot[i]
        try:
            self.routes[i] = self.roadmap.route(position, self.slots[self.slot[i]])[1:]
        except ValueError:  # cornered by the others' clearance: stay and pick here once more
            self.routes[i] = self.slots[self.slot[i]][None]
        self.waypoint[i] = 0

    def preferred_velocities(self, positions: np.ndarray) -> list[tuple[float, float]]:
        """Towards the current waypoint at v_pref (slowing into the last one); zero while standing."""
        v_pref, out = self.scene.human_v_pref, []
        for i, (x, y) in enumerate(positions.tolist()):
            if self.dwell[i] > 0:
                out.append((0.0, 0.0))
                continue
            route = self.routes[i]
            while self.waypoint[i] < len(route) - 1 and math.dist((x, y), route[self.waypoint[i]]) < ARRIVAL:
                self.waypoint[i] += 1
            gx, gy = route[self.waypoint[i]]
            dx, dy = gx - x, gy - y
            norm = math.hypot(dx, dy)
            last = self.waypoint[i] == len(route) - 1
            if norm > v_pref or (not last and norm > 1e-9):
                dx, dy = dx / norm * v_pref, dy / norm * v_pref
            out.append((dx, dy))
        return out

    def step(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One ORCA step from ``positions`` (n, 2); new positions and velocities, each (n, 2)."""
        dt = self.scene.time_step
        pos, vel = self.orca.step(self.preferred_velocities(positions))
        pressed = ~shapely.contains_xy(self._room, pos[:, 0], pos[:, 1])
        for i in np.flatnonzero(pressed):  # never seen at Δt <= 0.5 s; a guard that costs one vectorised call
            p = self._outside(pos[i])
            if p is not None:
                self.orca.move_agent(int(i), p)
                pos[i] = p
        for i in range(self.n):
            if self.dwell[i] > 0:
                self.dwell[i] = max(0.0, self.dwell[i] - dt)
                if self.dwell[i] == 0:
                    self._next_job(i, pos[i])
            elif self.waypoint[i] == len(self.routes[i]) - 1 and math.dist(pos[i], self.routes[i][-1]) < ARRIVAL:
                self.dwell[i] = max(self.rng.uniform(*self.dwell_time), dt)
        return pos, vel

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
