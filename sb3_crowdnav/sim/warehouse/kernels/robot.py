"""Kernels of the robot's side: a step's sensing and route bookkeeping, the roadmaps' edges and joins, stations."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from sb3_crowdnav.sim.geometry import JIT, TIE_QUANTUM, distance_order, point_to_segment, segment_to_segment
from sb3_crowdnav.sim.warehouse.kernels.base import misses_boxes, segment_clearance


class BoxRoadmap(NamedTuple):
    """:func:`box_roadmap`'s geometry of a box roadmap."""

    apart: bool  # the grown racks lie strictly inside the shrunk hall and pairwise apart
    grown: np.ndarray  # (B, 4) the racks grown by the clearance
    corners: np.ndarray  # (4 + 4B, 2) the hall's corners, then each grown rack's counter-clockwise from (xmin, ymin)
    sides: np.ndarray  # (4 + 4B,) 0 for the hall's corners, then 1, -1, 1, -1 per rack
    opened: np.ndarray  # (B, 4) the grown racks shrunk by 1e-6 (open: touching them is allowed)


class Sensing(NamedTuple):
    """:func:`sense`'s answer."""

    hit: bool  # the swept disc touched a segment
    observed: np.ndarray  # (max_count, 4) the observed segments, nearest first, zeros after them
    mask: np.ndarray  # (max_count,) bool


class SensingAndRoute(NamedTuple):
    """:func:`sense_and_follow`'s answer: the step's :class:`Sensing`, then the route's bookkeeping."""

    hit: bool
    observed: np.ndarray
    mask: np.ndarray
    index: int  # the new current waypoint
    off: bool  # the robot strayed more than the replanning distance from the leg to it
    blocked: bool  # the robot's disc does not fit along the segment to it


class RouteQuery(NamedTuple):
    """:func:`route_query`'s answer; without ``direct``, the joins of both ends and the A* heuristic."""

    direct: bool  # the start sees the goal (the arrays below are then empty)
    start_joins: np.ndarray  # (a,) int64 the corners the start sees
    goal_joins: np.ndarray  # (b,) int64 the corners the goal sees
    start_lengths: np.ndarray  # (a,) their distances
    goal_lengths: np.ndarray  # (b,)
    heuristic: np.ndarray  # (n + 2,) every node's distance to the goal (the corners, the start, the goal)


@njit(**JIT)
def box_roadmap(boxes, c, x0, y0, x1, y1):  # pragma: no cover  (compiled)
    """A box roadmap's geometry (:class:`BoxRoadmap`): the racks ``boxes`` (B, 4) grown by the clearance ``c``, checked
    against the shrunk hall (x0, y0, x1, y1) (:func:`separated`), their corners and sides, and their open copies."""
    b = boxes.shape[0]
    grown, opened = np.empty((b, 4)), np.empty((b, 4))
    for k in range(b):
        grown[k, 0], grown[k, 1] = boxes[k, 0] + -c, boxes[k, 1] + -c
        grown[k, 2], grown[k, 3] = boxes[k, 2] + c, boxes[k, 3] + c
        opened[k, 0], opened[k, 1] = grown[k, 0] + 1e-6, grown[k, 1] + 1e-6
        opened[k, 2], opened[k, 3] = grown[k, 2] + -1e-6, grown[k, 3] + -1e-6
    corners, sides = np.empty((4 + 4 * b, 2)), np.zeros(4 + 4 * b)
    corners[0, 0], corners[0, 1], corners[1, 0], corners[1, 1] = x0, y0, x0, y1
    corners[2, 0], corners[2, 1], corners[3, 0], corners[3, 1] = x1, y1, x1, y0
    for k in range(b):
        gx0, gy0, gx1, gy1, r = grown[k, 0], grown[k, 1], grown[k, 2], grown[k, 3], 4 + 4 * k
        corners[r, 0], corners[r, 1], corners[r + 1, 0], corners[r + 1, 1] = gx0, gy0, gx1, gy0
        corners[r + 2, 0], corners[r + 2, 1], corners[r + 3, 0], corners[r + 3, 1] = gx1, gy1, gx0, gy1
        sides[r], sides[r + 1], sides[r + 2], sides[r + 3] = 1.0, -1.0, 1.0, -1.0
    return BoxRoadmap(separated(grown, x0, y0, x1, y1), grown, corners, sides, opened)


