"""Compiled loops (``numba``) of the warehouse's geometry: the robot's sensing and swept collision every step, and the
visibility tests that build a roadmap and join a route's ends to it every reset.

Each kernel is the loop form of a NumPy or Python-float function of the package and gives its values exactly (the same
IEEE operations in the same order: no fast-math, divisions by zero giving inf/NaN as NumPy's do; ``math.hypot`` and
``math.sqrt`` are the C library's, as NumPy's). A kernel stands in for several small NumPy calls on arrays of a few
dozen values, whose per-call overhead costs more than the arithmetic. The tests compare each kernel with the function
it replaces (``tests/test_warehouse_kernels.py``).

Where the replaced code calls CPython's ``math.hypot`` or ``math.dist`` (correctly rounded in most cases, unlike the
C library's ``hypot``), the kernel calls :func:`py_hypot`, CPython 3.11's algorithm for two values, so that the kernel
gives the same values on the Python the package is tested with.

Kernels compile on their first call and are cached on disk beside this file (``cache=True``): a new process loads them
in milliseconds.
"""

from __future__ import annotations

import math

import numpy as np
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
def sense(geometry, p0x, p0y, p1x, p1y, reach, radius, sensor_range, max_count, dist,
          order):  # pragma: no cover  (compiled)
    """The robot's sensing after it moved from p0 to p1, against the segments of a layout.

    :param geometry: (S, 9) every segment's start (x, y), direction (dx, dy), squared length (at least 1e-18), and
        the segment ``[x0, y0, x1, y1]``
    :param reach: the radius + the step's length: only segments closer than it to p1 can be touched
    :param dist: (S,) filled with the distance from p1 to every segment (``np.hypot`` of the clamped projection, as
        ``WarehouseSimulator``'s NumPy form)
    :param order: (S,) filled with the stable order of ``dist``
    :return: whether the disc of ``radius`` swept from p0 to p1 touches a segment closer than ``reach``
        (:func:`segment_distance` below ``radius``), and the observed segments: the first of that order within
        ``sensor_range``, at most ``max_count``, padded with zeros (max_count, 4), with their mask (max_count,) bool
    """
    ax, ay, abx, aby, len2, segments = geometry[:, 0], geometry[:, 1], geometry[:, 2], geometry[:, 3], \
        geometry[:, 4], geometry[:, 5:]
    n = ax.shape[0]
    for k in range(n):
        dx, dy = p1x - ax[k], p1y - ay[k]
        t = min(max((dx * abx[k] + dy * aby[k]) / len2[k], 0.0), 1.0)
        dist[k] = math.hypot(dx - t * abx[k], dy - t * aby[k])
    order[:] = np.argsort(dist, kind="mergesort")  # stable
    observed, mask = np.zeros((max_count, 4)), np.zeros(max_count, np.bool_)
    seen = 0
    while seen < n and seen < max_count and dist[order[seen]] <= sensor_range:
        observed[seen] = segments[order[seen]]
        mask[seen] = True
        seen += 1
    hit = False
    for k in order:
        if dist[k] >= reach:
            break
        if segment_distance(p0x, p0y, p1x, p1y, segments[k, 0], segments[k, 1], segments[k, 2],
                            segments[k, 3]) < radius:
            hit = True
            break
    return hit, observed, mask


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
    """:func:`~sb3_crowdnav.sim.warehouse.boxes.segments_miss_boxes` of one segment: Liang-Barsky clipping against
    the open ``boxes`` (B, 4), divisions by zero and NaNs as NumPy's."""
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
def bitangent_edges(corners, sides, first, boxes):  # pragma: no cover  (compiled)
    """The edges of a box roadmap's visibility graph (``Roadmap._edges``' NumPy form): every pair of corners i < j
    from ``first`` on, in the order of ``np.triu_indices``, that passes both ends on the outside of their racks
    (``sides[i] * dx * dy <= 0`` and likewise for j) and enters none of the open ``boxes``.

    :return: i (E,), j (E,), and the lengths (E,) (``np.linalg.norm``'s value, sqrt(dx * dx + dy * dy))
    """
    n = corners.shape[0]
    size = max((n - first) * (n - first - 1) // 2, 0)
    out_i, out_j, out_len = np.empty(size, np.int64), np.empty(size, np.int64), np.empty(size)
    count = 0
    for i in range(first, n):
        ax, ay = corners[i, 0], corners[i, 1]
        for j in range(i + 1, n):
            bx, by = corners[j, 0], corners[j, 1]
            dx, dy = bx - ax, by - ay
            turn = dx * dy
            if sides[i] * turn <= 0 and sides[j] * turn <= 0 and _misses_all(ax, ay, bx, by, boxes):
                out_i[count], out_j[count], out_len[count] = i, j, math.sqrt(dx * dx + dy * dy)
                count += 1
    return out_i[:count], out_j[:count], out_len[:count]


@njit(**_JIT)
def _meets_box_interior(ax, ay, dx, dy, x0, y0, x1, y1):  # pragma: no cover  (compiled)
    """:func:`~sb3_crowdnav.sim.warehouse.boxes.segment_meets_box` with ``interior=True``."""
    if dx == 0:
        if not (x0 < ax < x1):
            return False
        enter, leave = 0.0, 1.0
    else:
        t0, t1 = (x0 - ax) / dx, (x1 - ax) / dx
        if t1 < t0:
            t0, t1 = t1, t0
        enter, leave = (t0 if t0 > 0.0 else 0.0), (t1 if t1 < 1.0 else 1.0)
    if dy == 0:
        if not (y0 < ay < y1):
            return False
    else:
        t0, t1 = (y0 - ay) / dy, (y1 - ay) / dy
        if t1 < t0:
            t0, t1 = t1, t0
        enter, leave = (t0 if t0 > enter else enter), (t1 if t1 < leave else leave)
    return enter < leave


@njit(**_JIT)
def misses_boxes(ax, ay, bx, by, boxes):  # pragma: no cover  (compiled)
    """``roadmap._misses``: whether the segment from (ax, ay) to (bx, by) enters none of the open ``boxes`` (B, 4)
    (boxes beside its bounding box skipped, the others by :func:`segment_meets_box`'s test)."""
    sx0, sx1 = (ax, bx) if ax < bx else (bx, ax)
    sy0, sy1 = (ay, by) if ay < by else (by, ay)
    for k in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        if x0 < sx1 and sx0 < x1 and y0 < sy1 and sy0 < y1 and \
                _meets_box_interior(ax, ay, bx - ax, by - ay, x0, y0, x1, y1):
            return False
    return True


@njit(**_JIT)
def joins(px, py, corners, sides, first, boxes):  # pragma: no cover  (compiled)
    """``Roadmap._joins`` of a point inside the hall: the corners from ``first`` on that (px, py) sees and passes on
    the outside (``side * dx * dy <= 0`` with (dx, dy) = point - corner, :func:`misses_boxes`), and the lengths."""
    n = corners.shape[0]
    out_k, out_len = np.empty(max(n - first, 0), np.int64), np.empty(max(n - first, 0))
    count = 0
    for k in range(first, n):
        cx, cy = corners[k, 0], corners[k, 1]
        dx, dy = px - cx, py - cy
        if sides[k] * dx * dy <= 0 and misses_boxes(px, py, cx, cy, boxes):
            out_k[count], out_len[count] = k, math.sqrt(dx * dx + dy * dy)
            count += 1
    return out_k[:count], out_len[:count]


@njit(**_JIT)
def slot_points(segments, spacing, offset):  # pragma: no cover  (compiled)
    """``pick_slots``' candidate points (n, 2): along every edge (S, 4) ``length // spacing`` points at
    ``(k + 0.5) * length / count`` from its start, ``offset`` out along its normal (dy, -dx) / length (the NumPy
    form's operations, element by element)."""
    n_edges = segments.shape[0]
    length, count = np.empty(n_edges), np.empty(n_edges, np.int64)
    total = 0
    for e in range(n_edges):
        length[e] = math.hypot(segments[e, 2] - segments[e, 0], segments[e, 3] - segments[e, 1])
        count[e] = np.int64(length[e] // spacing) if length[e] >= spacing else 0
        total += count[e]
    out = np.empty((total, 2))
    row = 0
    for e in range(n_edges):
        ax, ay = segments[e, 0], segments[e, 1]
        ex, ey = segments[e, 2] - ax, segments[e, 3] - ay
        for k in range(count[e]):
            t = (k + 0.5) * length[e] / count[e]
            out[row, 0] = ax + ex * (t / length[e]) + ey / length[e] * offset
            out[row, 1] = ay + ey * (t / length[e]) + -ex / length[e] * offset
            row += 1
    return out


@njit(**_JIT)
def points_clearance(points, boxes, w, h):  # pragma: no cover  (compiled)
    """:func:`~sb3_crowdnav.sim.warehouse.boxes.points_clearance` (its values) of ``points`` (n, 2) in the hall
    ``[-w, w] x [-h, h]``."""
    n = points.shape[0]
    out = np.empty(n)
    for p in range(n):
        x, y = points[p, 0], points[p, 1]
        best = min(min(x + w, w - x), min(y + h, h - y))
        for k in range(boxes.shape[0]):
            dx = max(max(boxes[k, 0] - x, x - boxes[k, 2]), 0.0)
            dy = max(max(boxes[k, 1] - y, y - boxes[k, 3]), 0.0)
            best = min(best, math.sqrt(dx * dx + dy * dy))
        out[p] = best
    return out


@njit(**_JIT)
def point_clearance(x, y, boxes, w, h):  # pragma: no cover  (compiled)
    """:func:`~sb3_crowdnav.sim.warehouse.boxes.point_clearance` (its value)."""
    best = min(x + w, w - x, y + h, h - y)
    for k in range(boxes.shape[0]):
        dx, dy = max(boxes[k, 0] - x, 0.0, x - boxes[k, 2]), max(boxes[k, 1] - y, 0.0, y - boxes[k, 3])
        if dx < best and dy < best:
            best = min(best, math.sqrt(dx * dx + dy * dy))
    return best


@njit(**_JIT)
def pressed(state, room, grown, boxes, w, h, radius):  # pragma: no cover  (compiled)
    """``PickerCrowd._pressed_indices`` with boxes for racks: the rows of ``state`` (n, >= 2: x, y first) whose centre
    is closer than ``radius`` to a rack or a wall (:func:`point_clearance`), asked only of those outside ``room``
    (x0, y0, x1, y1; open) or inside one of the ``grown`` boxes (open)."""
    out = np.empty(state.shape[0], np.int64)
    count = 0
    for i in range(state.shape[0]):
        x, y = state[i, 0], state[i, 1]
        if room[0] < x < room[2] and room[1] < y < room[3]:
            near = False
            for k in range(grown.shape[0]):
                if grown[k, 0] < x < grown[k, 2] and grown[k, 1] < y < grown[k, 3]:
                    near = True
                    break
            if not near:
                continue  # farther than the radius from every rack and wall
        if point_clearance(x, y, boxes, w, h) < radius:
            out[count] = i
            count += 1
    return out[:count]


@njit(**_JIT)
def _point_segment_hypot(px, py, ax, ay, dx, dy):  # pragma: no cover  (compiled)
    """``boxes._point_segment``: distance from (px, py) to the segment from (ax, ay) along (dx, dy)."""
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 <= 1e-18 else min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / length2))
    return math.hypot(px - ax - t * dx, py - ay - t * dy)


