"""Compiled loops (``numba``) and helpers of the social force crowd
(:class:`~sb3_crowdnav.sim.crowd.SocialForceCrowdModel`): JuPedSim's compiled simulation, the walls' standoff, and
each step's targets and the open floor's inside test, loops over a few dozen values where the per-call overhead of
the dozen small NumPy calls they replace cost more than JuPedSim's own iterations. Same arithmetic, in the same order,
as those NumPy calls: the episodes are the same bit for bit."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from sb3_crowdnav.sim.geometry import JIT


@njit(**JIT)
def heading_points(positions, preferred, dt, ahead):  # pragma: no cover  (compiled)
    """For people at ``positions`` (n, 2) with ``preferred`` velocities (n, 2) [m/s]: their speeds (n,) [m/s], the
    points ``ahead`` [m] along each preferred velocity (n, 2; the person itself while it stands) and the points one
    step ``dt`` [s] of it away (n, 2)."""
    n = positions.shape[0]
    speeds, targets, near = np.empty(n), np.empty((n, 2)), np.empty((n, 2))
    for i in range(n):
        vx, vy = preferred[i, 0], preferred[i, 1]
        speed = np.hypot(vx, vy)
        speeds[i] = speed
        norm = max(speed, 1e-12)
        targets[i, 0] = positions[i, 0] + vx / norm * ahead
        targets[i, 1] = positions[i, 1] + vy / norm * ahead
        near[i, 0] = positions[i, 0] + vx * dt
        near[i, 1] = positions[i, 1] + vy * dt
    return speeds, targets, near


@njit(**JIT)
def first_inside(targets, near, positions, inside):  # pragma: no cover  (compiled)
    """Row i of ``targets`` (n, 2) where ``inside[i]``, else of ``near`` where ``inside[n + i]``, else of ``positions``
    (``inside`` (2n,) bool: the targets' then the near points' inside test), into ``targets``."""
    n = targets.shape[0]
    for i in range(n):
        if not inside[i]:
            source = near if inside[n + i] else positions
            targets[i, 0], targets[i, 1] = source[i, 0], source[i, 1]
    return targets


@njit(**JIT)
def in_square(points, half):  # pragma: no cover  (compiled)
    """(n,) bool: ``points`` (n, 2) strictly inside the square [-half, half]² [m]."""
    out = np.empty(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        out[i] = abs(points[i, 0]) < half and abs(points[i, 1]) < half
    return out


def native_simulation(simulation: Any) -> Any:
    """The compiled simulation inside a ``jupedsim.Simulation`` (JuPedSim 1.4.2's ``_obj``). The model calls it, its
    agents and their model states directly: JuPedSim's Python layer wraps every call (a new wrapper object per
    agent or model state asked for, per-call checks), which cost more than the calls themselves at dozens a step."""
    return simulation._obj


def wall_standoff(strength: float, force_range: float, relaxation_time: float, mass: float, clearance: float,
                  speed: float, slowing: bool) -> float:
    """:meth:`~sb3_crowdnav.sim.crowd.SocialForceCrowdModel.stops_short`: the d [m] where a wall's push
    ``strength · exp(-(clearance + d) / force_range)`` [N] balances the driving force ``mass · v / relaxation_time``,
    v ``speed`` or, ``slowing``, min(d, ``speed``) [m/s]; 0 without a push (bisection: the push falls, the drive
    does not)."""

    def push_wins(d: float) -> bool:
        v = min(d, speed) if slowing else speed
        return strength * math.exp(-(clearance + d) / force_range) > mass * v / relaxation_time

    if not push_wins(0.0):
        return 0.0
    low, high = 0.0, 1.0
    while push_wins(high):  # (the push decays exponentially: a bracket is soon found)
        low, high = high, 2 * high
    for _ in range(60):
        mid = (low + high) / 2
        low, high = (mid, high) if push_wins(mid) else (low, mid)
    return high
