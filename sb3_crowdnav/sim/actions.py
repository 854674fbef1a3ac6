"""The action tables (the paper's 80 actions, 5 speeds x 16 directions, or those and a stop) and the robot kinematics.

Action ``a`` has speed index ``a // n_directions`` and direction index ``a % n_directions``.
Speeds are ``v_pref * (1..5) / 5``. With ``rotation_range = 2π`` the directions are
``k * 2π / 16`` wrapped to (-π, π] (direction index 0 is "straight on"); with a narrower
range they are ``linspace(-range/2, range/2, 16)`` (end points included).

* ``"unicycle"``: the direction is a rotation of the current heading, θ' = wrap(θ + Δθ),
  then the robot moves ``v * Δt`` along θ'.
* ``"holonomic"``: the direction is an absolute angle in the frame whose x-axis points from
  the robot to its goal; the heading becomes the direction of motion.

Action sets (:data:`ACTION_SETS`): ``"paper"``, the 80 actions above; ``"with_stop"``, the same 80 and
:data:`STOP_ACTION` = 80, speed 0 and direction 0 (the robot stops, at once without limits, and keeps its heading;
stopped, it stays where it is).

Limits (None: unlimited, the paper's robot). The command (speed ``v``, heading θ_c) of an action is clipped to
what the robot can reach from its current velocity ``v0`` (the observation's vx, vy) within one step Δt:

* ``"unicycle"``: the speed to ``[|v0| - a_max·Δt, |v0| + a_max·Δt]`` (never below 0), and the turn
  ``wrap(Δθ)`` to ``[-ω_max·Δt, ω_max·Δt]``; each limit by itself (a full-speed U-turn becomes a turn of
  ω_max·Δt at the commanded speed, if that speed is reachable).
* ``"holonomic"``: the velocity change ``v_c - v0`` to a norm of at most ``a_max·Δt`` (the commanded velocity
  taken as is when it is within reach); the heading is the direction of the resulting velocity, kept when the
  robot stands. A holonomic robot does not turn to move, so ``max_turn_rate`` is refused with it.

:func:`move` (compiled) is the kinematics: the env calls it on its one robot, and :func:`apply_action`
(broadcast over leading dimensions: the lookahead's batch x actions, the ORCA robot's reachable velocities)
loops over it. With no limits it computes exactly the paper's step.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from sb3_crowdnav.sim.geometry import JIT, as_rows

N_SPEEDS = 5
N_DIRECTIONS = 16
N_ACTIONS = N_SPEEDS * N_DIRECTIONS  # the paper's action set
ACTION_SETS = {"paper": N_ACTIONS, "with_stop": N_ACTIONS + 1}  # name: number of actions
STOP_ACTION = N_ACTIONS  # the index of the stop in "with_stop" (the last)
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
def move(px, py, heading, vx0, vy0, gx, gy, speed, direction, holonomic, time_step, max_speed_change,
         max_turn):  # pragma: no cover  (compiled)
    """One robot's step from (px, py) with ``heading`` and velocity (vx0, vy0) towards the goal (gx, gy) under the
    action (``speed`` [m/s], ``direction`` [rad]) by the module docstring's kinematics (``holonomic``: else unicycle)
    and limits: ``max_speed_change`` = a_max·Δt [m/s], ``max_turn`` = ω_max·Δt [rad] (``inf``: unlimited).

    :return: ``(x, y, heading, vx, vy)`` after the step
    """
    if holonomic:
        target = wrap(math.atan2(gy - py, gx - px) + direction)
        cvx, cvy = speed * math.cos(target), speed * math.sin(target)
        dvx, dvy = cvx - vx0, cvy - vy0
        change = math.sqrt(dvx * dvx + dvy * dvy)
        if change <= max_speed_change:  # within reach: the command as it is
            vx, vy = cvx, cvy
            new_heading = target if speed > 0 else heading
        else:
            scale = max_speed_change / change
            vx, vy = vx0 + dvx * scale, vy0 + dvy * scale
            new_heading = math.atan2(vy, vx) if vx != 0 or vy != 0 else heading
        return px + vx * time_step, py + vy * time_step, new_heading, vx, vy
    new_heading = wrap(heading + direction)
    turn = wrap(direction)
    if turn > max_turn:
        new_heading = wrap(heading + max_turn)
    elif turn < -max_turn:
        new_heading = wrap(heading - max_turn)
    speed0 = math.sqrt(vx0 * vx0 + vy0 * vy0)
    speed = min(max(speed, speed0 - max_speed_change), speed0 + max_speed_change)
    vx, vy = speed * math.cos(new_heading), speed * math.sin(new_heading)
    return px + vx * time_step, py + vy * time_step, new_heading, vx, vy


def step_limits(max_acceleration: float | None, max_turn_rate: float | None, time_step: float) -> tuple[float, float]:
    """:func:`move`'s limits per step: (a_max·Δt [m/s], ω_max·Δt [rad]), ``inf`` for an unlimited (None) one."""
    return (math.inf if max_acceleration is None else max_acceleration * time_step,
            math.inf if max_turn_rate is None else max_turn_rate * time_step)


