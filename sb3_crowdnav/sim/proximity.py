"""The safety figures' thresholds and the time-to-collision of the robot with the people (compiled, ``numba``).

The episode statistics (:class:`~sb3_crowdnav.envs.statistics.EpisodeStatistics`) call
:func:`min_time_to_collision` once per step on the simulator's true people (``sim.history[-1]`` and ``sim.mask``, not
what the robot observes). A loop over at most ``max_humans`` rows, compiled like :mod:`~sb3_crowdnav.sim.geometry`'s
distances: one call costs less than the NumPy calls it would take. The readable form it is checked against lives in
the tests (``tests/test_safety_figures.py``).
"""

from __future__ import annotations

import math

from numba import njit

from sb3_crowdnav.sim.geometry import JIT
from sb3_crowdnav.sim.observation import Human

TTC_HORIZON = 10.0  # [s] the time-to-collision is capped here: "no collision within 10 s at constant velocity"
SHORT_TTC = 1.0  # [s] the tables give the share of episodes whose minimum time-to-collision is below this
NEAR_MISS_DISTANCE = 0.2  # [m] a step closer than this to a person's surface, without touching, is a near miss
NEAR_PERSON_DISTANCE = 1.0  # [m] the robot's speed is averaged over the steps with a person's surface closer than this

_PX, _PY = Human.POS.start, Human.POS.start + 1
_VX, _VY = Human.VEL.start, Human.VEL.start + 1
_R = Human.RADIUS


@njit(**JIT)
def min_time_to_collision(px, py, vx, vy, radius, humans, mask, horizon):  # pragma: no cover  (compiled)
    """The smallest time [s] until the robot's disc touches a present person's, both moving at constant velocity.

    For each person with ``mask`` set: the smallest t >= 0 with |Δp + Δv·t| = radius + r (Δp, Δv the person's position
    and velocity relative to the robot's), 0 when the discs overlap now, none when they never meet; the minimum over
    the people, capped at ``horizon`` (also the answer when no one is present or no one will meet the robot).

    :param px, py, vx, vy, radius: the robot's position [m], velocity [m/s] and radius [m]
    :param humans: (max_humans, 5) rows [px, py, vx, vy, radius] (the newest history row)
    :param mask: (max_humans,) bool, present people
    """
    best = horizon
    for k in range(humans.shape[0]):
        if not mask[k]:
            continue
        dx, dy = humans[k, _PX] - px, humans[k, _PY] - py
        dvx, dvy = humans[k, _VX] - vx, humans[k, _VY] - vy
        reach = radius + humans[k, _R]
        c = dx * dx + dy * dy - reach * reach
        if c <= 0.0:
            return 0.0
        b = dx * dvx + dy * dvy  # half the linear coefficient of |Δp + Δv·t|² - reach²
        a = dvx * dvx + dvy * dvy
        disc = b * b - a * c
        if b >= 0.0 or disc < 0.0:  # moving apart (or keeping the distance), or passing without touching
            continue
        t = c / (-b + math.sqrt(disc))  # the smaller root (-b - sqrt(disc)) / a, without cancellation
        best = min(best, t)
    return best


__all__ = ["NEAR_MISS_DISTANCE", "NEAR_PERSON_DISTANCE", "SHORT_TTC", "TTC_HORIZON", "min_time_to_collision"]
