"""The one 80-action table (5 speeds x 16 directions) and the robot kinematics.

Action ``a`` has speed index ``a // n_directions`` and direction index ``a % n_directions``.
Speeds are ``v_pref * (1..5) / 5``. With ``rotation_range = 2π`` the directions are
``k * 2π / 16`` wrapped to (-π, π] (direction index 0 is "straight on"); with a narrower
range they are ``linspace(-range/2, range/2, 16)`` (end points included).

* ``"unicycle"``: the direction is a rotation of the current heading, θ' = wrap(θ + Δθ),
  then the robot moves ``v * Δt`` along θ'.
* ``"holonomic"``: the direction is an absolute angle in the frame whose x-axis points from
  the robot to its goal; the heading becomes the direction of motion.

:func:`move` (compiled) is the kinematics: the env calls it on its one robot, and :func:`apply_action`
(broadcast over leading dimensions: the lookahead's batch x 80 actions) loops over it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from sb3_crowdnav.sim.geometry import JIT, as_rows

N_SPEEDS = 5
N_DIRECTIONS = 16
N_ACTIONS = N_SPEEDS * N_DIRECTIONS
KINEMATICS = ("unicycle", "holonomic")
_TWO_PI = 2 * math.pi


@njit(**JIT)
def wrap(angle):  # pragma: no cover  (compiled)
    """One angle [rad] wrapped to (-π, π]."""
    a = (angle + math.pi) % _TWO_PI - math.pi
    return a + _TWO_PI if a <= -math.pi else a


@njit(**JIT)
def _wrap_all(angles):  # pragma: no cover  (compiled)
    out = np.empty(angles.shape[0])
    for k in range(angles.shape[0]):
        out[k] = wrap(angles[k])
    return out


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to (-π, π] (:func:`wrap` of each), the shape of ``angle``."""
    a = np.asarray(angle, dtype=np.float64)
    return _wrap_all(a.reshape(-1)).reshape(a.shape)


@njit(**JIT)
def move(px, py, heading, gx, gy, speed, direction, holonomic, time_step):  # pragma: no cover  (compiled)
    """One robot's step from (px, py) with ``heading`` towards the goal (gx, gy) under the action (``speed`` [m/s],
    ``direction`` [rad]) of the module docstring's kinematics (``holonomic``: else unicycle).

    :return: ``(x, y, heading, vx, vy)`` after the step
    """
    base = math.atan2(gy - py, gx - px) if holonomic else heading
    new_heading = wrap(base + direction)
    vx, vy = speed * math.cos(new_heading), speed * math.sin(new_heading)
    return px + vx * time_step, py + vy * time_step, new_heading, vx, vy


class Motion(NamedTuple):
    """The robots after a step: :func:`apply_action`'s result."""

    position: np.ndarray  # (..., 2) [m]
    heading: np.ndarray  # (...) [rad]
    velocity: np.ndarray  # (..., 2) [m/s]


@njit(**JIT)
def _move_all(position, heading, goal, speed, direction, holonomic, time_step):  # pragma: no cover  (compiled)
    """:func:`move` of every row: position, goal (n, 2); heading, speed, direction (n,)."""
    n = position.shape[0]
    out = Motion(np.empty((n, 2)), np.empty(n), np.empty((n, 2)))
    for k in range(n):
        x, y, new_heading, vx, vy = move(position[k, 0], position[k, 1], heading[k], goal[k, 0], goal[k, 1], speed[k],
                                         direction[k], holonomic, time_step)
        out.position[k, 0], out.position[k, 1], out.heading[k] = x, y, new_heading
        out.velocity[k, 0], out.velocity[k, 1] = vx, vy
    return out


def check_kinematics(kinematics: str) -> bool:
    """Whether ``kinematics`` is holonomic (else unicycle); ``ValueError`` for any other value."""
    if kinematics not in KINEMATICS:
        raise ValueError(f"kinematics must be 'unicycle' or 'holonomic', got {kinematics!r}")
    return kinematics == "holonomic"


def action_table(v_pref: float = 1.0, rotation_range: float = 2 * math.pi) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(speeds, directions)``, each of shape (80,): the speed [m/s] and direction [rad] of every action."""
    if not (0 < rotation_range <= 2 * math.pi + 1e-9):
        raise ValueError(f"rotation_range must be in (0, 2π], got {rotation_range!r}")
    if not v_pref > 0:
        raise ValueError(f"v_pref must be > 0, got {v_pref!r}")
    speeds = v_pref * np.arange(1, N_SPEEDS + 1, dtype=np.float64) / N_SPEEDS
    if rotation_range >= 2 * math.pi - 1e-9:
        directions = wrap_angle(np.arange(N_DIRECTIONS) * 2 * np.pi / N_DIRECTIONS)
    else:
        directions = np.linspace(-rotation_range / 2, rotation_range / 2, N_DIRECTIONS)
    return np.repeat(speeds, N_DIRECTIONS), np.tile(directions, N_SPEEDS)


def apply_action(
    position: np.ndarray,
    heading: np.ndarray,
    goal: np.ndarray,
    speed: np.ndarray,
    direction: np.ndarray,
    kinematics: str,
    time_step: float,
) -> Motion:
    """Move the robot one step.

    :param position: (..., 2) [m]
    :param heading: (...) [rad]
    :param goal: (..., 2) [m]
    :param speed: (...) [m/s], broadcast against ``heading``
    :param direction: (...) [rad]
    :return: :class:`Motion`: ``(new_position (..., 2), new_heading (...), velocity (..., 2))``
    """
    holonomic = check_kinematics(kinematics)
    lead = np.broadcast_shapes(np.shape(position)[:-1], np.shape(heading), np.shape(goal)[:-1], np.shape(speed),
                               np.shape(direction))
    rows = [as_rows(x, lead, tail) for x, tail in ((position, (2,)), (heading, ()), (goal, (2,)), (speed, ()),
                                                   (direction, ()))]
    moved = _move_all(*rows, holonomic, float(time_step))
    return Motion(moved.position.reshape(*lead, 2), moved.heading.reshape(lead), moved.velocity.reshape(*lead, 2))


def nearest_action(
    velocity: np.ndarray,
    heading: float,
    goal_direction: float,
    speeds: np.ndarray,
    directions: np.ndarray,
    kinematics: str,
    allowed: np.ndarray | None = None,
) -> int:
    """Index of the action whose velocity is closest (Euclidean) to ``velocity`` (2,).

    ``allowed`` is an optional boolean mask (80,) restricting the choice.
    """
    base = heading if kinematics == "unicycle" else goal_direction
    angles = base + directions
    vx, vy = np.asarray(velocity, dtype=np.float64).tolist()
    dist = (speeds * np.cos(angles) - vx) ** 2 + (speeds * np.sin(angles) - vy) ** 2  # (80,)
    if allowed is not None and allowed.any():
        dist = np.where(allowed, dist, np.inf)
    return int(np.argmin(dist))
