"""The reward terms (paper Eq. 9-14), implemented once.

The env calls :func:`compute_reward` on one transition; the lookahead calls it on all
(batch x 80) propagated transitions. Everything broadcasts over leading dimensions.

Conventions (decisions on the paper's ambiguities, also in the docs: decisions):

* Collision: the robot and a pedestrian overlap at some moment of the step; both move on
  straight lines during Δt and the closest approach of the two segments is checked.
  A collision takes precedence over reaching the goal.
* Success: the robot's centre within its radius of the goal at the end of the step.
* On a terminal step (collision or success) the shaping terms are zero: the reward is the
  success reward or the collision penalty alone.
* ``"crowdnav"`` discomfort: ``(d - 0.2) * 0.5 * Δt`` with d the minimum *surface* distance
  to any pedestrian during the step, when d < 0.2 m.
* Social penalty (Eq. 9-11): in each pedestrian's frame (origin at its centre, x-axis along its
  walking direction) the robot's offset is measured **between surfaces**: the centre-to-centre
  vector shortened by the sum of the radii. ``w = sqrt(x0² d_side² / d_person² + y0²)`` and
  ``R = -r_p (exp(-(w - d_side)) - 1)`` when ``w <= d_side`` (inside the ellipse) and
  ``x0 >= 0`` (in front of the pedestrian). Penalties of several pedestrians are **summed**.
* Angular penalty (Eq. 13): ``-r_angle`` when ``|wrap(θ_t - θ_{t-1})| >= threshold``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from sb3_crowdnav.sim.actions import _wrap_scalar, wrap_angle
from sb3_crowdnav.sim.config import RewardConfig

STILL_SPEED = 1e-3  # [m/s] below this a pedestrian counts as standing still
ANGLE_TOLERANCE = 1e-9  # [rad] a turn of exactly the threshold (a table direction) counts despite rounding


def is_sharp_turn(turn: float, cfg: RewardConfig) -> bool:
    """Whether a heading change of ``|turn|`` rad in one step triggers Eq. 13 (``>= angular_penalty_threshold``)."""
    return abs(turn) >= cfg.angular_penalty_threshold - ANGLE_TOLERANCE


class RewardTerms(NamedTuple):
    """Every term of one (batch of) transition(s); arrays of shape (...)."""

    reward: np.ndarray
    success: np.ndarray
    collision: np.ndarray
    success_term: np.ndarray
    collision_term: np.ndarray
    discomfort_term: np.ndarray
    social_term: np.ndarray
    angular_term: np.ndarray
    min_distance: np.ndarray  # minimum surface distance to any present pedestrian during the step [m]
    in_comfort_zone: np.ndarray  # the robot is inside at least one comfort ellipse at the end of the step
    progress_term: np.ndarray | float = 0.0  # the warehouse's route-progress shaping (:func:`with_route_progress`)


def closest_approach(
    a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray
) -> np.ndarray:
    """Minimum centre distance between two points moving on straight lines a0→a1 and b0→b1 over one step.

    :param a0, a1, b0, b1: (..., 2), broadcast together
    :return: (...)
    """
    d0 = a0 - b0
    dv = (a1 - a0) - (b1 - b0)
    dv2 = np.sum(dv * dv, axis=-1)
    safe = np.where(dv2 > 1e-12, dv2, 1.0)
    t = np.clip(-np.sum(d0 * dv, axis=-1) / safe, 0.0, 1.0)
    t = np.where(dv2 > 1e-12, t, 0.0)
    closest = d0 + t[..., None] * dv
    return np.sqrt(np.sum(closest * closest, axis=-1))


def walking_direction(
    velocities: np.ndarray, human_pos: np.ndarray, robot_pos: np.ndarray
) -> np.ndarray:
    """Unit walking direction of each pedestrian from its velocity history.

    The most recent velocity faster than ``STILL_SPEED`` gives the direction (a pedestrian
    standing still keeps its last walking direction); a pedestrian still over the whole
    window faces the robot.

    :param velocities: (..., T, N, 2), oldest first
    :param human_pos: (..., N, 2)
    :param robot_pos: (..., 2)
    :return: (..., N, 2)
    """
    speed = np.linalg.norm(velocities, axis=-1)  # (..., T, N)
    moving = speed > STILL_SPEED
    t_len = velocities.shape[-3]
    # index of the last moving step (or -1)
    idx = np.where(moving, np.arange(t_len)[:, None], -1).max(axis=-2)  # (..., N)
    chosen = np.take_along_axis(velocities, np.maximum(idx, 0)[..., None, :, None], axis=-3)[..., 0, :, :]
    chosen_speed = np.linalg.norm(chosen, axis=-1, keepdims=True)
    facing = robot_pos[..., None, :] - human_pos
    facing_norm = np.linalg.norm(facing, axis=-1, keepdims=True)
    facing = np.where(facing_norm > 1e-9, facing / np.maximum(facing_norm, 1e-9), np.array([1.0, 0.0]))
    return np.where((idx >= 0)[..., None], chosen / np.maximum(chosen_speed, 1e-12), facing)


def social_penalty(
    rel_pos: np.ndarray, direction: np.ndarray, radius_sum: np.ndarray, mask: np.ndarray, cfg: RewardConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Summed comfort-zone penalty (Eq. 9-11) and whether the robot is inside any zone.

    :param rel_pos: (..., N, 2) robot centre minus pedestrian centre
    :param direction: (..., N, 2) unit walking direction
    :param radius_sum: (..., N)
    :param mask: (..., N) boolean
    :return: ``(penalty (...), inside_any (...))``
    """
    dist = np.linalg.norm(rel_pos, axis=-1)
    scale = np.maximum(dist - radius_sum, 0.0) / np.maximum(dist, 1e-9)
    surf = rel_pos * scale[..., None]
    x0 = np.sum(surf * direction, axis=-1)
    y0 = surf[..., 1] * direction[..., 0] - surf[..., 0] * direction[..., 1]
    w = np.sqrt(x0**2 * (cfg.comfort_side / cfg.comfort_person) ** 2 + y0**2)
    inside = (w <= cfg.comfort_side) & (x0 >= 0) & mask
    pen = np.where(inside, -cfg.social_penalty * (np.exp(-(w - cfg.comfort_side)) - 1.0), 0.0)
    return pen.sum(axis=-1), inside.any(axis=-1)


