"""The kernels' shared pieces: CPython's hypot, point and segment distances, box clipping and clearances."""

from __future__ import annotations

import math

from numba import njit

_JIT = dict(cache=True, nogil=True, error_model="numpy")  # error_model: x / 0.0 is inf or NaN, as in NumPy


_T27 = 134217729.0  # 2 ** 27 + 1: Veltkamp-Dekker splitting

@njit(**_JIT)
def _two_sum_into(csum, frac, v):  # pragma: no cover  (compiled)
    """csum + v and the error of that sum added to ``frac`` (|csum| >= |v|)."""
    total = csum + v
    return total, frac + ((csum - total) + v)


@njit(**_JIT)
def py_hypot(x, y):  # pragma: no cover  (compiled)
    """CPython 3.11's ``math.hypot(x, y)`` (``vector_norm`` of two values: scaled by a power of two, squared exactly
    with Veltkamp-Dekker splitting, summed with separate error terms, then one differential correction of the square
    root); also ``math.dist`` of two points, the hypot of their differences."""
    x, y = abs(x), abs(y)
    mx = 0.0
    if x > mx:
        mx = x
    if y > mx:
        mx = y
    if math.isinf(mx):
        return mx
    if math.isnan(x) or math.isnan(y):
        return math.nan
    if mx == 0.0:
        return mx
    e = math.frexp(mx)[1]
    scale = math.ldexp(1.0, -e)  # (CPython's path for subnormal maxima is not reproduced: no distance here has one)
    csum, frac1, frac2, frac3 = 1.0, 0.0, 0.0, 0.0
    for v in (x, y):
        v *= scale
        t = v * _T27
        hi = t - (t - v)
        lo = v - hi
        csum, frac1 = _two_sum_into(csum, frac1, hi * hi)
        csum, frac2 = _two_sum_into(csum, frac2, 2.0 * hi * lo)
        frac3 += lo * lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2 + frac3))
    t = h * _T27
    hi = t - (t - h)
    lo = h - hi
    csum, frac1 = _two_sum_into(csum, frac1, -hi * hi)
    csum, frac2 = _two_sum_into(csum, frac2, -2.0 * hi * lo)
    csum, frac3 = _two_sum_into(csum, frac3, -lo * lo)
    v = csum - 1.0 + (frac1 + frac2 + frac3)
    return (h + v / (2.0 * h)) / scale


@njit(**_JIT)
def _point_segment(px, py, ax, ay, bx, by):  # pragma: no cover  (compiled)
    """:func:`~sb3_crowdnav.sim.geometry.point_segment_distance_scalar`."""
    abx, aby = bx - ax, by - ay
    length2 = abx * abx + aby * aby
    t = ((px - ax) * abx + (py - ay) * aby) / (length2 if length2 > 1e-18 else 1.0)
    t = min(max(t, 0.0), 1.0)
    dx, dy = px - (ax + t * abx), py - (ay + t * aby)
    return math.sqrt(dx * dx + dy * dy)


@njit(**_JIT)
def _cross(ox, oy, ax, ay, bx, by):  # pragma: no cover  (compiled)
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@njit(**_JIT)
def segment_distance(p0x, p0y, p1x, p1y, q0x, q0y, q1x, q1y):  # pragma: no cover  (compiled)
    """:func:`~sb3_crowdnav.sim.geometry.segment_distance_scalar` of the segments p0-p1 and q0-q1."""
    if _cross(q0x, q0y, q1x, q1y, p0x, p0y) * _cross(q0x, q0y, q1x, q1y, p1x, p1y) < 0 and \
            _cross(p0x, p0y, p1x, p1y, q0x, q0y) * _cross(p0x, p0y, p1x, p1y, q1x, q1y) < 0:
        return 0.0
    return min(_point_segment(p0x, p0y, q0x, q0y, q1x, q1y), _point_segment(p1x, p1y, q0x, q0y, q1x, q1y),
               _point_segment(q0x, q0y, p0x, p0y, p1x, p1y), _point_segment(q1x, q1y, p0x, p0y, p1x, p1y))


@njit(**_JIT)
def _nan_min(a, b):  # pragma: no cover  (compiled)
    """``np.minimum`` of two floats: NaN when either is."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a < b else b


@njit(**_JIT)
def _nan_max(a, b):  # pragma: no cover  (compiled)
    """``np.maximum`` of two floats: NaN when either is."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a > b else b


