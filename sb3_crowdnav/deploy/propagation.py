"""The lookahead's propagation model and reward in torch, in float64: the part of an exported decision before V.

:class:`~sb3_crowdnav.apg_value.propagation.PropagationModel` runs in numpy and calls the env's own compiled
functions, which an exported graph cannot hold. :class:`GraphPropagation` is the same computation written with torch
operators so that ``torch.onnx.export`` records it: the robot's kinematics and limits
(:func:`~sb3_crowdnav.sim.actions.move`), the constant-velocity pedestrians and the history shift, the reward terms
(:func:`~sb3_crowdnav.sim.rewards.compute_reward`, the cautious model's :func:`~sb3_crowdnav.sim.rewards.worse_of`),
the progress shaping (on the goal, or on the route's current waypoint), in the warehouse the swept-disc obstacle
check (:func:`~sb3_crowdnav.sim.geometry.swept_clearance`) and the waypoint rule
(:func:`~sb3_crowdnav.sim.warehouse.simulator.next_waypoints`), and the stopping-distance check
(:func:`~sb3_crowdnav.apg_value.propagation.braking_path`, :func:`~sb3_crowdnav.apg_value.propagation.braking_hits`).
Each function follows its numpy counterpart's arithmetic step by step, in float64 as it does; ``tests/test_deploy.py``
compares the two.

The one difference is the stopping check's number of braking sub-steps. The numpy lookahead brakes until the fastest
robot of its batch stands; a graph runs a fixed number, ``braking_steps`` (:func:`braking_steps`: enough for a robot
one a_max·Δt faster than the fastest action of its v_pref). A robot stands after its own last sub-step and stays put in
the extra ones, which charge nothing, so the two agree wherever the robot brakes within ``braking_steps``; the runtime
refuses an observation it would not (:class:`~sb3_crowdnav.deploy.runtime.OnnxPolicy`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch as th
from torch import nn

from sb3_crowdnav.sim.actions import wrap_angle
from sb3_crowdnav.sim.observation import (
    OBS_KEYS,
    OBSTACLE_KEYS,
    ROBOT_DIM,
    SEGMENT_DIM,
    WAYPOINT_KEY,
    Human,
    ObservationSchema,
    Robot,
)
from sb3_crowdnav.sim.rewards import ANGLE_TOLERANCE, STANDING_STEP, STILL_SPEED
from sb3_crowdnav.sim.world import World

TWO_PI = 2 * math.pi
F64 = th.float64


def f64(value: float) -> th.Tensor:
    """A float64 constant. Every constant of the float64 arithmetic is one: the exporter would write a Python number
    into the graph as a float32 constant (π as 3.14159274), and the graph would no longer be the numpy code's."""
    return th.tensor(value, dtype=F64)


def wrap(angle: th.Tensor) -> th.Tensor:
    """Angles wrapped to (-π, π], as :func:`~sb3_crowdnav.sim.actions.wrap` (Python's float ``%``: fmod, then
    the divisor added to a negative remainder)."""
    pi, two_pi = f64(math.pi), f64(TWO_PI)
    r = th.fmod(angle + pi, two_pi)
    a = th.where(r < 0, r + two_pi, r) - pi
    return th.where(a <= -pi, a + two_pi, a)


def atan2(y: th.Tensor, x: th.Tensor) -> th.Tensor:
    """``atan2`` of float64 tensors to float64 precision: ONNX Runtime has no float64 Atan, so a float32 first guess
    is corrected by one Newton step, ``a + (y cos a - x sin a) / (x cos a + y sin a)`` (error ~ guess error³);
    0 where x = y = 0, as ``math.atan2``."""
    a = th.atan2(y.float(), x.float()).to(F64)
    cos, sin = th.cos(a), th.sin(a)
    den = x * cos + y * sin  # |(x, y)| when the guess is right
    ok = den > 0
    a = a + th.where(ok, (y * cos - x * sin) / th.where(ok, den, 1.0), 0.0)
    pi, two_pi = f64(math.pi), f64(TWO_PI)
    return th.where(a > pi, a - two_pi, th.where(a < -pi, a + two_pi, a))


