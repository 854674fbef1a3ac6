"""Readable NumPy and Python-float forms of the geometry that the compiled kernels (``sb3_crowdnav.sim.geometry``,
``sb3_crowdnav.sim.warehouse.kernels``) implement: the references the kernels are tested against, with tolerances
(to rounding: the kernels' operations need not be these in this order) and properties."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` to segments ``a``-``b``; all (..., 2), broadcast; returns (...)."""
    ab = b - a
    length2 = np.sum(ab * ab, axis=-1)
    t = np.clip(np.sum((p - a) * ab, axis=-1) / np.where(length2 > 1e-18, length2, 1.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - (a[..., 1] - o[..., 1]) * (b[..., 0] - o[..., 0])


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Minimum distance between segments ``p0``-``p1`` and ``q0``-``q1``; all (..., 2), broadcast: zero when they
    cross, otherwise the smallest of the four endpoint-to-segment distances."""
    crossing = (_cross(q0, q1, p0) * _cross(q0, q1, p1) < 0) & (_cross(p0, p1, q0) * _cross(p0, p1, q1) < 0)
    ends = np.minimum(
        np.minimum(point_segment_distance(p0, q0, q1), point_segment_distance(p1, q0, q1)),
        np.minimum(point_segment_distance(q0, p0, p1), point_segment_distance(q1, p0, p1)),
    )
    return np.where(crossing, 0.0, ends)


def separated(boxes: np.ndarray, inner: tuple[float, float, float, float]) -> bool:
    """Whether ``boxes`` (B, 4) lie strictly inside the rectangle ``inner`` and pairwise apart (a gap in x or y)."""
    x0, y0, x1, y1 = inner
    listed = boxes.tolist()
    if not all(x0 < a and y0 < b and c < x1 and d < y1 for a, b, c, d in listed):
        return False
    return all(p[2] < q[0] or q[2] < p[0] or p[3] < q[1] or q[3] < p[1]
               for k, p in enumerate(listed) for q in listed[k + 1 :])


def segments_miss_boxes(a: np.ndarray, b: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(n,) bool: the segment ``a[k]``-``b[k]`` (each (n, 2)) enters the interior of none of the ``boxes`` (B, 4);
    running along a box's side or through its corner is allowed (Liang-Barsky clipping against the open boxes).

    Along an axis the segment does not move in, the division by zero gives the right answer by itself: t = ±inf
    (inside that slab for every t, or for none) or NaN when it runs on the slab's edge, which the NaN-propagating
    ``minimum``/``maximum`` turn into "misses" (the slab is open).
    """
    enter, leave = np.zeros((len(boxes), len(a))), np.ones((len(boxes), len(a)))  # (B, n): the part inside
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in (0, 1):
            start, d = a[:, axis], b[:, axis] - a[:, axis]  # (n,)
            t_lo, t_hi = (boxes[:, axis, None] - start) / d, (boxes[:, axis + 2, None] - start) / d  # (B, n)
            enter = np.maximum(enter, np.minimum(t_lo, t_hi))
            leave = np.minimum(leave, np.maximum(t_lo, t_hi))
    return ~(enter < leave).any(axis=0)


def points_clearance(points: np.ndarray, boxes: np.ndarray, hall: tuple[float, float]) -> np.ndarray:
    """(n,) distance from each of ``points`` (n, 2) to the nearest rack (a box of ``boxes`` (B, 4), solid) or wall
    (the hall ``[-hall[0], hall[0]] x [-hall[1], hall[1]]``); 0 inside a rack, negative outside the hall."""
    (x, y), (w, h) = points.T, hall
    out = np.minimum(np.minimum(x + w, w - x), np.minimum(y + h, h - y))
    if len(boxes):
        dx = np.maximum(np.maximum(boxes[:, 0, None] - x, x - boxes[:, 2, None]), 0.0)  # (B, n)
        dy = np.maximum(np.maximum(boxes[:, 1, None] - y, y - boxes[:, 3, None]), 0.0)
        out = np.minimum(out, np.sqrt(dx * dx + dy * dy).min(axis=0))
    return out


def point_clearance(x: float, y: float, boxes: list[tuple[float, float, float, float]], hall: tuple[float, float]) -> float:
    """:func:`points_clearance` of one point, in floats."""
    w, h = hall
    best = min(x + w, w - x, y + h, h - y)
    for x0, y0, x1, y1 in boxes:
        dx, dy = max(x0 - x, 0.0, x - x1), max(y0 - y, 0.0, y - y1)
        if dx < best and dy < best:
            best = min(best, math.sqrt(dx * dx + dy * dy))
    return best


def segment_clearance(a: Sequence[float], b: Sequence[float], boxes: list[tuple[float, float, float, float]],
                      hall: tuple[float, float], cap: float) -> float:
    """Distance from the segment ``a``-``b`` to the nearest rack (a box of ``boxes``) or wall (see
    :func:`points_clearance`), in floats; racks farther than ``cap`` from the segment's bounding box are skipped, so
    a value >= ``cap`` only means "at least ``cap``".

    The walls are nearest at an end (the hall is convex); a rack is 0 away when the segment meets it, else nearest
    at an end of the segment or at a corner of the rack (the nearest points of two disjoint convex sets).
    """
    (ax, ay), (bx, by), (w, h) = a, b, hall
    best = min(cap, ax + w, w - ax, ay + h, h - ay, bx + w, w - bx, by + h, h - by)
    dx, dy = bx - ax, by - ay
    sx0, sx1, sy0, sy1 = min(ax, bx), max(ax, bx), min(ay, by), max(ay, by)
    for box in boxes:
        x0, y0, x1, y1 = box
        if x0 - sx1 >= best or sx0 - x1 >= best or y0 - sy1 >= best or sy0 - y1 >= best:
            continue
        if segment_meets_box(ax, ay, dx, dy, box):
            return 0.0
        ends = [math.hypot(max(x0 - px, 0.0, px - x1), max(y0 - py, 0.0, py - y1)) for px, py in ((ax, ay), (bx, by))]
        best = min(best, *ends, *(_point_segment(cx, cy, ax, ay, dx, dy) for cx in (x0, x1) for cy in (y0, y1)))
    return max(best, 0.0)


def _point_segment(px: float, py: float, ax: float, ay: float, dx: float, dy: float) -> float:
    """Distance from ``(px, py)`` to the segment from ``(ax, ay)`` along ``(dx, dy)``."""
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 <= 1e-18 else min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / length2))
    return math.hypot(px - ax - t * dx, py - ay - t * dy)