@njit(**_JIT)
def _meets_box(ax, ay, dx, dy, x0, y0, x1, y1):  # pragma: no cover  (compiled)
    """:func:`~sb3_crowdnav.sim.warehouse.boxes.segment_meets_box` (the closed box)."""
    if dx == 0:
        if not (x0 <= ax <= x1):
            return False
        enter, leave = 0.0, 1.0
    else:
        t0, t1 = (x0 - ax) / dx, (x1 - ax) / dx
        if t1 < t0:
            t0, t1 = t1, t0
        enter, leave = (t0 if t0 > 0.0 else 0.0), (t1 if t1 < 1.0 else 1.0)
    if dy == 0:
        if not (y0 <= ay <= y1):
            return False
    else:
        t0, t1 = (y0 - ay) / dy, (y1 - ay) / dy
        if t1 < t0:
            t0, t1 = t1, t0
        enter, leave = (t0 if t0 > enter else enter), (t1 if t1 < leave else leave)
    return enter <= leave


@njit(**_JIT)
def segment_clearance(ax, ay, bx, by, boxes, w, h, cap):  # pragma: no cover  (compiled)
    """:func:`~sb3_crowdnav.sim.warehouse.boxes.segment_clearance` (its operations; ``math.hypot`` is the C library's
    here and CPython's own there, which differ in the last bit of about one distance in a hundred)."""
    best = min(cap, ax + w, w - ax, ay + h, h - ay, bx + w, w - bx, by + h, h - by)
    dx, dy = bx - ax, by - ay
    sx0, sx1, sy0, sy1 = min(ax, bx), max(ax, bx), min(ay, by), max(ay, by)
    for k in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        if x0 - sx1 >= best or sx0 - x1 >= best or y0 - sy1 >= best or sy0 - y1 >= best:
            continue
        if _meets_box(ax, ay, dx, dy, x0, y0, x1, y1):
            return 0.0
        best = min(best, math.hypot(max(x0 - ax, 0.0, ax - x1), max(y0 - ay, 0.0, ay - y1)),
                   math.hypot(max(x0 - bx, 0.0, bx - x1), max(y0 - by, 0.0, by - y1)),
                   _point_segment_hypot(x0, y0, ax, ay, dx, dy), _point_segment_hypot(x0, y1, ax, ay, dx, dy),
                   _point_segment_hypot(x1, y0, ax, ay, dx, dy), _point_segment_hypot(x1, y1, ax, ay, dx, dy))
    return max(best, 0.0)