@njit(**JIT)
def sense(segments, p0x, p0y, p1x, p1y, reach, radius, sensor_range, max_count, dist,
          order):  # pragma: no cover  (compiled)
    """The robot's sensing after it moved from p0 to p1, against the segments (S, 4) of a layout.

    :param reach: the radius + the step's length: only segments closer than it to p1 can be touched
    :param dist: (S,) filled with the distance from p1 to every segment
    :param order: (S,) filled with the order of ``dist`` (nearest first, ties by index: :func:`distance_order`)
    :return: :class:`Sensing`: whether the disc of ``radius`` swept from p0 to p1 touches a segment closer than
        ``reach`` (:func:`~sb3_crowdnav.sim.geometry.segment_to_segment` below ``radius``), and the observed segments:
        the first of that order within ``sensor_range``, at most ``max_count``, padded with zeros (max_count, 4), with
        their mask (max_count,) bool
    """
    n = segments.shape[0]
    for k in range(n):
        dist[k] = point_to_segment(p1x, p1y, segments[k, 0], segments[k, 1], segments[k, 2], segments[k, 3])
    distance_order(dist, order)
    observed, mask = np.zeros((max_count, 4)), np.zeros(max_count, np.bool_)
    seen = 0
    while seen < n and seen < max_count and dist[order[seen]] <= sensor_range:
        observed[seen] = segments[order[seen]]
        mask[seen] = True
        seen += 1
    hit = False
    for k in order:
        if dist[k] >= reach + TIE_QUANTUM:  # (a later one is at least dist[k] - TIE_QUANTUM away: distance_order)
            break
        if segment_to_segment(p0x, p0y, p1x, p1y, segments[k, 0], segments[k, 1], segments[k, 2],
                              segments[k, 3]) < radius:
            hit = True
            break
    return Sensing(hit, observed, mask)


@njit(**JIT)
def sense_and_follow(segments, p0x, p0y, p1x, p1y, reach, radius, sensor_range, max_count, dist, order, route, index,
                     waypoint_radius, replan_distance, boxes, w, h):  # pragma: no cover  (compiled)
    """A step's :func:`sense`, then the route's bookkeeping of ``WarehouseSimulator._advance_route`` at p1 (what the
    caller applies unless the step ended the episode): the waypoints passed (closer than ``waypoint_radius``, never
    the last) give the new current ``index``; ``off``: p1 strayed more than
    ``replan_distance`` from the leg to it; ``blocked`` (asked only when not off, and only of ``boxes`` (B, 4), None
    for a layout of other racks): the robot's disc does not fit along the segment to it (:func:`segment_clearance`
    below ``radius`` - 1 µm).

    :param route: (R, 2) the route's waypoints
    :return: :class:`SensingAndRoute`
    """
    hit, observed, mask = sense(segments, p0x, p0y, p1x, p1y, reach, radius, sensor_range, max_count, dist, order)
    last = route.shape[0] - 1
    while index < last and math.hypot(p1x - route[index, 0], p1y - route[index, 1]) < waypoint_radius:
        index += 1
    off = point_to_segment(p1x, p1y, route[index - 1, 0], route[index - 1, 1], route[index, 0],
                         route[index, 1]) > replan_distance
    blocked = False
    if not off and boxes is not None:
        blocked = not segment_clearance(p1x, p1y, route[index, 0], route[index, 1], boxes, w, h, radius) >= \
            radius - 1e-6
    return SensingAndRoute(hit, observed, mask, index, off, blocked)


@njit(**JIT)
def swept_segment_distance(segments, p0x, p0y, p1x, p1y, dist, order):  # pragma: no cover  (compiled)
    """The smallest distance [m] between the path p0-p1 of the robot's centre and the segments (S, 4), given
    :func:`sense`'s ``dist`` (S,) from p1 and its ``order``: a segment farther from p1 than the best so far + the
    step's length cannot be nearer the path, so the loop stops there (``inf`` without segments). Below the robot's
    radius exactly when :func:`sense` reports a hit."""
    step = math.hypot(p1x - p0x, p1y - p0y)
    best = np.inf
    for k in order:
        if dist[k] - step >= best + TIE_QUANTUM:  # (as in sense: the order is by distance to within TIE_QUANTUM)
            break
        best = min(best, segment_to_segment(p0x, p0y, p1x, p1y, segments[k, 0], segments[k, 1], segments[k, 2],
                                            segments[k, 3]))
    return best


@njit(**JIT)
def step_sensing(segments, p0x, p0y, p1x, p1y, reach, radius, sensor_range, max_count, dist, order, route, index,
                 waypoint_radius, replan_distance, boxes, w, h):  # pragma: no cover  (compiled)
    """A step's :func:`sense_and_follow` and :func:`swept_segment_distance` in one call, as a plain tuple (numba
    builds a named tuple's Python object slower): ``(hit, observed, mask, index, off, blocked, swept distance)``."""
    step = sense_and_follow(segments, p0x, p0y, p1x, p1y, reach, radius, sensor_range, max_count, dist, order, route,
                            index, waypoint_radius, replan_distance, boxes, w, h)
    swept = swept_segment_distance(segments, p0x, p0y, p1x, p1y, dist, order)
    return step.hit, step.observed, step.mask, step.index, step.off, step.blocked, swept


