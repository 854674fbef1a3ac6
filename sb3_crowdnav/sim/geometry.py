"""Segment geometry for static obstacles, one implementation for the env and the lookahead (numpy, broadcasting).

Obstacles are line segments ``[x0, y0, x1, y1]`` (the edges of racks and the inner faces of the walls). The
robot collides with an obstacle when the straight path of its centre during a step passes closer than its
radius to any segment (the swept disc touches it), checked with :func:`segment_distance`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

SEGMENT_DIM = 4  # x0, y0, x1, y1


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` to segments ``a``-``b``; all (..., 2), broadcast; returns (...)."""
    ab = b - a
    length2 = np.sum(ab * ab, axis=-1)
    t = np.clip(np.sum((p - a) * ab, axis=-1) / np.where(length2 > 1e-18, length2, 1.0), 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.linalg.norm(p - closest, axis=-1)


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - (a[..., 1] - o[..., 1]) * (b[..., 0] - o[..., 0])


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Minimum distance between segments ``p0``-``p1`` and ``q0``-``q1``; all (..., 2), broadcast; returns (...).

    Zero when they cross; otherwise the smallest of the four endpoint-to-segment distances.
    """
    d1, d2 = _cross(q0, q1, p0), _cross(q0, q1, p1)
    d3, d4 = _cross(p0, p1, q0), _cross(p0, p1, q1)
    crossing = (d1 * d2 < 0) & (d3 * d4 < 0)
    ends = np.minimum(
        np.minimum(point_segment_distance(p0, q0, q1), point_segment_distance(p1, q0, q1)),
        np.minimum(point_segment_distance(q0, p0, p1), point_segment_distance(q1, p0, p1)),
    )
    return np.where(crossing, 0.0, ends)


def swept_clearance(pos0: np.ndarray, pos1: np.ndarray, segments: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Smallest distance between the path ``pos0``-``pos1`` (..., 2) of the robot's centre and the present segments.

    :param segments: (..., M, 4); :param mask: (..., M) (True/1: a segment, 0: padding)
    :return: (...) [m], ``inf`` without any segment; the robot hits an obstacle where it is below its radius
    """
    a, b = segments[..., :2], segments[..., 2:]
    d = segment_distance(pos0[..., None, :], pos1[..., None, :], a, b)
    d = np.where(np.asarray(mask) > 0.5, d, np.inf)
    return d.min(axis=-1) if d.shape[-1] else np.full(d.shape[:-1], np.inf)


def point_segment_distance_scalar(p: Sequence[float], a: Sequence[float], b: Sequence[float]) -> float:
    """:func:`point_segment_distance` of one point and one segment, in Python floats (the same operations in the
    same order, so the same value; NumPy's per-call overhead exceeds the arithmetic of one pair)."""
    abx, aby = b[0] - a[0], b[1] - a[1]
    length2 = abx * abx + aby * aby
    t = ((p[0] - a[0]) * abx + (p[1] - a[1]) * aby) / (length2 if length2 > 1e-18 else 1.0)
    t = min(max(t, 0.0), 1.0)
    dx, dy = p[0] - (a[0] + t * abx), p[1] - (a[1] + t * aby)
    return math.sqrt(dx * dx + dy * dy)


def segment_distance_scalar(p0: Sequence[float], p1: Sequence[float], q0: Sequence[float],
                            q1: Sequence[float]) -> float:
    """:func:`segment_distance` of two segments, in Python floats (the same value)."""
    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    if cross(q0, q1, p0) * cross(q0, q1, p1) < 0 and cross(p0, p1, q0) * cross(p0, p1, q1) < 0:
        return 0.0
    return min(point_segment_distance_scalar(p0, q0, q1), point_segment_distance_scalar(p1, q0, q1),
               point_segment_distance_scalar(q0, p0, p1), point_segment_distance_scalar(q1, p0, p1))


def polygon_segments(polygons: list[np.ndarray]) -> np.ndarray:
    """The edges of closed polygons ((k, 2) vertex arrays) as (total, 4) segments."""
    if not polygons:
        return np.zeros((0, SEGMENT_DIM))
    vertices, sizes = np.concatenate(polygons), [len(p) for p in polygons]
    following = np.arange(1, len(vertices) + 1)  # each vertex's successor along its ring (one call per list)
    ends = np.cumsum(sizes) - 1
    following[ends] = ends + 1 - np.asarray(sizes)
    return np.concatenate([vertices, vertices[following]], axis=1)


def nearest_segments(position: np.ndarray, segments: np.ndarray, max_count: int,
                     sensor_range: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``max_count`` segments nearest ``position`` (2,) within ``sensor_range``, nearest first, padded with zeros.

    :return: segments (max_count, 4) and mask (max_count,) bool
    """
    out = np.zeros((max_count, SEGMENT_DIM))
    mask = np.zeros(max_count, dtype=bool)
    if len(segments):
        d = point_segment_distance(position, segments[:, :2], segments[:, 2:])
        order = np.argsort(d, kind="stable")
        order = order[d[order] <= sensor_range][:max_count]
        out[: len(order)] = segments[order]
        mask[: len(order)] = True
    return out, mask