@njit(**_JIT)
def free_points(points, hall, grown):  # pragma: no cover  (compiled)
    """``Roadmap.is_free`` of each of ``points`` (n, 2): strictly inside ``hall`` (x0, y0, x1, y1) and in none of the
    closed ``grown`` boxes (B, 4)."""
    out = np.empty(points.shape[0], np.bool_)
    for p in range(points.shape[0]):
        x, y = points[p, 0], points[p, 1]
        free = hall[0] < x < hall[2] and hall[1] < y < hall[3]
        for k in range(grown.shape[0]):
            if not free:
                break
            if grown[k, 0] <= x <= grown[k, 2] and grown[k, 1] <= y <= grown[k, 3]:
                free = False
        out[p] = free
    return out


@njit(**_JIT)
def separated(boxes, x0, y0, x1, y1):  # pragma: no cover  (compiled)
    """:func:`~sb3_crowdnav.sim.warehouse.boxes.separated`: ``boxes`` (B, 4) strictly inside the rectangle and
    pairwise apart (a gap in x or y)."""
    n = boxes.shape[0]
    for k in range(n):
        if not (x0 < boxes[k, 0] and y0 < boxes[k, 1] and boxes[k, 2] < x1 and boxes[k, 3] < y1):
            return False
    for k in range(n):
        for m in range(k + 1, n):
            if not (boxes[k, 2] < boxes[m, 0] or boxes[m, 2] < boxes[k, 0] or boxes[k, 3] < boxes[m, 1] or
                    boxes[m, 3] < boxes[k, 1]):
                return False
    return True