def compute_reward(
    cfg: RewardConfig,
    time_step: float,
    robot_pos0: np.ndarray,
    robot_pos1: np.ndarray,
    heading0: np.ndarray,
    heading1: np.ndarray,
    goal: np.ndarray,
    robot_radius: np.ndarray,
    human_pos0: np.ndarray,
    human_pos1: np.ndarray,
    human_dir: np.ndarray | None,
    human_radius: np.ndarray,
    mask: np.ndarray,
) -> RewardTerms:
    """Reward of the transitions robot_pos0 → robot_pos1 while pedestrians move human_pos0 → human_pos1.

    Shapes: robot positions and goal (..., 2); headings and robot radius (...);
    pedestrian positions and unit walking directions (..., N, 2); radius and mask (..., N).
    ``human_dir=None`` (batched path only) skips the comfort ellipses: allowed when the reward has
    no social term, and then ``in_comfort_zone`` is all False (the lookahead's case).
    A single transition (no leading dimensions, the env's case) takes a scalar fast path with
    the same arithmetic; a test checks that both paths agree on random transitions.
    """
    if human_dir is None and cfg.uses_social:
        raise ValueError(f"reward {cfg.name!r} has a social term: human_dir is required")
    if np.ndim(robot_pos1) == 1 and np.ndim(human_pos1) == 2 and np.ndim(heading1) == 0 and human_dir is not None:
        return _compute_reward_single(cfg, time_step, robot_pos0, robot_pos1, heading0, heading1, goal, robot_radius,
                                      human_pos0, human_pos1, human_dir, human_radius, mask)
    mask = mask.astype(bool)
    radius_sum = human_radius + robot_radius[..., None]
    centre = closest_approach(robot_pos0[..., None, :], robot_pos1[..., None, :], human_pos0, human_pos1)
    surface = np.where(mask, centre - radius_sum, np.inf)
    min_distance = surface.min(axis=-1) if surface.shape[-1] else np.full(surface.shape[:-1], np.inf)
    collision = min_distance < 0
    success = ~collision & (np.linalg.norm(robot_pos1 - goal, axis=-1) < robot_radius)
    terminal = collision | success
    zero = np.zeros(collision.shape)

    success_term = np.where(success, cfg.success_reward, 0.0)
    collision_term = np.where(collision, cfg.collision_penalty, 0.0)
    if human_dir is None:
        social, inside = zero, np.zeros(collision.shape, dtype=bool)
    else:
        social, inside = social_penalty(robot_pos1[..., None, :] - human_pos1, human_dir, radius_sum, mask, cfg)
    discomfort = zero
    if cfg.uses_discomfort:
        discomfort = np.where(
            ~terminal & (min_distance < cfg.discomfort_dist),
            (min_distance - cfg.discomfort_dist) * cfg.discomfort_factor * time_step,
            0.0,
        )
    social_term = np.where(~terminal, social, 0.0) if cfg.uses_social else zero
    angular_term = zero
    if cfg.uses_angular:
        turn = np.abs(wrap_angle(heading1 - heading0))
        sharp = turn >= cfg.angular_penalty_threshold - ANGLE_TOLERANCE  # is_sharp_turn, broadcast
        angular_term = np.where(~terminal & sharp, -cfg.angular_penalty, 0.0)
    reward = success_term + collision_term + discomfort + social_term + angular_term
    return RewardTerms(
        reward=reward,
        success=success,
        collision=collision,
        success_term=success_term,
        collision_term=collision_term,
        discomfort_term=discomfort,
        social_term=social_term,
        angular_term=angular_term,
        min_distance=min_distance,
        in_comfort_zone=inside,
        progress_term=zero,
    )


