"""The reward terms (paper Eq. 9-14), implemented once.

The env calls :func:`compute_reward` on one transition; the lookahead calls it on all
(batch x 80) propagated transitions. Everything broadcasts over leading dimensions; one compiled
loop (``numba``) computes every transition, so both callers get the same arithmetic.

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
from numba import njit

from sb3_crowdnav.sim.actions import wrap
from sb3_crowdnav.sim.config import RewardConfig
from sb3_crowdnav.sim.geometry import JIT, as_rows

STILL_SPEED = 1e-3  # [m/s] below this a pedestrian counts as standing still
ANGLE_TOLERANCE = 1e-9  # [rad] a turn of exactly the threshold (a table direction) counts despite rounding
# [m] a braking sub-step that moves the robot less than this is standing: braking from a whole number of a_max·Δt
# leaves a speed residue of ~1e-16 m/s at the last sub-step, and whether it moves the position by an ulp depends on
# the last bit of the arithmetic (the numpy lookahead, an exported graph's operators)
STANDING_STEP = 1e-9


@njit(**JIT)
def _sharp(turn, threshold):  # pragma: no cover  (compiled)
    return abs(turn) >= threshold - ANGLE_TOLERANCE


def is_sharp_turn(turn: float, cfg: RewardConfig) -> bool:
    """Whether a heading change of ``|turn|`` rad in one step triggers Eq. 13 (``>= angular_penalty_threshold``)."""
    return bool(_sharp(turn, cfg.angular_penalty_threshold))


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


@njit(**JIT)
def _approach(d0x, d0y, dvx, dvy):  # pragma: no cover  (compiled)
    """Minimum of |d0 + t dv| over t in [0, 1]: the closest approach of two points whose offset starts at d0 and
    changes by dv over the step (linearly)."""
    dv2 = dvx * dvx + dvy * dvy
    t = 0.0
    if dv2 > 1e-12:
        t = min(max(-(d0x * dvx + d0y * dvy) / dv2, 0.0), 1.0)
    return math.hypot(d0x + t * dvx, d0y + t * dvy)


@njit(**JIT)
def _approaches(a0, a1, b0, b1):  # pragma: no cover  (compiled)
    out = np.empty(a0.shape[0])
    for k in range(a0.shape[0]):
        out[k] = _approach(a0[k, 0] - b0[k, 0], a0[k, 1] - b0[k, 1], (a1[k, 0] - a0[k, 0]) - (b1[k, 0] - b0[k, 0]),
                           (a1[k, 1] - a0[k, 1]) - (b1[k, 1] - b0[k, 1]))
    return out


def closest_approach(
    a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray
) -> np.ndarray:
    """Minimum centre distance between two points moving on straight lines a0→a1 and b0→b1 over one step.

    :param a0, a1, b0, b1: (..., 2), broadcast together
    :return: (...)
    """
    lead = np.broadcast_shapes(*(np.shape(x)[:-1] for x in (a0, a1, b0, b1)))
    rows = [as_rows(x, lead, (2,)) for x in (a0, a1, b0, b1)]
    return _approaches(*rows).reshape(lead)


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


class _Weights(NamedTuple):
    """What the compiled reward reads of a :class:`RewardConfig` (and the step)."""

    success_reward: float
    collision_penalty: float
    discomfort: bool
    discomfort_dist: float
    discomfort_scale: float  # discomfort_factor x Δt
    social: bool
    social_penalty: float
    comfort_side: float
    comfort_ratio2: float  # (comfort_side / comfort_person)²
    angular: bool
    angular_penalty: float
    angular_threshold: float


_WEIGHTS: dict[tuple[int, float], tuple[RewardConfig, _Weights]] = {}


def _weights(cfg: RewardConfig, time_step: float) -> _Weights:
    """The weights of ``cfg`` and the step, remembered per config object (the env asks every step)."""
    known = _WEIGHTS.get((id(cfg), time_step))
    if known is not None and known[0] is cfg:
        return known[1]
    weights = _Weights(float(cfg.success_reward), float(cfg.collision_penalty), cfg.uses_discomfort,
                       float(cfg.discomfort_dist), float(cfg.discomfort_factor) * time_step, cfg.uses_social,
                       float(cfg.social_penalty), float(cfg.comfort_side),
                       (float(cfg.comfort_side) / float(cfg.comfort_person)) ** 2, cfg.uses_angular,
                       float(cfg.angular_penalty), float(cfg.angular_penalty_threshold))
    if len(_WEIGHTS) >= 64:
        _WEIGHTS.clear()
    _WEIGHTS[(id(cfg), time_step)] = (cfg, weights)
    return weights


@njit(**JIT)
def _comfort(rx, ry, dx, dy, radius_sum, social_penalty, side, ratio2):  # pragma: no cover  (compiled)
    """Eq. 9-11 of one pedestrian: the robot's offset (rx, ry) from its centre, shortened by the radii (surface to
    surface), in the frame of its walking direction (dx, dy); returns (inside its comfort ellipse, the penalty)."""
    dist = math.hypot(rx, ry)
    scale = max(dist - radius_sum, 0.0) / max(dist, 1e-9)
    sx, sy = rx * scale, ry * scale
    x0 = sx * dx + sy * dy  # ahead of the pedestrian
    y0 = sy * dx - sx * dy  # beside it
    ellipse = math.sqrt(x0 * x0 * ratio2 + y0 * y0)
    inside = ellipse <= side and x0 >= 0
    return inside, -social_penalty * (math.exp(-(ellipse - side)) - 1.0) if inside else 0.0


@njit(**JIT)
def _transition(robot_pos0, robot_pos1, heading0, heading1, goal, robot_radius, human_pos0, human_pos1, human_dir,
                human_radius, mask, success_reward, collision_penalty, discomfort, discomfort_dist, discomfort_scale,
                social, social_penalty, comfort_side, comfort_ratio2, angular, angular_penalty,
                angular_threshold):  # pragma: no cover  (compiled)
    """The terms of one transition, in the order of :class:`RewardTerms`: robot positions and goal (2,), pedestrian
    arrays (N, 2) and (N,) (``human_dir`` None: no comfort ellipses), then the :class:`_Weights`."""
    ax0, ay0, ax1, ay1 = robot_pos0[0], robot_pos0[1], robot_pos1[0], robot_pos1[1]
    closest, summed, inside_any = np.inf, 0.0, False
    for j in range(human_pos0.shape[0]):
        if not mask[j]:
            continue
        bx0, by0, bx1, by1 = human_pos0[j, 0], human_pos0[j, 1], human_pos1[j, 0], human_pos1[j, 1]
        radius_sum = human_radius[j] + robot_radius
        closest = min(closest, _approach(ax0 - bx0, ay0 - by0, (ax1 - ax0) - (bx1 - bx0), (ay1 - ay0) - (by1 - by0))
                      - radius_sum)
        if human_dir is not None:
            inside, penalty = _comfort(ax1 - bx1, ay1 - by1, human_dir[j, 0], human_dir[j, 1], radius_sum,
                                       social_penalty, comfort_side, comfort_ratio2)
            inside_any = inside_any or inside
            summed += penalty
    collision = closest < 0
    success = not collision and math.hypot(ax1 - goal[0], ay1 - goal[1]) < robot_radius
    success_term = success_reward if success else 0.0
    collision_term = collision_penalty if collision else 0.0
    discomfort_term = social_term = angular_term = 0.0
    if not (collision or success):  # the shaping terms, on non-terminal steps only
        if discomfort and closest < discomfort_dist:
            discomfort_term = (closest - discomfort_dist) * discomfort_scale
        if social:
            social_term = summed
        if angular and _sharp(wrap(heading1 - heading0), angular_threshold):
            angular_term = -angular_penalty
    reward = success_term + collision_term + discomfort_term + social_term + angular_term
    return (reward, success, collision, success_term, collision_term, discomfort_term, social_term, angular_term,
            closest, inside_any)


@njit(**JIT)
def _transitions(robot_pos0, robot_pos1, heading0, heading1, goal, robot_radius, human_pos0, human_pos1, human_dir,
                 human_radius, mask, *weights):  # pragma: no cover  (compiled)
    """:func:`_transition` of n transitions, every array with a leading n; :class:`RewardTerms` of (n,) arrays."""
    n = robot_pos0.shape[0]
    out = RewardTerms(np.empty(n), np.empty(n, np.bool_), np.empty(n, np.bool_), np.empty(n), np.empty(n),
                      np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n, np.bool_), np.zeros(n))
    for k in range(n):
        (reward, success, collision, success_term, collision_term, discomfort_term, social_term, angular_term, closest,
         inside) = _transition(robot_pos0[k], robot_pos1[k], heading0[k], heading1[k], goal[k], robot_radius[k],
                               human_pos0[k], human_pos1[k], None if human_dir is None else human_dir[k],
                               human_radius[k], mask[k], *weights)
        out.reward[k], out.success[k], out.collision[k] = reward, success, collision
        out.success_term[k], out.collision_term[k], out.discomfort_term[k] = success_term, collision_term, discomfort_term
        out.social_term[k], out.angular_term[k] = social_term, angular_term
        out.min_distance[k], out.in_comfort_zone[k] = closest, inside
    return out


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
    pedestrian positions and unit walking directions (..., N, 2); radius and mask (..., N); broadcast together.
    ``human_dir=None`` skips the comfort ellipses: allowed when the reward has no social term, and then
    ``in_comfort_zone`` is all False (the lookahead's case).
    """
    if human_dir is None and cfg.uses_social:
        raise ValueError(f"reward {cfg.name!r} has a social term: human_dir is required")
    weights = _weights(cfg, float(time_step))
    one = np.ndim(robot_pos0) == np.ndim(robot_pos1) == np.ndim(goal) == 1 and np.ndim(heading1) == 0 and \
        np.ndim(human_pos1) == 2
    if one:  # one transition (the env's): no rows to make
        terms = _transition(robot_pos0, robot_pos1, float(heading0), float(heading1), goal, float(robot_radius),
                            human_pos0, human_pos1, human_dir, human_radius, np.asarray(mask, dtype=np.bool_), *weights)
        return RewardTerms(*(np.float64(x) if type(x) is float else np.bool_(x) for x in terms),
                           progress_term=np.float64(0.0))
    n_humans = np.shape(human_pos1)[-2]
    shapes = (np.shape(robot_pos0)[:-1], np.shape(robot_pos1)[:-1], np.shape(heading0), np.shape(heading1),
              np.shape(goal)[:-1], np.shape(robot_radius), np.shape(human_pos0)[:-2], np.shape(human_pos1)[:-2],
              np.shape(human_radius)[:-1], np.shape(mask)[:-1], () if human_dir is None else np.shape(human_dir)[:-2])
    lead = np.broadcast_shapes(*shapes)
    points, humans, per_human = (2,), (n_humans, 2), (n_humans,)
    terms = _transitions(
        as_rows(robot_pos0, lead, points), as_rows(robot_pos1, lead, points), as_rows(heading0, lead, ()),
        as_rows(heading1, lead, ()), as_rows(goal, lead, points), as_rows(robot_radius, lead, ()),
        as_rows(human_pos0, lead, humans), as_rows(human_pos1, lead, humans),
        None if human_dir is None else as_rows(human_dir, lead, humans), as_rows(human_radius, lead, per_human),
        as_rows(mask, lead, per_human, np.bool_), *weights,
    )
    return RewardTerms(*(x.reshape(lead) for x in terms))