class Motion(NamedTuple):
    """The robots after a step: :func:`apply_action`'s result."""

    position: np.ndarray  # (..., 2) [m]
    heading: np.ndarray  # (...) [rad]
    velocity: np.ndarray  # (..., 2) [m/s]


@njit(**JIT)
def _move_all(position, heading, velocity, goal, speed, direction, holonomic, time_step, max_speed_change,
              max_turn):  # pragma: no cover  (compiled)
    """:func:`move` of every row: position, velocity, goal (n, 2); heading, speed, direction (n,)."""
    n = position.shape[0]
    out = Motion(np.empty((n, 2)), np.empty(n), np.empty((n, 2)))
    for k in range(n):
        x, y, new_heading, vx, vy = move(position[k, 0], position[k, 1], heading[k], velocity[k, 0], velocity[k, 1],
                                         goal[k, 0], goal[k, 1], speed[k], direction[k], holonomic, time_step,
                                         max_speed_change, max_turn)
        out.position[k, 0], out.position[k, 1], out.heading[k] = x, y, new_heading
        out.velocity[k, 0], out.velocity[k, 1] = vx, vy
    return out


@njit(**JIT)
def reachable_velocities(px, py, heading, vx0, vy0, gx, gy, speeds, directions, holonomic, time_step,
                         max_speed_change, max_turn):  # pragma: no cover  (compiled)
    """The velocity (vx (n,), vy (n,)) :func:`move` gives one robot under each action (``speeds``, ``directions``
    (n,)): :func:`apply_action`'s velocities of one robot and every action, without its broadcasting."""
    n = speeds.shape[0]
    vx, vy = np.empty(n), np.empty(n)
    for k in range(n):
        _, _, _, vx[k], vy[k] = move(px, py, heading, vx0, vy0, gx, gy, speeds[k], directions[k], holonomic, time_step,
                                     max_speed_change, max_turn)
    return vx, vy


def check_kinematics(kinematics: str) -> bool:
    """Whether ``kinematics`` is holonomic (else unicycle); ``ValueError`` for any other value."""
    if kinematics not in KINEMATICS:
        raise ValueError(f"kinematics must be 'unicycle' or 'holonomic', got {kinematics!r}")
    return kinematics == "holonomic"


def check_actions(actions: str) -> int:
    """The number of actions of the action set ``actions`` (:data:`ACTION_SETS`); ``ValueError`` for another name."""
    if actions not in ACTION_SETS:
        raise ValueError(f"actions must be one of {sorted(ACTION_SETS)}, got {actions!r}")
    return ACTION_SETS[actions]