@njit(**JIT)
def bitangent_edges(corners, sides, first, boxes):  # pragma: no cover  (compiled)
    """The edges of a box roadmap's visibility graph: every pair of corners i < j from ``first`` on, in the order of
    ``np.triu_indices``, that passes both ends on the outside of their racks
    (``sides[i] * dx * dy <= 0`` and likewise for j) and enters none of the open ``boxes``.

    :return: i (E,), j (E,), and the lengths (E,)
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
            if sides[i] * turn <= 0 and sides[j] * turn <= 0 and misses_boxes(ax, ay, bx, by, boxes):
                out_i[count], out_j[count], out_len[count] = i, j, math.sqrt(dx * dx + dy * dy)
                count += 1
    return out_i[:count], out_j[:count], out_len[:count]


@njit(**JIT)
def joins(px, py, corners, sides, first, boxes):  # pragma: no cover  (compiled)
    """A route's end inside the hall joined to a box roadmap: the corners from ``first`` on that (px, py) sees and passes on
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


@njit(**JIT)
def _ends_joins(px, py, corners, sides, first, boxes, hall):  # pragma: no cover  (compiled)
    """:func:`joins` of a route's end inside the hall (to within 1 µm), none outside it."""
    if hall[0] - 1e-6 <= px <= hall[2] + 1e-6 and hall[1] - 1e-6 <= py <= hall[3] + 1e-6:
        return joins(px, py, corners, sides, first, boxes)
    return np.empty(0, np.int64), np.empty(0)


@njit(**JIT)
def route_query(sx, sy, gx, gy, corners, sides, first, boxes, hall):  # pragma: no cover  (compiled)
    """What a box roadmap asks before its A*, in one call (:class:`RouteQuery`): whether the start sees the goal (both
    within the hall ``(x0, y0, x1, y1)`` to within 1 µm and the segment entering no open box), else the corners each
    end sees (:func:`joins`) with their lengths, and the A* heuristic of every node (the corners, the start, the
    goal)."""
    inside = hall[0] - 1e-6 <= min(sx, gx) and max(sx, gx) <= hall[2] + 1e-6 and \
        hall[1] - 1e-6 <= min(sy, gy) and max(sy, gy) <= hall[3] + 1e-6
    if inside and misses_boxes(sx, sy, gx, gy, boxes):
        none, empty = np.empty(0, np.int64), np.empty(0)
        return RouteQuery(True, none, none, empty, empty, empty)
    start_joins, start_lengths = _ends_joins(sx, sy, corners, sides, first, boxes, hall)
    goal_joins, goal_lengths = _ends_joins(gx, gy, corners, sides, first, boxes, hall)
    n = corners.shape[0]
    heuristic = np.empty(n + 2)
    heuristic[:n] = distances_to(corners, gx, gy)
    heuristic[n] = math.sqrt((sx - gx) * (sx - gx) + (sy - gy) * (sy - gy))
    heuristic[n + 1] = 0.0
    return RouteQuery(False, start_joins, goal_joins, start_lengths, goal_lengths, heuristic)


@njit(**JIT)
def route_query_fields(sx, sy, gx, gy, corners, sides, first, boxes, hall):  # pragma: no cover  (compiled)
    """:func:`route_query`'s fields as a plain tuple (the caller makes the :class:`RouteQuery`: numba builds a named
    tuple's Python object slower)."""
    q = route_query(sx, sy, gx, gy, corners, sides, first, boxes, hall)
    return q.direct, q.start_joins, q.goal_joins, q.start_lengths, q.goal_lengths, q.heuristic


@njit(**JIT)
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


@njit(**JIT)
def separated(boxes, x0, y0, x1, y1):  # pragma: no cover  (compiled)
    """Whether ``boxes`` (B, 4) lie strictly inside the rectangle (x0, y0, x1, y1) and pairwise apart (a gap in x or
    y): the roadmap's fast geometry applies to grown racks that are."""
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


@njit(**JIT)
def distances_to(points, gx, gy):  # pragma: no cover  (compiled)
    """The distance from every row of ``points`` (n, 2) to (gx, gy)."""
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        dx, dy = points[p, 0] - gx, points[p, 1] - gy
        out[p] = math.sqrt(dx * dx + dy * dy)
    return out