def bitangent_edges(corners: np.ndarray, sides: np.ndarray, boxes: np.ndarray) -> tuple[list, list, list]:
    """A box roadmap's edges: the pairs of corners from 4 on (``np.triu_indices``' order) that pass both ends on the
    outside of their racks and enter none of the open ``boxes``, and their lengths."""
    i, j = (np.arange(4, len(corners))[k] for k in np.triu_indices(len(corners) - 4, k=1))
    d = corners[j] - corners[i]
    turn = d[:, 0] * d[:, 1]
    keep = (sides[i] * turn <= 0) & (sides[j] * turn <= 0)
    i, j, d = i[keep], j[keep], d[keep]
    visible = segments_miss_boxes(corners[i], corners[j], boxes)
    return i[visible].tolist(), j[visible].tolist(), np.linalg.norm(d[visible], axis=1).tolist()


def joins(point: Sequence[float], corners: np.ndarray, sides: np.ndarray, boxes: np.ndarray) -> tuple[list, list]:
    """The corners from 4 on that ``point`` sees (the segment enters no open box) and passes on the outside, and
    their distances."""
    (px, py), nodes, lengths = point, [], []
    for k in range(4, len(corners)):
        cx, cy = corners[k].tolist()
        dx, dy = px - cx, py - cy
        (sx0, sx1), (sy0, sy1) = sorted((px, cx)), sorted((py, cy))
        misses = not any(x0 < sx1 and sx0 < x1 and y0 < sy1 and sy0 < y1 and
                         segment_meets_box(px, py, cx - px, cy - py, (x0, y0, x1, y1), interior=True)
                         for x0, y0, x1, y1 in boxes.tolist())
        if sides[k] * dx * dy <= 0 and misses:
            nodes.append(k)
            lengths.append(math.sqrt(dx * dx + dy * dy))
    return nodes, lengths