@njit(**_JIT)
def _misses_all(ax, ay, bx, by, boxes):  # pragma: no cover  (compiled)
    """Whether the segment from (ax, ay) to (bx, by) enters the open interior of none of ``boxes`` (B, 4):
    Liang-Barsky clipping, with NumPy's ``minimum``/``maximum`` on the inf and NaN that a segment along an axis gives
    (running along a box's side or through its corner is allowed). The roadmap's edges are tested so."""
    dx, dy = bx - ax, by - ay
    for k in range(boxes.shape[0]):
        t_lo, t_hi = (boxes[k, 0] - ax) / dx, (boxes[k, 2] - ax) / dx
        enter, leave = _nan_max(0.0, _nan_min(t_lo, t_hi)), _nan_min(1.0, _nan_max(t_lo, t_hi))
        t_lo, t_hi = (boxes[k, 1] - ay) / dy, (boxes[k, 3] - ay) / dy
        enter, leave = _nan_max(enter, _nan_min(t_lo, t_hi)), _nan_min(leave, _nan_max(t_lo, t_hi))
        if enter < leave:
            return False
    return True


@njit(**_JIT)
def misses_boxes(ax, ay, bx, by, boxes):  # pragma: no cover  (compiled)
    """``roadmap._misses``: whether the segment from (ax, ay) to (bx, by) enters none of the open ``boxes`` (B, 4)
    (boxes beside its bounding box skipped, the others by :func:`_meets_box`'s interior test); a route's ends and
    lines of sight are tested so."""
    sx0, sx1 = (ax, bx) if ax < bx else (bx, ax)
    sy0, sy1 = (ay, by) if ay < by else (by, ay)
    for k in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        if x0 < sx1 and sx0 < x1 and y0 < sy1 and sy0 < y1 and \
                _meets_box(ax, ay, bx - ax, by - ay, x0, y0, x1, y1, True):
            return False
    return True


@njit(**_JIT)
def point_clearance(x, y, boxes, w, h):  # pragma: no cover  (compiled)
    """The distance from (x, y) to the nearest rack (a box of ``boxes`` (B, 4), solid) or wall (the hall
    [-w, w] x [-h, h]); 0 inside a rack, negative outside the hall (boxes not nearer than the best so far skipped)."""
    best = min(x + w, w - x, y + h, h - y)
    for k in range(boxes.shape[0]):
        dx, dy = max(boxes[k, 0] - x, 0.0, x - boxes[k, 2]), max(boxes[k, 1] - y, 0.0, y - boxes[k, 3])
        if dx < best and dy < best:
            best = min(best, math.sqrt(dx * dx + dy * dy))
    return best


@njit(**_JIT)
def _point_segment_hypot(px, py, ax, ay, dx, dy):  # pragma: no cover  (compiled)
    """Distance from (px, py) to the segment from (ax, ay) along (dx, dy) (``math.hypot``: the C library's)."""
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 <= 1e-18 else min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / length2))
    return math.hypot(px - ax - t * dx, py - ay - t * dy)


@njit(**_JIT)
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


@njit(**_JIT)
def segment_clearance(ax, ay, bx, by, boxes, w, h, cap):  # pragma: no cover  (compiled)
    """Distance from the segment (ax, ay)-(bx, by) to the nearest rack (a box of ``boxes``) or wall of the hall
    [-w, w] x [-h, h]; racks farther than ``cap`` from the segment's bounding box are skipped, so a value >= ``cap``
    only means "at least ``cap``". The walls are nearest at an end (the hall is convex); a rack is 0 away when the
    segment meets it, else nearest at an end of the segment or at a corner of the rack (the nearest points of two
    disjoint convex sets). (``math.hypot`` is the C library's here; the float form it replaced used CPython's, which
    differs in the last bit of about one distance in a hundred: only a comparison with the radius leaves the kernel.)"""
    best = min(cap, ax + w, w - ax, ay + h, h - ay, bx + w, w - bx, by + h, h - by)
    dx, dy = bx - ax, by - ay
    sx0, sx1, sy0, sy1 = min(ax, bx), max(ax, bx), min(ay, by), max(ay, by)
    for k in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        if x0 - sx1 >= best or sx0 - x1 >= best or y0 - sy1 >= best or sy0 - y1 >= best:
            continue
        if _meets_box(ax, ay, dx, dy, x0, y0, x1, y1, False):
            return 0.0
        best = min(best, math.hypot(max(x0 - ax, 0.0, ax - x1), max(y0 - ay, 0.0, ay - y1)),
                   math.hypot(max(x0 - bx, 0.0, bx - x1), max(y0 - by, 0.0, by - y1)),
                   _point_segment_hypot(x0, y0, ax, ay, dx, dy), _point_segment_hypot(x0, y1, ax, ay, dx, dy),
                   _point_segment_hypot(x1, y0, ax, ay, dx, dy), _point_segment_hypot(x1, y1, ax, ay, dx, dy))
    return max(best, 0.0)


__all__ = ["misses_boxes", "point_clearance", "py_hypot", "segment_clearance", "segment_distance"]
