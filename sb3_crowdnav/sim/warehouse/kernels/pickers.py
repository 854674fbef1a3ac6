"""Kernels of the pickers' side: pick slots, start slots, preferred velocities, dwell countdown, overlap guard."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from sb3_crowdnav.sim.geometry import JIT
from sb3_crowdnav.sim.warehouse.kernels.base import point_clearance


class AfterStep(NamedTuple):
    """:func:`picker_after_step`'s answer."""

    pressed: np.ndarray  # (p,) int64 the pickers pressed into a rack or a wall
    which: np.ndarray  # (k,) int64 the pickers with something to do next (none when p > 0), in order
    what: np.ndarray  # (k,) int64 1: its dwell is over (a new job); 2: it reached its route's end (a dwell is drawn)


@njit(**JIT)
def slot_points(segments, spacing, offset):  # pragma: no cover  (compiled)
    """``pick_slots``' candidate points (n, 2): along every edge (S, 4) ``length // spacing`` points at
    ``(k + 0.5) * length / count`` from its start, ``offset`` out along its normal (dy, -dx) / length."""
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


@njit(**JIT)
def points_clearance(points, boxes, w, h):  # pragma: no cover  (compiled)
    """The distance from each of ``points`` (n, 2) to the nearest rack (a box of ``boxes`` (B, 4), solid) or wall (the
    hall [-w, w] x [-h, h]), (n,); 0 inside a rack, negative outside the hall."""
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        out[p] = point_clearance(points[p, 0], points[p, 1], boxes, w, h)
    return out


@njit(**JIT)
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


@njit(**JIT)
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


@njit(**JIT)
def spread(points, permutation, n, spacing):  # pragma: no cover  (compiled)
    """``WarehouseSimulator._spread``: the first ``n`` of ``points`` (u, 2) in the order of ``permutation`` that are
    pairwise at least ``spacing`` apart greedily; fewer when they do not fit."""
    chosen = np.empty(n, np.int64)
    count = 0
    for i in permutation:
        if count == n:
            break
        fits = True
        for c in range(count):
            k = chosen[c]
            if not math.hypot(points[i, 0] - points[k, 0], points[i, 1] - points[k, 1]) >= spacing:
                fits = False
                break
        if fits:
            chosen[count] = i
            count += 1
    return chosen[:count]


@njit(**JIT)
def picker_preferences(positions, dwell, waypoint, routes, lengths, v_pref, arrival, out):  # pragma: no cover
    """``PickerCrowd.preferred_velocities`` into ``out`` (n, 2): towards each walking picker's current waypoint at
    its ``v_pref`` (n,) [m/s] (slowing into the last one), zero for a standing one (``dwell`` > 0); a walking picker
    first passes the waypoints within its ``arrival`` (n,) [m] (never the last), ``waypoint`` (n,) updated in place.

    :param routes: (n, K, 2) each picker's waypoints, the first ``lengths[i]`` of row i
    """
    for i in range(positions.shape[0]):
        out[i, 0] = out[i, 1] = 0.0
        if dwell[i] > 0:
            continue
        x, y, w, last = positions[i, 0], positions[i, 1], waypoint[i], lengths[i] - 1
        while w < last and math.hypot(x - routes[i, w, 0], y - routes[i, w, 1]) < arrival[i]:
            w += 1
        waypoint[i] = w
        dx, dy = routes[i, w, 0] - x, routes[i, w, 1] - y
        norm = math.hypot(dx, dy)
        v = v_pref[i]
        if norm > v or (w < last and norm > 1e-9):
            dx, dy = dx / norm * v, dy / norm * v
        out[i, 0], out[i, 1] = dx, dy


@njit(**JIT)
def picker_progress(state, dwell, waypoint, routes, lengths, dt, arrival):  # pragma: no cover  (compiled)
    """After a step: a standing picker's dwell counts down by ``dt`` (to 0 at least; ``dwell`` updated in place); the
    pickers with something to do next, in order, (k,), and what: 1 its dwell is over (a new job), 2 it walked within
    its ``arrival`` (n,) [m] of the last waypoint of its route (it stands: a dwell is drawn), (k,)."""
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
            if waypoint[i] == last and math.hypot(state[i, 0] - routes[i, last, 0], state[i, 1] - routes[i, last, 1]) < \
                    arrival[i]:
                event = 2
        if event:
            which[count], what[count] = i, event
            count += 1
    return which[:count], what[:count]


@njit(**JIT)
def picker_after_step(state, room, grown, boxes, w, h, radius, dwell, waypoint, routes, lengths, dt,
                      arrival):  # pragma: no cover  (compiled)
    """:func:`pressed`, then, when no picker is pressed into a rack, :func:`picker_progress`, in one call
    (:class:`AfterStep`; no events when a picker is pressed: the caller moves the pressed ones out first, then asks
    :func:`picker_progress`)."""
    out = pressed(state, room, grown, boxes, w, h, radius)
    if out.shape[0]:
        none = np.empty(0, np.int64)
        return AfterStep(out, none, none)
    which, what = picker_progress(state, dwell, waypoint, routes, lengths, dt, arrival)
    return AfterStep(out, which, what)


@njit(**JIT)
def picker_after_step_fields(state, room, grown, boxes, w, h, radius, dwell, waypoint, routes, lengths, dt,
                             arrival):  # pragma: no cover  (compiled)
    """:func:`picker_after_step`'s fields ``(pressed, which, what)`` as a plain tuple (numba builds a named tuple's
    Python object slower): the per-step call."""
    after = picker_after_step(state, room, grown, boxes, w, h, radius, dwell, waypoint, routes, lengths, dt, arrival)
    return after.pressed, after.which, after.what