def _compute_reward_single(cfg, time_step, robot_pos0, robot_pos1, heading0, heading1, goal, robot_radius,
                           human_pos0, human_pos1, human_dir, human_radius, mask) -> RewardTerms:
    """:func:`compute_reward` of one transition in Python floats (NumPy's per-call overhead dominates at N <= 10).

    Line by line the same formulas as :func:`closest_approach`, :func:`social_penalty` and the
    batched body; results agree to rounding (NumPy sums 8+ terms pairwise).
    """
    ax0, ay0 = float(robot_pos0[0]), float(robot_pos0[1])
    ax1, ay1 = float(robot_pos1[0]), float(robot_pos1[1])
    rr = float(robot_radius)
    k2 = (cfg.comfort_side / cfg.comfort_person) ** 2
    side = cfg.comfort_side
    # inside an ellipse needs w <= d_side, and w >= min(1, d_side/d_person) * |offset| for a unit direction
    reach = max(cfg.comfort_person, cfg.comfort_side) * (1 + 1e-9)
    min_distance = math.inf
    social = 0.0
    inside_any = False
    for (bx0, by0), (bx1, by1), (dx, dy), hr, present in zip(
        human_pos0.tolist(), human_pos1.tolist(), human_dir.tolist(), human_radius.tolist(), mask.tolist(),
        strict=True,
    ):
        if not present:
            continue
        rs = hr + rr
        # closest approach of the two straight-line motions (closest_approach)
        d0x, d0y = ax0 - bx0, ay0 - by0
        dvx, dvy = (ax1 - ax0) - (bx1 - bx0), (ay1 - ay0) - (by1 - by0)
        dv2 = dvx * dvx + dvy * dvy
        t = 0.0
        if dv2 > 1e-12:
            t = -(d0x * dvx + d0y * dvy) / dv2
            t = 0.0 if t < 0.0 else 1.0 if t > 1.0 else t
        cx, cy = d0x + t * dvx, d0y + t * dvy
        surface = math.sqrt(cx * cx + cy * cy) - rs
        if surface < min_distance:
            min_distance = surface
        # comfort ellipse at the end of the step (social_penalty)
        rx, ry = ax1 - bx1, ay1 - by1
        dist = math.sqrt(rx * rx + ry * ry)
        gap = dist - rs
        if gap > reach:
            continue
        scale = (gap if gap > 0.0 else 0.0) / (dist if dist > 1e-9 else 1e-9)
        sx, sy = rx * scale, ry * scale
        x0 = sx * dx + sy * dy
        y0 = sy * dx - sx * dy
        w = math.sqrt(x0**2 * k2 + y0**2)
        if w <= side and x0 >= 0:
            inside_any = True
            social += -cfg.social_penalty * (math.exp(-(w - side)) - 1.0)
    collision = min_distance < 0
    gx, gy = ax1 - float(goal[0]), ay1 - float(goal[1])
    success = not collision and math.sqrt(gx * gx + gy * gy) < rr
    terminal = collision or success
    success_term = cfg.success_reward if success else 0.0
    collision_term = cfg.collision_penalty if collision else 0.0
    discomfort = 0.0
    if cfg.uses_discomfort and not terminal and min_distance < cfg.discomfort_dist:
        discomfort = (min_distance - cfg.discomfort_dist) * cfg.discomfort_factor * time_step
    social_term = social if cfg.uses_social and not terminal else 0.0
    angular_term = 0.0
    if cfg.uses_angular and not terminal:
        if is_sharp_turn(_wrap_scalar(float(heading1) - float(heading0)), cfg):
            angular_term = -cfg.angular_penalty
    reward = success_term + collision_term + discomfort + social_term + angular_term
    f64, b_ = np.float64, np.bool_
    return RewardTerms(
        reward=f64(reward),
        success=b_(success),
        collision=b_(collision),
        success_term=f64(success_term),
        collision_term=f64(collision_term),
        discomfort_term=f64(discomfort),
        social_term=f64(social_term),
        angular_term=f64(angular_term),
        min_distance=f64(min_distance),
        in_comfort_zone=b_(inside_any),
        progress_term=f64(0.0),
    )


