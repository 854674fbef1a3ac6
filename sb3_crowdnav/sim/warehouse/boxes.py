"""Fast geometry of layouts whose racks are axis-aligned rectangles ("boxes"), as every generated layout's are.

`shapely` answers every geometric question about a layout, but building the free space of a clearance (the hall
minus the racks, buffered) costs a tenth of a millisecond and each predicate call microseconds, and an env that
draws a layout per episode asks many. For boxes in a rectangular hall the same questions are a few comparisons:

* the free space of a disc of radius ``c`` with mitred corners (the roadmaps') is the hall shrunk by ``c`` minus
  the racks grown by ``c``, each grown rack again a box: a segment is in it when it enters none of those boxes
  (Liang-Barsky clipping);
* with round corners (the robot's line of sight, the pickers' room, the pick slots) a point or a segment is in
  it when its distance to every rack and to the walls is at least ``c``.

The loops that answer them are compiled (:mod:`~sb3_crowdnav.sim.warehouse.kernels`: ``misses_boxes``,
``bitangent_edges``, ``joins``, ``points_clearance``, ``segment_clearance``, ``pressed``); this module keeps what
decides which geometry applies (:func:`rack_boxes`) and the pick slots' test (:func:`in_free_space`).

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


__all__ = ["BAND", "in_free_space", "rack_boxes"]
