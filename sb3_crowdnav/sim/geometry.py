"""Segment geometry for static obstacles, one implementation for the env, the warehouse's kernels and the lookahead.

Obstacles are line segments ``[x0, y0, x1, y1]`` (the edges of racks and the inner faces of the walls). The
robot collides with an obstacle when the straight path of its centre during a step passes closer than its
radius to any segment (the swept disc touches it), checked with :func:`segment_distance`.

The distances are compiled scalar functions (``numba``): the warehouse's kernels call them inside their loops, and
the array forms below (broadcasting over leading dimensions) loop over them, so every caller gets the same values.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SEGMENT_DIM = 4  # x0, y0, x1, y1
JIT = dict(cache=True, nogil=True, error_model="numpy")  # error_model: x / 0.0 is inf or NaN, as in NumPy
# [m] distances within this of each other are ties, ordered by index: segments equally far in exact arithmetic (the
# faces of an aisle from its centre line) differ in the last bits of their computed distances, and those bits differ
# between machines (vector width, fused multiply-adds), so ordering by them made the observation machine-dependent
TIE_QUANTUM = 1e-9


@njit(**JIT)
def point_to_segment(px, py, ax, ay, bx, by):  # pragma: no cover  (compiled)
    """Distance from the point (px, py) to the segment (ax, ay)-(bx, by); a segment shorter than 1e-9 is its start."""
    abx, aby = bx - ax, by - ay
    length2 = abx * abx + aby * aby
    t = ((px - ax) * abx + (py - ay) * aby) / (length2 if length2 > 1e-18 else 1.0)
    t = min(max(t, 0.0), 1.0)
    return math.hypot(px - (ax + t * abx), py - (ay + t * aby))


@njit(**JIT)
def _cross(ox, oy, ax, ay, bx, by):  # pragma: no cover  (compiled)
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@njit(**JIT)
def segment_to_segment(p0x, p0y, p1x, p1y, q0x, q0y, q1x, q1y):  # pragma: no cover  (compiled)
    """Minimum distance between the segments p0-p1 and q0-q1: zero when they cross, otherwise the smallest of the
    four endpoint-to-segment distances."""
    if _cross(q0x, q0y, q1x, q1y, p0x, p0y) * _cross(q0x, q0y, q1x, q1y, p1x, p1y) < 0 and \
            _cross(p0x, p0y, p1x, p1y, q0x, q0y) * _cross(p0x, p0y, p1x, p1y, q1x, q1y) < 0:
        return 0.0
    return min(point_to_segment(p0x, p0y, q0x, q0y, q1x, q1y), point_to_segment(p1x, p1y, q0x, q0y, q1x, q1y),
               point_to_segment(q0x, q0y, p0x, p0y, p1x, p1y), point_to_segment(q1x, q1y, p0x, p0y, p1x, p1y))


@njit(**JIT)
def _points_to_segments(p, a, b):  # pragma: no cover  (compiled)
    """(n,) :func:`point_to_segment` of rows of p, a, b (n, 2)."""
    out = np.empty(p.shape[0])
    for k in range(p.shape[0]):
        out[k] = point_to_segment(p[k, 0], p[k, 1], a[k, 0], a[k, 1], b[k, 0], b[k, 1])
    return out


@njit(**JIT)
def _segments_to_segments(p0, p1, q0, q1):  # pragma: no cover  (compiled)
    """(n,) :func:`segment_to_segment` of rows of p0, p1, q0, q1 (n, 2)."""
    out = np.empty(p0.shape[0])
    for k in range(p0.shape[0]):
        out[k] = segment_to_segment(p0[k, 0], p0[k, 1], p1[k, 0], p1[k, 1], q0[k, 0], q0[k, 1], q1[k, 0], q1[k, 1])
    return out


@njit(**JIT)
def _swept_clearances(pos0, pos1, segments, mask):  # pragma: no cover  (compiled)
    """(n,) the smallest :func:`segment_to_segment` of each path pos0[k]-pos1[k] (n, 2) and the segments (n, M, 4)
    where mask (n, M) is set; inf without any."""
    out = np.full(pos0.shape[0], np.inf)
    for k in range(pos0.shape[0]):
        for s in range(segments.shape[1]):
            if mask[k, s]:
                d = segment_to_segment(pos0[k, 0], pos0[k, 1], pos1[k, 0], pos1[k, 1], segments[k, s, 0],
                                       segments[k, s, 1], segments[k, s, 2], segments[k, s, 3])
                out[k] = min(out[k], d)
    return out


@njit(**JIT)
def within(values, bound):  # pragma: no cover  (compiled)
    """Whether every one of ``values`` (n,) lies in [-bound, bound] (False when one is NaN)."""
    for x in values:
        if not (-bound <= x <= bound):
            return False
    return True


def as_rows(x: np.ndarray, lead: tuple[int, ...], tail: tuple[int, ...], dtype: type = np.float64) -> np.ndarray:
    """``x`` broadcast to ``lead + tail`` as (prod(lead), *tail) rows for a compiled loop (a view when ``x`` has that
    shape and dtype: the env's one transition pays no copy)."""
    if type(x) is not np.ndarray or x.dtype != dtype:
        x = np.asarray(x, dtype=dtype)
    if x.shape != lead + tail:
        x = np.broadcast_to(x, lead + tail)
    return x.reshape(-1, *tail)


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` to segments ``a``-``b``; all (..., 2), broadcast; returns (...)."""
    lead = np.broadcast_shapes(np.shape(p)[:-1], np.shape(a)[:-1], np.shape(b)[:-1])
    return _points_to_segments(*(as_rows(x, lead, (2,)) for x in (p, a, b))).reshape(lead)


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Minimum distance between segments ``p0``-``p1`` and ``q0``-``q1``; all (..., 2), broadcast; returns (...).

    Zero when they cross; otherwise the smallest of the four endpoint-to-segment distances.
    """
    lead = np.broadcast_shapes(*(np.shape(x)[:-1] for x in (p0, p1, q0, q1)))
    return _segments_to_segments(*(as_rows(x, lead, (2,)) for x in (p0, p1, q0, q1))).reshape(lead)


def swept_clearance(pos0: np.ndarray, pos1: np.ndarray, segments: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Smallest distance between the path ``pos0``-``pos1`` (..., 2) of the robot's centre and the present segments.

    :param segments: (..., M, 4); :param mask: (..., M) (True/1: a segment, 0: padding)
    :return: (...) [m], ``inf`` without any segment; the robot hits an obstacle where it is below its radius
    """
    m = np.shape(segments)[-2]
    lead = np.broadcast_shapes(np.shape(pos0)[:-1], np.shape(pos1)[:-1], np.shape(segments)[:-2], np.shape(mask)[:-1])
    present = as_rows(np.asarray(mask) > 0.5, lead, (m,), np.bool_)
    rows = (as_rows(pos0, lead, (2,)), as_rows(pos1, lead, (2,)), as_rows(segments, lead, (m, SEGMENT_DIM)), present)
    return _swept_clearances(*rows).reshape(lead)


def polygon_segments(polygons: list[np.ndarray]) -> np.ndarray:
    """The edges of closed polygons ((k, 2) vertex arrays) as (total, 4) segments."""
    if not polygons:
        return np.zeros((0, SEGMENT_DIM))
    vertices, sizes = np.concatenate(polygons), [len(p) for p in polygons]
    following = np.arange(1, len(vertices) + 1)  # each vertex's successor along its ring (one call per list)
    ends = np.cumsum(sizes) - 1
    following[ends] = ends + 1 - np.asarray(sizes)
    return np.concatenate([vertices, vertices[following]], axis=1)


@njit(**JIT)
def distance_order(dist, order):  # pragma: no cover  (compiled)
    """Fill ``order`` (n,) with the indices of ``dist`` (n,) nearest first, distances on the same multiple of
    :data:`TIE_QUANTUM` (rounded) in index order."""
    key = np.empty(dist.shape[0])
    for k in range(dist.shape[0]):
        key[k] = math.floor(dist[k] / TIE_QUANTUM + 0.5)
    order[:] = np.argsort(key, kind="mergesort")  # stable: ties by index


def nearest_segments(position: np.ndarray, segments: np.ndarray, max_count: int,
                     sensor_range: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``max_count`` segments nearest ``position`` (2,) within ``sensor_range``, nearest first (equally far ones in
    index order, :func:`distance_order`), padded with zeros.

    :return: segments (max_count, 4) and mask (max_count,) bool
    """
    out = np.zeros((max_count, SEGMENT_DIM))
    mask = np.zeros(max_count, dtype=bool)
    if len(segments):
        d = point_segment_distance(position, segments[:, :2], segments[:, 2:])
        order = np.zeros(len(d), dtype=np.int64)
        distance_order(d, order)
        order = order[d[order] <= sensor_range][:max_count]
        out[: len(order)] = segments[order]
        mask[: len(order)] = True
    return out, mask