def with_obstacle_collision(terms: RewardTerms, hit: np.ndarray, penalty: float) -> RewardTerms:
    """``terms`` of transitions in which the robot also hit a static obstacle where ``hit`` (...) is True.

    A hit is a collision: it ends the episode and takes precedence over reaching the goal; its reward is
    ``penalty`` alone (no shaping terms), unless the same step already collided with a pedestrian, whose
    penalty then stands. Broadcasts like :func:`compute_reward`; the env and the lookahead both use it.
    """
    hit = np.asarray(hit, dtype=bool) & ~np.asarray(terms.collision, dtype=bool)
    if not hit.any():
        return terms
    keep = ~hit
    zero = np.zeros(hit.shape)
    return RewardTerms(
        reward=np.where(keep, terms.reward, penalty),
        success=np.asarray(terms.success) & keep,
        collision=np.asarray(terms.collision) | hit,
        success_term=np.where(keep, terms.success_term, zero),
        collision_term=np.where(keep, terms.collision_term, penalty),
        discomfort_term=np.where(keep, terms.discomfort_term, zero),
        social_term=np.where(keep, terms.social_term, zero),
        angular_term=np.where(keep, terms.angular_term, zero),
        min_distance=terms.min_distance,
        in_comfort_zone=terms.in_comfort_zone,
        progress_term=np.where(keep, terms.progress_term, zero),
    )


def with_route_progress(terms: RewardTerms, pos0: np.ndarray, pos1: np.ndarray, waypoint: np.ndarray,
                        coefficient: float) -> RewardTerms:
    """``terms`` plus the route-progress shaping of the warehouse (off when ``coefficient`` is 0, the paper's reward).

    ``coefficient x (|pos0 - waypoint| - |pos1 - waypoint|)``: the metres the step gained on the route's current
    waypoint (the one observed at the start of the step), positive towards it, negative away; zero on a terminal
    step like every shaping term. Broadcasts like :func:`compute_reward` (positions (..., 2)); the env and the
    lookahead both use it, so the value's one-step reward equals the env's.
    """
    if coefficient == 0:
        return terms
    gained = np.linalg.norm(pos0 - waypoint, axis=-1) - np.linalg.norm(pos1 - waypoint, axis=-1)
    terminal = np.asarray(terms.success, dtype=bool) | np.asarray(terms.collision, dtype=bool)
    progress = np.where(terminal, 0.0, coefficient * gained)
    return terms._replace(reward=terms.reward + progress, progress_term=progress)


def worse_of(a: RewardTerms, b: RewardTerms) -> RewardTerms:
    """Per transition, the terms of ``a`` or ``b`` (same shapes) whichever has the lower reward (``a`` on ties).

    The lookahead's cautious pedestrian model (:class:`~sb3_crowdnav.apg_value.propagation.PropagationModel`)
    charges each action the worse of two predictions of the pedestrians' motion.
    """
    worse = np.asarray(b.reward) < np.asarray(a.reward)
    if not worse.any():
        return a
    return RewardTerms(*(np.where(worse, y, x) for x, y in zip(a, b, strict=True)))