def norm2(x: th.Tensor, y: th.Tensor) -> th.Tensor:
    """``sqrt(x² + y²)`` (ONNX has no hypot; equal to ``math.hypot`` but for the last bit)."""
    return th.sqrt(x * x + y * y)


def closest_approach(d0x, d0y, dvx, dvy) -> th.Tensor:
    """Minimum of |d0 + t dv| over t in [0, 1] (:func:`~sb3_crowdnav.sim.rewards.closest_approach`'s kernel)."""
    dv2 = dvx * dvx + dvy * dvy
    moving = dv2 > f64(1e-12)
    t = th.where(moving, (-(d0x * dvx + d0y * dvy) / th.where(moving, dv2, 1.0)).clamp(0.0, 1.0), 0.0)
    return norm2(d0x + t * dvx, d0y + t * dvy)


def point_to_segment(px, py, ax, ay, bx, by) -> th.Tensor:
    """Distance from points to segments (:func:`~sb3_crowdnav.sim.geometry.point_to_segment`)."""
    abx, aby = bx - ax, by - ay
    length2 = abx * abx + aby * aby
    t = ((px - ax) * abx + (py - ay) * aby) / th.where(length2 > f64(1e-18), length2, 1.0)
    t = t.clamp(0.0, 1.0)
    return norm2(px - (ax + t * abx), py - (ay + t * aby))


def _cross(ox, oy, ax, ay, bx, by):
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


def segment_to_segment(p0x, p0y, p1x, p1y, q0x, q0y, q1x, q1y) -> th.Tensor:
    """Minimum distance between segments (:func:`~sb3_crowdnav.sim.geometry.segment_to_segment`)."""
    crossing = (_cross(q0x, q0y, q1x, q1y, p0x, p0y) * _cross(q0x, q0y, q1x, q1y, p1x, p1y) < 0) & \
               (_cross(p0x, p0y, p1x, p1y, q0x, q0y) * _cross(p0x, p0y, p1x, p1y, q1x, q1y) < 0)
    ends = th.minimum(th.minimum(point_to_segment(p0x, p0y, q0x, q0y, q1x, q1y),
                                 point_to_segment(p1x, p1y, q0x, q0y, q1x, q1y)),
                      th.minimum(point_to_segment(q0x, q0y, p0x, p0y, p1x, p1y),
                                 point_to_segment(q1x, q1y, p0x, p0y, p1x, p1y)))
    return th.where(crossing, 0.0, ends)


def braking_steps(world: World, v_pref: float) -> int:
    """The braking sub-steps of an exported stopping check for a robot of preferred speed ``v_pref`` [m/s]:
    ``ceil(v_pref·max(speed fractions) / (a_max·Δt)) + 1``, one more than the fastest action of the table needs, so
    that a robot whose odometry reads up to a_max·Δt above its fastest action still brakes to a stand in the graph."""
    if world.max_acceleration is None:
        raise ValueError("braking_steps needs a world with max_acceleration (a robot without a limit stops at once)")
    fastest = float(v_pref) * float(np.max(world.action_table(1.0)[0]))
    return math.ceil(fastest / (world.max_acceleration * world.time_step) - 1e-9) + 1


def walking_direction(velocities: th.Tensor, human_pos: th.Tensor, robot_pos: th.Tensor) -> th.Tensor:
    """Unit walking directions (:func:`~sb3_crowdnav.sim.rewards.walking_direction`): velocities (B, T, M, 2),
    human_pos (B, M, 2), robot_pos (B, A, 2) -> (B, A, M, 2)."""
    steps = velocities.shape[1]
    moving = norm2(velocities[..., 0], velocities[..., 1]) > f64(STILL_SPEED)  # (B, T, M)
    index = th.arange(steps, device=velocities.device)[None, :, None]
    last = th.where(moving, index, -1).amax(dim=1)  # (B, M) the last moving step, or -1
    chosen = th.gather(velocities, 1, last.clamp(min=0)[:, None, :, None].expand(-1, 1, -1, 2))[:, 0]  # (B, M, 2)
    chosen_speed = norm2(chosen[..., 0], chosen[..., 1])[..., None]
    facing = robot_pos[:, :, None, :] - human_pos[:, None]  # (B, A, M, 2)
    facing_norm = norm2(facing[..., 0], facing[..., 1])[..., None]
    east = th.tensor([1.0, 0.0], dtype=F64, device=facing.device)
    facing = th.where(facing_norm > f64(1e-9), facing / th.maximum(facing_norm, f64(1e-9)), east)
    walking = (chosen / th.maximum(chosen_speed, f64(1e-12)))[:, None]  # (B, 1, M, 2)
    return th.where((last >= 0)[:, None, :, None], walking, facing)