def slot_points(segments: np.ndarray, spacing: float, offset: float) -> np.ndarray:
    """Along every edge (S, 4) ``length // spacing`` points, evenly spread, ``offset`` out along its normal."""
    (ax, ay), (ex, ey) = segments[:, :2].T, (segments[:, 2:] - segments[:, :2]).T
    length = np.hypot(ex, ey)
    count = np.where(length >= spacing, length // spacing, 0.0).astype(np.int64)
    edge = np.repeat(np.arange(len(count)), count)
    k = np.arange(len(edge)) - np.repeat(np.cumsum(count) - count, count)
    ax, ay, ex, ey, length = ax[edge], ay[edge], ex[edge], ey[edge], length[edge]
    t = (k + 0.5) * length / count[edge]
    return np.stack([ax + ex * (t / length) + ey / length * offset, ay + ey * (t / length) + -ex / length * offset], axis=1)


def preferences(positions: np.ndarray, dwell: np.ndarray, waypoint: list[int], routes: list, v_prefs: list[float],
                arrivals: list[float]) -> list[list[float]]:
    """The pickers' preferred velocities: towards the current waypoint (those within the picker's ``arrivals[i]``
    passed, never the last) at its ``v_prefs[i]``, slowing into the last one; zero while standing. ``waypoint``
    updated in place."""
    out = []
    for i, (x, y) in enumerate(positions.tolist()):
        if dwell[i] > 0:
            out.append([0.0, 0.0])
            continue
        route, w, v_pref, arrival = routes[i], waypoint[i], v_prefs[i], arrivals[i]
        while w < len(route) - 1 and math.dist((x, y), route[w]) < arrival:
            w += 1
        waypoint[i] = w
        dx, dy = route[w][0] - x, route[w][1] - y
        norm = math.hypot(dx, dy)
        if norm > v_pref or (w < len(route) - 1 and norm > 1e-9):
            dx, dy = dx / norm * v_pref, dy / norm * v_pref
        out.append([dx, dy])
    return out


def segment_meets_box(ax: float, ay: float, dx: float, dy: float, box: Sequence[float], interior: bool = False) -> bool:
    """Whether the segment from ``(ax, ay)`` along ``(dx, dy)`` meets the closed ``box`` ``[xmin, ymin, xmax, ymax]``,
    or its interior (``interior``; the test of :func:`segments_miss_boxes`, for one segment and one box, in floats:
    the part of the segment in each slab, t in [enter, leave], the two axes written out)."""
    x0, y0, x1, y1 = box
    if dx == 0:
        if not (x0 < ax < x1 if interior else x0 <= ax <= x1):
            return False
        enter, leave = 0.0, 1.0
    else:
        t0, t1 = (x0 - ax) / dx, (x1 - ax) / dx
        if t1 < t0:
            t0, t1 = t1, t0
        enter, leave = (t0 if t0 > 0.0 else 0.0), (t1 if t1 < 1.0 else 1.0)
    if dy == 0:
        if not (y0 < ay < y1 if interior else y0 <= ay <= y1):
            return False
    else:
        t0, t1 = (y0 - ay) / dy, (y1 - ay) / dy
        if t1 < t0:
            t0, t1 = t1, t0
        enter, leave = (t0 if t0 > enter else enter), (t1 if t1 < leave else leave)
    return enter < leave if interior else enter <= leave
