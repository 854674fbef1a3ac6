"""The kernels' shared pieces: box clipping and the clearances of points and segments to racks and walls."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from sb3_crowdnav.sim.geometry import JIT, point_to_segment
from sb3_crowdnav.sim.sensing import deliver


@njit(**JIT)
def misses_boxes(ax, ay, bx, by, boxes):  # pragma: no cover  (compiled)
    """Whether the segment from (ax, ay) to (bx, by) enters the open interior of none of ``boxes`` (B, 4) (boxes beside
    its bounding box skipped, the others by :func:`_meets_box`'s interior test): running along a box's side or through
    its corner is allowed. The roadmap's edges, a route's ends and lines of sight are tested so."""
    sx0, sx1 = (ax, bx) if ax < bx else (bx, ax)
    sy0, sy1 = (ay, by) if ay < by else (by, ay)
    for k in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        if x0 < sx1 and sx0 < x1 and y0 < sy1 and sy0 < y1 and \
                _meets_box(ax, ay, bx - ax, by - ay, x0, y0, x1, y1, True):
            return False
    return True


@njit(**JIT)
def point_clearance(x, y, boxes, w, h):  # pragma: no cover  (compiled)
    """The distance from (x, y) to the nearest rack (a box of ``boxes`` (B, 4), solid) or wall (the hall
    [-w, w] x [-h, h]); 0 inside a rack, negative outside the hall (boxes not nearer than the best so far skipped)."""
    best = min(x + w, w - x, y + h, h - y)
    for k in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        if x0 - x < best and x - x1 < best and y0 - y < best and y - y1 < best:  # else no nearer than best
            best = min(best, _point_box(x, y, x0, y0, x1, y1))
    return best


@njit(**JIT)
def _point_box(x, y, x0, y0, x1, y1):  # pragma: no cover  (compiled)
    """Distance from (x, y) to the closed box [x0, x1] x [y0, y1] (0 inside)."""
    return math.hypot(max(x0 - x, 0.0, x - x1), max(y0 - y, 0.0, y - y1))


@njit(**JIT)
def _meets_box(ax, ay, dx, dy, x0, y0, x1, y1, interior):  # pragma: no cover  (compiled)
    """Whether the segment from (ax, ay) along (dx, dy) meets the closed box, or its open interior (``interior``):
    the part of the segment in each slab, t in [enter, leave], the two axes written out (Liang-Barsky)."""
    if dx == 0:
        if not ((x0 < ax < x1) if interior else (x0 <= ax <= x1)):
            return False
        enter, leave = 0.0, 1.0
    else:
        t0, t1 = (x0 - ax) / dx, (x1 - ax) / dx
        if t1 < t0:
            t0, t1 = t1, t0
        enter, leave = (t0 if t0 > 0.0 else 0.0), (t1 if t1 < 1.0 else 1.0)
    if dy == 0:
        if not ((y0 < ay < y1) if interior else (y0 <= ay <= y1)):
            return False
    else:
        t0, t1 = (y0 - ay) / dy, (y1 - ay) / dy
        if t1 < t0:
            t0, t1 = t1, t0
        enter, leave = (t0 if t0 > enter else enter), (t1 if t1 < leave else leave)
    return enter < leave if interior else enter <= leave


@njit(**JIT)
def segment_clearance(ax, ay, bx, by, boxes, w, h, cap):  # pragma: no cover  (compiled)
    """Distance from the segment (ax, ay)-(bx, by) to the nearest rack (a box of ``boxes``) or wall of the hall
    [-w, w] x [-h, h]; racks farther than ``cap`` from the segment's bounding box are skipped, so a value >= ``cap``
    only means "at least ``cap``". The walls are nearest at an end (the hall is convex); a rack is 0 away when the
    segment meets it, else nearest at an end of the segment or at a corner of the rack (the nearest points of two
    disjoint convex sets)."""
    best = min(cap, ax + w, w - ax, ay + h, h - ay, bx + w, w - bx, by + h, h - by)
    dx, dy = bx - ax, by - ay
    sx0, sx1, sy0, sy1 = min(ax, bx), max(ax, bx), min(ay, by), max(ay, by)
    for k in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        if x0 - sx1 >= best or sx0 - x1 >= best or y0 - sy1 >= best or sy0 - y1 >= best:
            continue
        if _meets_box(ax, ay, dx, dy, x0, y0, x1, y1, False):
            return 0.0
        best = min(best, _point_box(ax, ay, x0, y0, x1, y1), _point_box(bx, by, x0, y0, x1, y1),
                   point_to_segment(x0, y0, ax, ay, bx, by), point_to_segment(x0, y1, ax, ay, bx, by),
                   point_to_segment(x1, y0, ax, ay, bx, by), point_to_segment(x1, y1, ax, ay, bx, by))
    return max(best, 0.0)


@njit(**JIT)
def disc_in_sight(ox, oy, cx, cy, r, boxes):  # pragma: no cover  (compiled)
    """Whether a line of sight from (ox, oy) reaches the disc of centre (cx, cy) and radius ``r`` past ``boxes`` (B, 4):
    one of three lines, to the centre and to the disc's two sides across the line of sight (centre ± r, perpendicular
    to it), enters the open interior of no box (:func:`misses_boxes`: grazing a side or a corner does not block)."""
    if misses_boxes(ox, oy, cx, cy, boxes):
        return True
    dx, dy = cx - ox, cy - oy
    d = math.hypot(dx, dy)
    if d <= 1e-12:
        return False
    px, py = -dy / d * r, dx / d * r
    return misses_boxes(ox, oy, cx + px, cy + py, boxes) or misses_boxes(ox, oy, cx - px, cy - py, boxes)


@njit(**JIT)
def discs_in_sight(ox, oy, positions, radii, boxes):  # pragma: no cover  (compiled)
    """(n,) bool: :func:`disc_in_sight` of each disc (``positions`` (n, 2), ``radii`` (n,))."""
    out = np.zeros(positions.shape[0], dtype=np.bool_)
    for i in range(positions.shape[0]):
        out[i] = disc_in_sight(ox, oy, positions[i, 0], positions[i, 1], radii[i], boxes)
    return out


@njit(**JIT)
def people_frame(ox, oy, row, present, sensor_range, boxes, states, seen):  # pragma: no cover  (compiled)
    """One frame of the people sensor (:mod:`sb3_crowdnav.sim.sensing`'s rules) into ``states`` (M, 5) and ``seen``
    (M,): a person of ``row`` (M, 5: x, y, vx, vy, radius) is seen when ``present``, their disc within
    ``sensor_range`` of (ox, oy) (< 0: unlimited) and :func:`disc_in_sight` past ``boxes``; their state is copied,
    zeros otherwise."""
    for i in range(row.shape[0]):
        s = present[i]
        if s and sensor_range >= 0.0:
            s = math.hypot(row[i, 0] - ox, row[i, 1] - oy) - row[i, 4] <= sensor_range
        if s:
            s = disc_in_sight(ox, oy, row[i, 0], row[i, 1], row[i, 4], boxes)
        seen[i] = s
        for k in range(row.shape[1]):
            states[i, k] = row[i, k] if s else 0.0


@njit(**JIT)
def people_deliver(ox, oy, row, present, sensor_range, boxes, history, mask):  # pragma: no cover  (compiled)
    """:func:`people_frame`, then the frame delivered into the observed ``history`` (T, M, 5) and ``mask`` (M,) by
    :func:`~sb3_crowdnav.sim.sensing.deliver`, in one call (a sensor without latency, noise or ``"nearest"``)."""
    states, seen = np.empty_like(row), np.empty(row.shape[0], np.bool_)
    people_frame(ox, oy, row, present, sensor_range, boxes, states, seen)
    deliver(history, mask, states, seen)