def action_table(v_pref: float = 1.0, rotation_range: float = 2 * math.pi,
                 actions: str = "paper") -> tuple[np.ndarray, np.ndarray]:
    """Return ``(speeds, directions)``, each of shape (n_actions,): the speed [m/s] and direction [rad] of every
    action of the set ``actions`` (80 for ``"paper"``; ``"with_stop"`` adds (0, 0) as action :data:`STOP_ACTION`)."""
    check_actions(actions)
    if not (0 < rotation_range <= 2 * math.pi + 1e-9):
        raise ValueError(f"rotation_range must be in (0, 2π], got {rotation_range!r}")
    if not v_pref > 0:
        raise ValueError(f"v_pref must be > 0, got {v_pref!r}")
    speeds = v_pref * np.arange(1, N_SPEEDS + 1, dtype=np.float64) / N_SPEEDS
    if rotation_range >= 2 * math.pi - 1e-9:
        directions = wrap_angle(np.arange(N_DIRECTIONS) * 2 * np.pi / N_DIRECTIONS)
    else:
        directions = np.linspace(-rotation_range / 2, rotation_range / 2, N_DIRECTIONS)
    speeds, directions = np.repeat(speeds, N_DIRECTIONS), np.tile(directions, N_SPEEDS)
    if actions == "with_stop":
        speeds, directions = np.append(speeds, 0.0), np.append(directions, 0.0)
    return speeds, directions


def apply_action(
    position: np.ndarray,
    heading: np.ndarray,
    goal: np.ndarray,
    speed: np.ndarray,
    direction: np.ndarray,
    kinematics: str,
    time_step: float,
    velocity: np.ndarray | None = None,
    max_acceleration: float | None = None,
    max_turn_rate: float | None = None,
) -> Motion:
    """Move the robot one step (:func:`move` of every entry).

    :param position: (..., 2) [m]
    :param heading: (...) [rad]
    :param goal: (..., 2) [m]
    :param speed: (...) [m/s], broadcast against ``heading``
    :param direction: (...) [rad]
    :param velocity: (..., 2) [m/s] the robot's velocity before the step; needed with ``max_acceleration`` only
    :param max_acceleration: a_max [m/s²], None: unlimited
    :param max_turn_rate: ω_max [rad/s], None: unlimited
    :return: :class:`Motion`: ``(new_position (..., 2), new_heading (...), velocity (..., 2))``
    """
    holonomic = check_kinematics(kinematics)
    if velocity is None:
        if max_acceleration is not None:
            raise ValueError("velocity: max_acceleration limits the change of the robot's velocity; pass it")
        velocity = np.zeros(2)
    lead = np.broadcast_shapes(np.shape(position)[:-1], np.shape(heading), np.shape(velocity)[:-1],
                               np.shape(goal)[:-1], np.shape(speed), np.shape(direction))
    rows = [as_rows(x, lead, tail) for x, tail in ((position, (2,)), (heading, ()), (velocity, (2,)), (goal, (2,)),
                                                   (speed, ()), (direction, ()))]
    moved = _move_all(*rows, holonomic, float(time_step), *step_limits(max_acceleration, max_turn_rate, time_step))
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
    """Index of the action whose commanded velocity is closest (Euclidean) to ``velocity`` (2,).

    ``allowed`` is an optional boolean mask (n_actions,) restricting the choice.
    """
    base = heading if kinematics == "unicycle" else goal_direction
    angles = base + directions
    return nearest_velocity(velocity, speeds * np.cos(angles), speeds * np.sin(angles), allowed)


def nearest_velocity(velocity: np.ndarray, vx: np.ndarray, vy: np.ndarray, allowed: np.ndarray | None = None) -> int:
    """Index of the candidate velocity (``vx``, ``vy``, each (n,) [m/s]) closest (Euclidean) to ``velocity`` (2,);
    ``allowed`` (n,) bool restricts the choice unless it allows none."""
    wx, wy = np.asarray(velocity, dtype=np.float64).tolist()
    dist = (vx - wx) ** 2 + (vy - wy) ** 2  # (n,)
    if allowed is not None and allowed.any():
        dist = np.where(allowed, dist, np.inf)
    return int(np.argmin(dist))