@njit(**_JIT)
def far_from_both(points, ax, ay, bx, by, gap):  # pragma: no cover  (compiled)
    """The indices of ``points`` (n, 2) at least ``gap`` from (ax, ay) and from (bx, by) (``np.hypot``)."""
    out = np.empty(points.shape[0], np.int64)
    count = 0
    for p in range(points.shape[0]):
        if math.hypot(points[p, 0] - ax, points[p, 1] - ay) >= gap and \
                math.hypot(points[p, 0] - bx, points[p, 1] - by) >= gap:
            out[count] = p
            count += 1
    return out[:count]


@njit(**_JIT)
def distances_to(points, gx, gy):  # pragma: no cover  (compiled)
    """sqrt((x - gx)^2 + (y - gy)^2) of every row of ``points`` (n, 2) (``np.linalg.norm``'s operations)."""
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        dx, dy = points[p, 0] - gx, points[p, 1] - gy
        out[p] = math.sqrt(dx * dx + dy * dy)
    return out


@njit(**_JIT)
def picker_preferences(positions, dwell, waypoint, routes, lengths, v_pref, arrival, out):  # pragma: no cover
    """``PickerCrowd.preferred_velocities`` into ``out`` (n, 2): towards each walking picker's current waypoint at
    ``v_pref`` (slowing into the last one), zero for a standing one (``dwell`` > 0); a walking picker first passes the
    waypoints within ``arrival`` (never the last), ``waypoint`` (n,) updated in place.

    :param routes: (n, K, 2) each picker's waypoints, the first ``lengths[i]`` of row i
    """
    for i in range(positions.shape[0]):
        out[i, 0] = out[i, 1] = 0.0
        if dwell[i] > 0:
            continue
        x, y, w, last = positions[i, 0], positions[i, 1], waypoint[i], lengths[i] - 1
        while w < last and py_hypot(x - routes[i, w, 0], y - routes[i, w, 1]) < arrival:
            w += 1
        waypoint[i] = w
        dx, dy = routes[i, w, 0] - x, routes[i, w, 1] - y
        norm = py_hypot(dx, dy)
        if norm > v_pref or (w < last and norm > 1e-9):
            dx, dy = dx / norm * v_pref, dy / norm * v_pref
        out[i, 0], out[i, 1] = dx, dy


