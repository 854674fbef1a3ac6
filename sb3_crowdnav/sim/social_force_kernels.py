"""Compiled loops (``numba``) of the social force crowd (:class:`~sb3_crowdnav.sim.crowd.SocialForceCrowdModel`): each
step's targets and the open floor's inside test, a loop over a few dozen values where the per-call overhead of the
dozen small NumPy calls they replace cost more than JuPedSim's own iterations. Same arithmetic, in the same order, as
those NumPy calls: the episodes are the same bit for bit."""

from __future__ import annotations

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
