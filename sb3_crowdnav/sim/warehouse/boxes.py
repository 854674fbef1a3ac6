"""Fast geometry of layouts whose racks are axis-aligned rectangles ("boxes"), as every generated layout's are.

`shapely` answers every geometric question about a layout, but it builds the free space of a clearance (the hall
minus the racks, buffered) as a general polygon and answers each question through a general predicate, and an env
that draws a layout per episode asks many. For boxes in a rectangular hall the same questions are a few comparisons:

* the free space of a disc of radius ``c`` with mitred corners (the roadmaps') is the hall shrunk by ``c`` minus
  the racks grown by ``c``, each grown rack again a box: a segment is in it when it enters none of those boxes
  (Liang-Barsky clipping);
* with round corners (the robot's line of sight, the pickers' room, the pick slots) a point or a segment is in
  it when its distance to every rack and to the walls is at least ``c``.

The loops that answer them are compiled (:mod:`~sb3_crowdnav.sim.warehouse.kernels`: ``misses_boxes``,
``bitangent_edges``, ``joins``, ``points_clearance``, ``segment_clearance``, ``pressed``); this module keeps what
decides which geometry applies (:func:`rack_boxes`), the pick slots' test (:func:`in_free_space`) and the roadmap's
free space among boxes (:class:`BoxSpace`).

shapely's round buffers approximate the arcs around rack corners by chords (within 0.4 mm at the radii used here).
The pick slots (:func:`in_free_space`) therefore take the answer of an exact distance only when it is farther than
:data:`BAND` from the threshold and ask shapely otherwise, so they are shapely's everywhere; the robot's line of sight
and the pickers' overlap guard take the exact distance itself (to within 1 µm of the radius).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import shapely

from sb3_crowdnav.sim.warehouse import kernels

BAND = 1e-3  # [m] an exact distance this close to a round free space's radius is left to shapely's polygon


def rack_boxes(racks: Sequence[np.ndarray]) -> np.ndarray | None:
    """(B, 4) ``[xmin, ymin, xmax, ymax]`` of the racks when every one is an axis-aligned rectangle of positive
    area (four vertices, the corners of its bounding box, in ring order), else None."""
    if not racks or any(len(r) != 4 for r in racks):
        return None if racks else np.zeros((0, 4))
    vertices = np.stack(racks)  # (B, 4, 2)
    lo, hi = vertices.min(axis=1), vertices.max(axis=1)
    at_corner = ((vertices == lo[:, None]) | (vertices == hi[:, None])).all(axis=(1, 2))
    steps = vertices != np.roll(vertices, -1, axis=1)  # (B, 4, 2): which coordinates change along each edge
    one_axis = (steps.sum(axis=2) == 1).all(axis=1)  # every edge along x or along y: a rectangle, no bow tie
    if not (at_corner & one_axis & (hi > lo).all(axis=1)).all():
        return None
    return np.concatenate([lo, hi], axis=1)


def in_free_space(layout: Any, points: np.ndarray, clearance: float) -> np.ndarray:
    """(n,) bool: ``shapely.contains_xy(layout.free_space(clearance), ...)`` of ``points`` (n, 2), the free space
    built only when the racks are not boxes or a point is within :data:`BAND` of its boundary."""
    boxes = layout.boxes
    if boxes is None:
        d, unsure = None, np.ones(len(points), dtype=bool)
    else:
        d = kernels.points_clearance(np.ascontiguousarray(points, dtype=np.float64), boxes, layout.width / 2,
                                     layout.height / 2)  # the distance to the nearest rack or wall
        unsure = np.abs(d - clearance) <= BAND
    inside = np.zeros(len(points), dtype=bool) if d is None else d > clearance
    if unsure.any():
        free = layout.free_space(clearance)
        shapely.prepare(free)
        inside[unsure] = shapely.contains_xy(free, points[unsure, 0], points[unsure, 1])
    return inside


class BoxSpace:
    """The free space of a disc of radius ``c`` among box racks whose grown copies stay apart and off the walls: the
    shrunk ``hall`` (x0, y0, x1, y1) minus the racks grown by ``c`` (shapely's mitred buffers, whose corners these
    are to within an ulp). A :class:`~sb3_crowdnav.sim.warehouse.roadmap.Roadmap`'s free space, asked through the same
    methods as :class:`~sb3_crowdnav.sim.warehouse.roadmap.PolygonSpace`'s.

    The graph keeps only what a shortest path can use: the racks' corners (a shortest path never bends at a corner of
    the hall) and the bitangents, the edges that pass each of their ends on the outside of its rack: a segment leaving
    a rack's corner along (dx, dy) does so when ``side * dx * dy <= 0`` (both sides of the rack at the corner on one
    side of the segment, as each segment of a shortest route is at a corner it bends around; the product keeps its
    sign along -(dx, dy)). A route's end is joined likewise. The same shortest routes, from about a third of the edges.
    """

    def __init__(self, hall: tuple[float, float, float, float], geometry: kernels.BoxRoadmap) -> None:
        self.hall = hall
        self.grown = geometry.grown  # (B, 4) closed: a disc centred in one overlaps its rack
        self.opened = geometry.opened  # (B, 4) open: a segment may run along a grown rack's side
        self.corners, self.sides = geometry.corners, geometry.sides
        self.nodes = np.arange(4, len(self.corners))
        self._grown_list = self.grown.tolist()

    def edges(self) -> tuple[list[int], list[int], list[float]]:
        """Both corners and the length of every bitangent, in the order of ``np.triu_indices``."""
        i, j, lengths = self.edge_arrays()
        return i.tolist(), j.tolist(), lengths.tolist()

    def edge_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`edges` as arrays: i (E,) and j (E,) int64, the lengths (E,)."""
        return kernels.bitangent_edges(self.corners, self.sides, 4, self.opened)

    def free_points(self, points: np.ndarray) -> list[bool]:
        """:meth:`is_free` of each of ``points`` (n, 2)."""
        return kernels.free_points(points, self.hall, self.grown).tolist()

    def is_free(self, point: Sequence[float]) -> bool:
        """Whether the disc centred at ``point`` is in the free space."""
        (x, y), (x0, y0, x1, y1) = point, self.hall
        return bool(x0 < x < x1 and y0 < y < y1 and not any(gx0 <= x <= gx1 and gy0 <= y <= gy1
                                                            for gx0, gy0, gx1, gy1 in self._grown_list))

    def sees(self, a: Sequence[float], b: Sequence[float]) -> bool:
        """Whether the segment ``a``-``b`` lies in the free space (both ends in the hall to within 1 µm)."""
        (ax, ay), (bx, by), (x0, y0, x1, y1) = a, b, self.hall
        inside = x0 - 1e-6 <= min(ax, bx) and max(ax, bx) <= x1 + 1e-6 and y0 - 1e-6 <= min(ay, by) and \
            max(ay, by) <= y1 + 1e-6
        return inside and kernels.misses_boxes(ax, ay, bx, by, self.opened)

    def joins(self, point: Sequence[float]) -> tuple[list[int], list[float]]:
        """The corners a route's end at ``point`` sees and passes on the outside, and their distances; none when
        ``point`` is outside the hall."""
        (px, py), (x0, y0, x1, y1) = point, self.hall
        if not (x0 - 1e-6 <= px <= x1 + 1e-6 and y0 - 1e-6 <= py <= y1 + 1e-6):
            return [], []
        nodes, lengths = kernels.joins(px, py, self.corners, self.sides, 4, self.opened)
        return nodes.tolist(), lengths.tolist()

    def query(self, start: Sequence[float], goal: Sequence[float]) -> kernels.RouteQuery:
        """What a route from ``start`` to ``goal`` asks before its search, in one kernel call."""
        (sx, sy), (gx, gy) = start, goal
        return kernels.RouteQuery(*kernels.route_query_fields(sx, sy, gx, gy, self.corners, self.sides, 4, self.opened,
                                                              self.hall))


__all__ = ["BAND", "BoxSpace", "in_free_space", "rack_boxes"]