def transition_terms(cfg: RewardConfig, time_step: float, robot_pos0: np.ndarray, robot_pos1: np.ndarray,
                     heading0: float, heading1: float, goal: np.ndarray, robot_radius: float, human_pos0: np.ndarray,
                     human_pos1: np.ndarray, human_dir: np.ndarray, human_radius: np.ndarray,
                     mask: np.ndarray) -> RewardTerms:
    """:func:`compute_reward` of one transition (a simulator's step: robot positions and goal (2,), pedestrian arrays
    (N, 2) and (N,), ``mask`` bool), the same kernel, its terms left as Python floats and bools."""
    return RewardTerms(*_transition(robot_pos0, robot_pos1, heading0, heading1, goal, robot_radius, human_pos0,
                                    human_pos1, human_dir, human_radius, mask, *_weights(cfg, time_step)), 0.0)


@njit(**JIT)
def walking_directions_step(newest, walk, age, t_len, robot_x, robot_y):  # pragma: no cover  (compiled)
    """:func:`walking_direction` of N pedestrians kept step by step: ``newest`` (N, >= 4) their newest px, py, vx, vy;
    ``walk`` (N, 2) the last walking direction of each and ``age`` (N,) the steps since (updated in place). A velocity
    faster than ``STILL_SPEED`` is the direction; a pedestrian still over the last ``t_len`` steps faces the robot."""
    n = newest.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        vx, vy = newest[i, 2], newest[i, 3]
        speed = math.sqrt(vx * vx + vy * vy)
        if speed > STILL_SPEED:
            walk[i, 0], walk[i, 1], age[i] = vx / speed, vy / speed, 0
        else:
            age[i] += 1
        if age[i] < t_len:
            out[i, 0], out[i, 1] = walk[i, 0], walk[i, 1]
        else:
            fx, fy = robot_x - newest[i, 0], robot_y - newest[i, 1]
            norm = math.sqrt(fx * fx + fy * fy)
            if norm > 1e-9:
                out[i, 0], out[i, 1] = fx / norm, fy / norm
            else:
                out[i, 0], out[i, 1] = 1.0, 0.0
    return out


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