@njit(**_JIT)
def picker_progress(state, dwell, waypoint, routes, lengths, dt, arrival):  # pragma: no cover  (compiled)
    """After a step: a standing picker's dwell counts down by ``dt`` (to 0 at least; ``dwell`` updated in place); the
    pickers with something to do next, in order, (k,), and what: 1 its dwell is over (a new job), 2 it walked within
    ``arrival`` of the last waypoint of its route (it stands: a dwell is drawn), (k,)."""
    n = state.shape[0]
    which, what = np.empty(n, np.int64), np.empty(n, np.int64)
    count = 0
    for i in range(n):
        event = 0
        if dwell[i] > 0:
            dwell[i] = max(0.0, dwell[i] - dt)
            if dwell[i] == 0:
                event = 1
        else:
            last = lengths[i] - 1
            if waypoint[i] == last and py_hypot(state[i, 0] - routes[i, last, 0], state[i, 1] - routes[i, last, 1]) < \
                    arrival:
                event = 2
        if event:
            which[count], what[count] = i, event
            count += 1
    return which[:count], what[:count]


@njit(**_JIT)
def picker_after_step(state, geometry, w, h, radius, dwell, waypoint, routes, lengths, dt,
                      arrival):  # pragma: no cover  (compiled)
    """:func:`pressed`, then, when no picker is pressed into a rack (always so far), :func:`picker_progress`, in one
    call and one array: ``[p, the p pressed pickers..., then (picker, event) pairs...]`` (no pairs when p > 0: the
    caller moves the pressed ones out first, then asks :func:`picker_progress`).

    :param geometry: (2B + 1, 4) the ``room`` of :func:`pressed`, then its ``grown`` boxes, then the ``boxes``
    """
    b = (geometry.shape[0] - 1) // 2
    out = pressed(state, geometry[0], geometry[1 : b + 1], geometry[b + 1 :], w, h, radius)
    if out.shape[0]:
        return np.concatenate((np.array([out.shape[0]]), out))
    which, what = picker_progress(state, dwell, waypoint, routes, lengths, dt, arrival)
    packed = np.empty(1 + 2 * which.shape[0], np.int64)
    packed[0] = 0
    packed[1::2], packed[2::2] = which, what
    return packed


@njit(**_JIT)
def spread(points, permutation, n, spacing):  # pragma: no cover  (compiled)
    """``WarehouseSimulator._spread``: the first ``n`` of ``points`` (u, 2) in the order of ``permutation`` that are
    pairwise at least ``spacing`` apart (``math.hypot``, :func:`py_hypot`), greedily; fewer when they do not fit."""
    chosen = np.empty(n, np.int64)
    count = 0
    for i in permutation:
        if count == n:
            break
        fits = True
        for c in range(count):
            k = chosen[c]
            if not py_hypot(points[i, 0] - points[k, 0], points[i, 1] - points[k, 1]) >= spacing:
                fits = False
                break
        if fits:
            chosen[count] = i
            count += 1
    return chosen[:count]


@njit(**_JIT)
def sense_and_follow(geometry, p0x, p0y, p1x, p1y, reach, radius, sensor_range, max_count, dist, order, route, index,
                     waypoint_radius, replan_distance, boxes, w, h):  # pragma: no cover  (compiled)
    """A step's :func:`sense`, then the route's bookkeeping of ``WarehouseSimulator._advance_route`` at p1 (what the
    caller applies unless the step ended the episode): the waypoints passed (``math.dist`` below
    ``waypoint_radius``, never the last) give the new current ``index``; ``off``: p1 strayed more than
    ``replan_distance`` from the leg to it; ``blocked`` (asked only when not off, and only of ``boxes`` (B, 4), None
    for a layout of other racks): the robot's disc does not fit along the segment to it (:func:`segment_clearance`
    below ``radius`` - 1 µm).

    :param route: (R, 2) the route's waypoints
    :return: hit, observed segments, their mask (:func:`sense`), the new index, off, blocked
    """
    hit, observed, mask = sense(geometry, p0x, p0y, p1x, p1y, reach, radius, sensor_range, max_count, dist, order)
    last = route.shape[0] - 1
    while index < last and py_hypot(p1x - route[index, 0], p1y - route[index, 1]) < waypoint_radius:
        index += 1
    off = _point_segment(p1x, p1y, route[index - 1, 0], route[index - 1, 1], route[index, 0],
                         route[index, 1]) > replan_distance
    blocked = False
    if not off and boxes is not None:
        blocked = not segment_clearance(p1x, p1y, route[index, 0], route[index, 1], boxes, w, h, radius) >= \
            radius - 1e-6
    return hit, observed, mask, index, off, blocked


__all__ = [
    "bitangent_edges",
    "distances_to",
    "far_from_both",
    "free_points",
    "joins",
    "misses_boxes",
    "picker_after_step",
    "picker_preferences",
    "picker_progress",
    "point_clearance",
    "points_clearance",
    "pressed",
    "py_hypot",
    "segment_clearance",
    "segment_distance",
    "sense",
    "sense_and_follow",
    "separated",
    "slot_points",
    "spread",
]