class Terms(NamedTuple):
    """What the decision needs of the reward terms, each (B, A)."""

    reward: th.Tensor
    success: th.Tensor
    collision: th.Tensor


class Propagated(NamedTuple):
    """The propagated observations (float32, rows b-major: b * A + a) and the reward (float64) of B x A actions."""

    observation: dict[str, th.Tensor]
    reward: th.Tensor  # (B, A)
    terminal: th.Tensor  # (B, A)
    discount: th.Tensor  # (B,)


class GraphPropagation(nn.Module):
    """:class:`~sb3_crowdnav.apg_value.propagation.PropagationModel` as a torch module (see the module docstring).

    :param world: the model's world
    :param schema: its observation schema
    :param gamma: discount per second at v_pref = 1
    :param pedestrian_model: ``"constant_velocity"`` or ``"cautious"``
    :param braking_steps: the stopping-distance check's braking sub-steps (:func:`braking_steps`); None: no check
    """

    def __init__(self, world: World, schema: ObservationSchema, gamma: float, pedestrian_model: str,
                 braking_steps: int | None = None) -> None:
        super().__init__()
        self.world, self.schema, self.gamma = world, schema, float(gamma)
        self.cautious = pedestrian_model == "cautious"
        self.braking_steps = braking_steps
        speeds, directions = world.action_table(1.0)
        max_turn = None if world.max_turn_rate is None else world.max_turn_rate * world.time_step
        self.max_speed_change = None if world.max_acceleration is None else world.max_acceleration * world.time_step
        if max_turn is not None:  # move(): a turn beyond ω_max·Δt becomes exactly ±ω_max·Δt
            turn = wrap_angle(directions)
            directions = np.where(turn > max_turn, max_turn, np.where(turn < -max_turn, -max_turn, directions))
        self.register_buffer("speed_fractions", th.as_tensor(speeds, dtype=F64), persistent=False)
        self.register_buffer("directions", th.as_tensor(directions, dtype=F64), persistent=False)
        cfg = world.reward
        self.weights = dict(success=float(cfg.success_reward), collision=float(cfg.collision_penalty),
                            discomfort_dist=float(cfg.discomfort_dist),
                            discomfort_scale=float(cfg.discomfort_factor) * world.time_step,
                            social_penalty=float(cfg.social_penalty), side=float(cfg.comfort_side),
                            ratio2=(float(cfg.comfort_side) / float(cfg.comfort_person)) ** 2,
                            angular_penalty=float(cfg.angular_penalty), threshold=float(cfg.angular_penalty_threshold))

    # ------------------------------------------------------------------ the robot
    def move(self, pos0: th.Tensor, heading0: th.Tensor, goal: th.Tensor, vel0: th.Tensor, speeds: th.Tensor,
             directions: th.Tensor | None = None) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """:func:`~sb3_crowdnav.sim.actions.move` of every action: pos0, goal, vel0 (B, 1, 2), heading0 (B, 1),
        speeds (B, A) -> position (B, A, 2), heading (B, A), velocity (B, A, 2). ``directions``: the commands'
        directions (default: the action table's; braking: 0), broadcast with the speeds."""
        limit = None if self.max_speed_change is None else f64(self.max_speed_change)
        directions = self.directions if directions is None else directions
        vx0, vy0 = vel0[..., 0], vel0[..., 1]
        if self.world.kinematics == "holonomic":
            to_goal = goal - pos0
            target = wrap(atan2(to_goal[..., 1], to_goal[..., 0]) + directions)
            vx, vy = speeds * th.cos(target), speeds * th.sin(target)
            heading = th.where(speeds > 0, target, heading0)
            if limit is not None:
                dvx, dvy = vx - vx0, vy - vy0
                change = th.sqrt(dvx * dvx + dvy * dvy)
                within = change <= limit
                scale = limit / th.where(within, 1.0, change)
                vx, vy = th.where(within, vx, vx0 + dvx * scale), th.where(within, vy, vy0 + dvy * scale)
                still = (vx == 0) & (vy == 0)
                heading = th.where(within, heading, th.where(still, heading0, atan2(vy, vx)))
        else:
            heading = wrap(heading0 + directions)
            if limit is not None:
                speed0 = th.sqrt(vx0 * vx0 + vy0 * vy0)
                speeds = th.minimum(th.maximum(speeds, speed0 - limit), speed0 + limit)
            vx, vy = speeds * th.cos(heading), speeds * th.sin(heading)
        dt = f64(self.world.time_step)
        position = th.stack((pos0[..., 0] + vx * dt, pos0[..., 1] + vy * dt), dim=-1)
        return position, heading, th.stack((vx, vy), dim=-1)

    # ------------------------------------------------------------------ the reward
    def terms(self, pos0, pos1, heading0, heading1, goal, radius, start, end, dirs, human_radius, mask) -> Terms:
        """:func:`~sb3_crowdnav.sim.rewards.compute_reward`: robot pos0, goal (B, 1, 2), pos1 (B, A, 2), heading0,
        radius (B, 1), heading1 (B, A); pedestrians start, end (B, 1, M, 2), dirs (B, A, M, 2) or None, radius and
        mask (B, 1, M)."""
        w = {name: f64(value) for name, value in self.weights.items()}
        ax0, ay0 = pos0[..., 0:1], pos0[..., 1:2]  # (B, 1, 1)
        ax1, ay1 = pos1[..., 0:1], pos1[..., 1:2]  # (B, A, 1)
        bx0, by0, bx1, by1 = start[..., 0], start[..., 1], end[..., 0], end[..., 1]  # (B, 1, M)
        radius_sum = human_radius + radius[..., None]
        gap = closest_approach(ax0 - bx0, ay0 - by0, (ax1 - ax0) - (bx1 - bx0), (ay1 - ay0) - (by1 - by0)) - radius_sum
        closest = th.where(mask, gap, math.inf).amin(dim=-1)  # (B, A); inf without anyone
        collision = closest < 0
        success = ~collision & (norm2(pos1[..., 0] - goal[..., 0], pos1[..., 1] - goal[..., 1]) < radius)
        shaping = ~(collision | success)
        reward = _where(success, self.weights["success"]) + _where(collision, self.weights["collision"])
        cfg = self.world.reward
        if cfg.uses_discomfort:
            near = shaping & (closest < w["discomfort_dist"])
            reward = reward + th.where(near, (closest - w["discomfort_dist"]) * w["discomfort_scale"], 0.0)
        if cfg.uses_social:
            penalty = self.comfort(ax1 - bx1, ay1 - by1, dirs, radius_sum)
            penalty = th.where(mask, penalty, 0.0)
            summed = th.zeros_like(closest)
            for j in range(penalty.shape[-1]):  # in slot order, as the compiled loop adds them
                summed = summed + penalty[..., j]
            reward = reward + th.where(shaping, summed, 0.0)
        if cfg.uses_angular:
            sharp = th.abs(wrap(heading1 - heading0)) >= f64(self.weights["threshold"] - ANGLE_TOLERANCE)
            reward = reward + _where(shaping & sharp, -self.weights["angular_penalty"])
        return Terms(reward, success, collision)

    def comfort(self, rx: th.Tensor, ry: th.Tensor, dirs: th.Tensor, radius_sum: th.Tensor) -> th.Tensor:
        """Eq. 9-11 of every pedestrian (``_comfort`` of :mod:`sb3_crowdnav.sim.rewards`): (B, A, M)."""
        w = {name: f64(value) for name, value in self.weights.items()}
        dist = norm2(rx, ry)
        scale = (dist - radius_sum).clamp(min=0.0) / th.maximum(dist, f64(1e-9))
        sx, sy = rx * scale, ry * scale
        dx, dy = dirs[..., 0], dirs[..., 1]
        x0 = sx * dx + sy * dy
        y0 = sy * dx - sx * dy
        ellipse = th.sqrt(x0 * x0 * w["ratio2"] + y0 * y0)
        inside = (ellipse <= w["side"]) & (x0 >= 0)
        return th.where(inside, -w["social_penalty"] * (th.exp(-(ellipse - w["side"])) - 1.0), 0.0)

    def progress(self, terms: Terms, pos0: th.Tensor, pos1: th.Tensor, target: th.Tensor) -> Terms:
        """:func:`~sb3_crowdnav.sim.rewards.with_route_progress`: ``terms`` plus k x the metres gained on ``target``
        (the goal, or the route's current waypoint), zero on terminal steps; pos0, target (B, 1, 2), pos1 (B, A, 2).
        Without shaping (k = 0) the terms as they are, and nothing enters the graph."""
        if self.world.progress_reward == 0:
            return terms
        wx, wy = target[..., 0], target[..., 1]
        gained = norm2(pos0[..., 0] - wx, pos0[..., 1] - wy) - norm2(pos1[..., 0] - wx, pos1[..., 1] - wy)
        progress = th.where(terms.success | terms.collision, 0.0, f64(self.world.progress_reward) * gained)
        return terms._replace(reward=terms.reward + progress)

    # ------------------------------------------------------------------ the warehouse
    def static_world(self, terms: Terms, pos0, pos1, radius, obstacles, obstacles_mask, waypoints) -> tuple[Terms, th.Tensor]:
        """The obstacle collision, the route progress and the moved waypoints (B, A, K, 2) of the warehouse."""
        world = self.world
        batch = pos0.shape[0]
        seg = obstacles.reshape(batch, 1, -1, SEGMENT_DIM)  # (B, 1, S, 4)
        p0, p1 = pos0[..., None, :], pos1[..., None, :]  # (B, 1, 1, 2), (B, A, 1, 2)
        dist = segment_to_segment(p0[..., 0], p0[..., 1], p1[..., 0], p1[..., 1],
                                  seg[..., 0], seg[..., 1], seg[..., 2], seg[..., 3])  # (B, A, S)
        clearance = th.where(obstacles_mask.reshape(batch, 1, -1) > 0.5, dist, math.inf).amin(dim=-1)
        terms = _collide(terms, clearance < radius, world.obstacle_collision_penalty)
        route = waypoints.reshape(batch, 1, -1, 2)  # (B, 1, K, 2)
        terms = self.progress(terms, pos0, pos1, route[..., 0, :])
        out = route.expand(-1, pos1.shape[1], -1, -1)
        for _ in range(out.shape[-2] - 1):  # next_waypoints: drop each passed waypoint, never the goal
            first, goal = out[..., 0, :], out[..., -1, :]
            reached = (norm2(first[..., 0] - pos1[..., 0], first[..., 1] - pos1[..., 1]) < f64(world.waypoint_radius)) & \
                ((first[..., 0] != goal[..., 0]) | (first[..., 1] != goal[..., 1]))
            shifted = th.cat((out[..., 1:, :], out[..., -1:, :]), dim=-2)
            out = th.where(reached[..., None, None], shifted, out)
        return terms, out

    # ------------------------------------------------------------------ the stopping-distance check
    def braking(self, terms: Terms, pos1, heading1, vel1, goal, radius, hpos0, hpos1, hvel, human_radius, present,
                segments: list[th.Tensor] | None) -> Terms:
        """``PropagationModel(stopping_check=True)``: the robot braking from each action's new state at a_max
        (the stop command, :attr:`braking_steps` sub-steps, :func:`~sb3_crowdnav.apg_value.propagation.braking_path`)
        charged a collision where it comes within the radii sum of an observed person
        (:func:`~sb3_crowdnav.apg_value.propagation.braking_hits`; constant velocity from ``hpos1``, and with the
        cautious model also standing at ``hpos0``) or sweeps into an observed segment, unless every action of the
        observation collides or cannot brake. pos1, vel1 (B, A, 2); heading1 (B, A); goal (B, 1, 2); radius (B, 1);
        hpos0, hpos1, hvel (B, M, 2); human_radius (B, M); present (B, M); segments: obstacles, obstacles_mask."""
        zero, dt = f64(0.0), self.world.time_step
        path, pos, heading, vel = [pos1], pos1, heading1, vel1
        for _ in range(self.braking_steps):
            pos, heading, vel = self.move(pos, heading, goal, vel, zero, zero)
            path.append(pos)
        reach = (human_radius + radius)[:, None, :]  # (B, 1, M)
        seen = present[:, None, :]
        person = th.zeros_like(terms.collision)
        for k in range(self.braking_steps):
            step = path[k + 1] - path[k]  # a standing robot (a step below STANDING_STEP) is not charged
            moving = (step.square().sum(dim=-1) > STANDING_STEP ** 2)[..., None]  # (B, A, 1)
            r0, r1 = path[k][:, :, None, :], path[k + 1][:, :, None, :]  # (B, A, 1, 2)
            predictions = [(hpos1 + hvel * f64(k * dt), hpos1 + hvel * f64(k * dt + dt))]
            if self.cautious:  # or they stand where they are
                predictions.append((hpos0, hpos0))
            for h0, h1 in predictions:
                off0, off1 = r0 - h0[:, None], r1 - h1[:, None]  # (B, A, M, 2): the offsets from the people
                gap = closest_approach(off0[..., 0], off0[..., 1], off1[..., 0] - off0[..., 0],
                                       off1[..., 1] - off0[..., 1])
                person = person | ((gap < reach) & seen & moving).any(dim=-1)
        rack = th.zeros_like(person)
        if segments is not None:  # the path is straight: one swept disc from its start to its end
            obstacles, obstacles_mask = segments
            seg = obstacles.reshape(obstacles.shape[0], 1, -1, SEGMENT_DIM)  # (B, 1, S, 4)
            p0, p1 = path[0][..., None, :], path[-1][..., None, :]  # (B, A, 1, 2)
            dist = segment_to_segment(p0[..., 0], p0[..., 1], p1[..., 0], p1[..., 1],
                                      seg[..., 0], seg[..., 1], seg[..., 2], seg[..., 3])  # (B, A, S)
            mask = obstacles_mask.reshape(obstacles.shape[0], 1, -1) > 0.5
            rack = th.where(mask, dist, math.inf).amin(dim=-1) < radius
        # a filter, not a verdict: where every action collides or cannot brake, the lookahead chooses without it
        possible = ~(terms.collision | person | rack).all(dim=1, keepdim=True)  # (B, 1)
        terms = _collide(terms, person & possible & ~terms.success, self.world.reward.collision_penalty)
        return _collide(terms, rack & possible & ~terms.success, self.world.obstacle_collision_penalty or 0.0)

    # ------------------------------------------------------------------ everything
    def forward(self, observation: dict[str, th.Tensor]) -> Propagated:
        """The observations (float32 inputs, (B, n) per key) one Δt ahead under every action, with R(s, a)."""
        robot = observation["robot"].to(F64)
        batch = robot.shape[0]
        hist = self.schema.humans_view(observation["humans"].to(F64))  # (B, T, M, 5)
        present = observation["humans_mask"] > 0.5  # (B, M)
        pos0, goal, vel0 = robot[:, None, Robot.POS], robot[:, None, Robot.GOAL], robot[:, None, Robot.VEL]
        heading0, v_pref = robot[:, Robot.HEADING:Robot.HEADING + 1], robot[:, Robot.V_PREF]
        radius = robot[:, Robot.RADIUS:Robot.RADIUS + 1]  # (B, 1)
        speeds = v_pref[:, None] * self.speed_fractions  # (B, A)
        pos1, heading1, vel1 = self.move(pos0, heading0, goal, vel0, speeds)

        hpos0 = hist[:, -1, :, Human.POS]  # (B, M, 2)
        hpos1 = th.where(present[..., None], hpos0 + hist[:, -1, :, Human.VEL] * f64(self.world.time_step), 0.0)
        latest = hist[:, -1].clone()  # (B, M, 5): moved, velocity and radius kept
        latest[..., Human.POS] = hpos1
        new_hist = th.cat((hist[:, 1:], latest[:, None]), dim=1)  # (B, T, M, 5)
        dirs = walking_direction(new_hist[..., Human.VEL], hpos1, pos1) if self.world.reward.uses_social else None
        human_args = (latest[:, None, :, Human.RADIUS], present[:, None])
        start, end = hpos0[:, None], hpos1[:, None]
        terms = self.terms(pos0, pos1, heading0, heading1, goal, radius, start, end, dirs, *human_args)
        if self.cautious:  # worse_of: the pedestrians may also stand still
            still = self.terms(pos0, pos1, heading0, heading1, goal, radius, start, start, dirs, *human_args)
            worse = still.reward < terms.reward  # flags by logic: ONNX Runtime has no Where of booleans
            terms = Terms(th.where(worse, still.reward, terms.reward), (worse & still.success) | (~worse & terms.success),
                          (worse & still.collision) | (~worse & terms.collision))

        n_actions = speeds.shape[1]
        propagated, segments = {}, None
        if not self.world.has_static_world:  # the open floor's goal-progress shaping
            terms = self.progress(terms, pos0, pos1, goal)
        elif self.schema.max_obstacles and self.schema.num_waypoints:
            segments = [observation[key] for key in OBSTACLE_KEYS]  # obstacles, obstacles_mask
            terms, route = self.static_world(terms, pos0, pos1, radius, *segments, observation[WAYPOINT_KEY])
            propagated = {key: _per_action(observation[key], n_actions) for key in OBSTACLE_KEYS}
            propagated[WAYPOINT_KEY] = route.reshape(batch * n_actions, -1).float()
        if self.braking_steps is not None:  # after the step's own terms: the braking path and the people over it
            terms = self.braking(terms, pos1, heading1, vel1, goal, radius, hpos0, hpos1, hist[:, -1, :, Human.VEL],
                                 latest[..., Human.RADIUS], present, segments)
        new_robot = robot[:, None, :].expand(-1, n_actions, -1).clone()  # (B, A, 9)
        new_robot[..., Robot.POS] = pos1
        new_robot[..., Robot.VEL] = vel1
        new_robot[..., Robot.HEADING] = heading1
        mask = present.to(th.float32)
        crowd = (new_robot.reshape(batch * n_actions, ROBOT_DIM).float(),
                 _per_action(self.schema.flatten_humans(new_hist).float(), n_actions), _per_action(mask, n_actions))
        obs = {**dict(zip(OBS_KEYS, crowd, strict=True)), **propagated}
        discount = th.pow(f64(self.gamma), f64(self.world.time_step) * v_pref)
        return Propagated(obs, terms.reward, terms.success | terms.collision, discount)


def _collide(terms: Terms, hit: th.Tensor, penalty: float) -> Terms:
    """:func:`~sb3_crowdnav.sim.rewards.with_obstacle_collision`: a collision of reward ``penalty`` where ``hit``
    (B, A), unless the step already collided with a person, whose penalty stands; it ends the episode, not in success."""
    hit = hit & ~terms.collision
    return Terms(th.where(hit, f64(penalty), terms.reward), terms.success & ~hit, terms.collision | hit)


def _where(condition: th.Tensor, value: float) -> th.Tensor:
    """``value`` where ``condition``, else 0, in float64 (``th.where`` of two Python numbers would be float32)."""
    return th.where(condition, f64(value), f64(0.0))


def _per_action(x: th.Tensor, n_actions: int) -> th.Tensor:
    """(B, F) -> (B * A, F), row b * A + a = x[b] (``np.repeat(x, A, axis=0)``)."""
    return x[:, None, :].expand(-1, n_actions, -1).reshape(-1, x.shape[-1])


__all__ = ["GraphPropagation", "Propagated", "atan2", "braking_steps", "f64", "wrap"]
