"""The state-propagation model of the one-step lookahead (paper Eq. 1-2).

From a batch of observations and all the world's actions (80, or 81 with a stop): the observations one Δt ahead
(robot by the env's own kinematics, limits and action table, pedestrians at constant velocity, history window
shifted) and the reward R(s, a) with its terminal flags. Everything it shares with the env
comes from one :class:`~sb3_crowdnav.sim.world.World`.

Decision: the propagation runs in numpy and calls the *same* functions as the env
(:func:`~sb3_crowdnav.sim.actions.apply_action`, :func:`~sb3_crowdnav.sim.rewards.compute_reward`,
:func:`~sb3_crowdnav.sim.rewards.walking_direction`), so the robot part and the reward equal the
env's by construction rather than by a second implementation kept in sync. Only the value
network runs in torch, on the (B x 80) propagated states in one forward pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sb3_crowdnav.sim.actions import apply_action
from sb3_crowdnav.sim.geometry import SEGMENT_DIM, swept_clearance
from sb3_crowdnav.sim.observation import HUMAN_DIM, Human, ObservationSchema, Robot
from sb3_crowdnav.sim.rewards import (
    STANDING_STEP,
    RewardTerms,
    closest_approach,
    compute_reward,
    walking_direction,
    with_obstacle_collision,
    with_route_progress,
    worse_of,
)
from sb3_crowdnav.sim.warehouse.simulator import next_waypoints
from sb3_crowdnav.sim.world import World


@dataclass(frozen=True)
class Propagated:
    """Result for B observations x A actions (the world's ``n_actions``)."""

    robot: np.ndarray  # (B, A, 9)
    humans: np.ndarray  # (B, T*M*5) -- the same for every action (constant-velocity pedestrians)
    humans_mask: np.ndarray  # (B, M)
    reward: np.ndarray  # (B, A)
    terminal: np.ndarray  # (B, A) collision or success
    discount: np.ndarray  # (B,) γ^(Δt·v_pref)
    static: dict[str, np.ndarray] = field(default_factory=dict)  # the warehouse's keys, per action (B, A, ...)


def robot_moves(world: World, robot: np.ndarray,
                table: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The robot's position [m], heading [rad] and velocity [m/s] one Δt ahead under each of the world's actions, by
    the env's own kinematics and limits (:func:`~sb3_crowdnav.sim.actions.apply_action`).

    :param robot: (B, 9) robot rows of observations
    :param table: ``world.action_table(1.0)`` when the caller keeps it (it is recomputed otherwise)
    :return: (B, A, 2), (B, A), (B, A, 2)
    """
    robot = np.asarray(robot, dtype=np.float64)
    speed_fractions, directions = world.action_table(1.0) if table is None else table
    speeds = robot[:, Robot.V_PREF, None] * speed_fractions[None, :]  # (B, A)
    return apply_action(robot[:, None, Robot.POS], robot[:, None, Robot.HEADING], robot[:, None, Robot.GOAL], speeds,
                        directions[None, :], world.kinematics, world.time_step, robot[:, None, Robot.VEL],
                        world.max_acceleration, world.max_turn_rate)


def check_stopping_check(stopping_check: bool, world: World) -> None:
    """Refuse ``stopping_check`` when it is not a bool (TypeError) or is on in a world without ``max_acceleration``
    (ValueError: the robot stops at once there, and the check would have nothing to follow)."""
    if not isinstance(stopping_check, (bool, np.bool_)):
        raise TypeError(f"stopping_check must be a bool, got {type(stopping_check).__name__}")
    if stopping_check and world.max_acceleration is None:
        raise ValueError("stopping_check=True needs a world with max_acceleration (a robot without an acceleration "
                         "limit stops within one step; the check would have no effect)")


def segments_of(static: dict[str, np.ndarray], b: int) -> np.ndarray:
    """The observation's segments (B, 1, S, 4) [m] (one row per batch entry, broadcast over the actions)."""
    return np.asarray(static["obstacles"], dtype=np.float64).reshape(b, 1, -1, SEGMENT_DIM)


def swept_hits(pos0: np.ndarray, new_pos: np.ndarray, radius: np.ndarray, static: dict[str, np.ndarray]) -> np.ndarray:
    """Whether the robot's disc, swept from ``pos0`` to each ``new_pos``, touches an observed rack or wall segment:
    the env's rule (:func:`~sb3_crowdnav.sim.geometry.swept_clearance` below the robot's radius) on the segments of
    the observation.

    :param pos0: (B, 2) [m]; :param new_pos: (B, A, 2) [m]; :param radius: (B,) [m]
    :param static: the observation's ``obstacles`` (B, S*4) and ``obstacles_mask`` (B, S)
    :return: (B, A) bool
    """
    b, n_actions = new_pos.shape[:2]
    segments = np.asarray(static["obstacles"], dtype=np.float64).reshape(b, 1, -1, SEGMENT_DIM)
    seg_mask = np.asarray(static["obstacles_mask"]).reshape(b, 1, -1)
    start = np.broadcast_to(np.asarray(pos0, dtype=np.float64)[:, None, :], (b, n_actions, 2))
    return swept_clearance(start, new_pos, segments, seg_mask) < np.asarray(radius, dtype=np.float64)[:, None]


def wall_hits(world: World, robot: np.ndarray, static: dict[str, np.ndarray]) -> np.ndarray:
    """(B, A) bool: the lookahead's prediction that each action makes the robot touch a rack or a wall during the
    next step (:func:`robot_moves`, then :func:`swept_hits`), from observations of a world of static obstacles."""
    if not world.has_static_world:
        raise ValueError("wall_hits needs a world of static obstacles (the warehouse); this world has none")
    robot = np.asarray(robot, dtype=np.float64)
    new_pos = robot_moves(world, robot)[0]
    return swept_hits(robot[:, Robot.POS], new_pos, robot[:, Robot.RADIUS], static)


def braking_path(world: World, position: np.ndarray, heading: np.ndarray, velocity: np.ndarray,
                 goal: np.ndarray) -> np.ndarray:
    """The robot braking to a stand from ``position`` with ``heading`` and ``velocity``: the env's own kinematics and
    limits (:func:`~sb3_crowdnav.sim.actions.apply_action`) under the stop command (speed 0, direction 0) repeated,
    one Δt per sub-step, until the fastest robot of the batch stands. The speed falls by a_max·Δt a step along the
    velocity's direction (no turn), so each path is a straight segment; a robot that already stands stays put.

    :param position: (..., 2) [m]; :param heading: (...) [rad]; :param velocity: (..., 2) [m/s]; :param goal: (..., 2)
    :return: (n + 1, ..., 2) the positions [m] at the sub-steps' ends, the first ``position`` (n = ceil(the largest
        speed / (a_max·Δt)); 0 when every robot stands)
    """
    if world.max_acceleration is None:
        raise ValueError("braking_path needs a world with max_acceleration (a robot without a limit stops at once)")
    position, velocity = np.asarray(position, dtype=np.float64), np.asarray(velocity, dtype=np.float64)
    fastest = float(np.linalg.norm(velocity, axis=-1).max(initial=0.0))
    n = math.ceil(fastest / (world.max_acceleration * world.time_step) - 1e-9)
    path = [position]
    for _ in range(max(n, 0)):
        position, heading, velocity = apply_action(position, heading, goal, 0.0, 0.0, world.kinematics,
                                                   world.time_step, velocity, world.max_acceleration,
                                                   world.max_turn_rate)
        path.append(position)
    return np.stack(path)


def braking_hits(path: np.ndarray, radius: np.ndarray, human_starts: list[np.ndarray], human_vel: list[np.ndarray],
                 human_radius: np.ndarray, mask: np.ndarray, time_step: float) -> np.ndarray:
    """Whether the robot braking along ``path`` (:func:`braking_path`) comes within the radii sum of an observed
    person: per sub-step the closest approach of the two straight motions (the reward's collision rule,
    :func:`~sb3_crowdnav.sim.rewards.closest_approach`), only in the sub-steps that move the robot by more than
    :data:`~sb3_crowdnav.sim.rewards.STANDING_STEP`.

    :param path: (n + 1, B, A, 2) [m]; :param radius: (B,) the robot's [m]
    :param human_starts: the people's positions (B, M, 2) [m] at the braking's start, one array per prediction
    :param human_vel: their velocities (B, M, 2) [m/s] over the braking, one array per prediction (zero: standing)
    :param human_radius: (B, M) [m]; :param mask: (B, M) bool, observed; :param time_step: Δt [s]
    :return: (B, A) bool
    """
    if path.shape[0] < 2:  # every robot stands
        return np.zeros(path.shape[1:3], dtype=bool)
    steps = np.arange(path.shape[0] - 1)[:, None, None, None, None] * time_step  # (n, 1, 1, 1, 1) [s]
    starts, velocities = np.stack(human_starts), np.stack(human_vel)  # (P, B, M, 2) for P predictions
    h0, h1 = starts + velocities * steps, starts + velocities * (steps + time_step)  # (n, P, B, M, 2)
    # every sub-step, prediction, action and person in one compiled call, on the robot's offsets from the people
    # (the same closest approach; full arrays pass without the row copies a broadcast would cost): (n, P, B, A, M)
    off0 = path[:-1, None, :, :, None] - h0[:, :, :, None]  # (n, P, B, A, M, 2)
    off1 = path[1:, None, :, :, None] - h1[:, :, :, None]
    origin = np.zeros_like(off0)
    gap = closest_approach(off0, off1, origin, origin)
    moving = np.sum((path[1:] - path[:-1]) ** 2, axis=-1) > STANDING_STEP ** 2  # (n, B, A): standing is not charged
    near = gap < (human_radius + np.asarray(radius, dtype=np.float64)[:, None])[:, None]  # (n, P, B, A, M)
    near &= (np.asarray(mask, dtype=bool)[:, None, :] & moving[:, None, :, :, None])
    return near.any(axis=(0, 1, 4))


def with_braking_collision(terms: RewardTerms, hit: np.ndarray, penalty: float) -> RewardTerms:
    """``terms`` with the actions whose braking path collides (``hit`` (B, A)) charged a collision of ``penalty``,
    terminal, exactly like a collision within the step (:func:`~sb3_crowdnav.sim.rewards.with_obstacle_collision`);
    an action that reaches the goal within the step ends the episode there and is not charged."""
    return with_obstacle_collision(terms, np.asarray(hit, dtype=bool) & ~np.asarray(terms.success, dtype=bool), penalty)


class PropagationModel:
    """Propagates observations of a crowd env under every action.

    :param world: the env's :class:`~sb3_crowdnav.sim.world.World` (time step, kinematics, action table, reward, the
        progress shaping (on the goal, or on the route's current waypoint) and, in a world of static obstacles, their
        collision penalty and the waypoint rule)
    :param history_length: T
    :param gamma: discount per second at v_pref = 1 (the lookahead discount is γ^(Δt·v_pref))
    :param pedestrian_model: how R(s, a) predicts the pedestrians over the step: ``"constant_velocity"`` (the
        paper) or ``"cautious"``, the worse for the robot of constant velocity and standing still (an action is
        charged a collision when either motion collides). The propagated state V sees is constant velocity in both.
    :param stopping_check: also charge an action a collision (the collision penalty, terminal) when the robot,
        braking from its new velocity at ``world.max_acceleration`` along its new heading until it stands
        (:func:`braking_path`, the env's kinematics one Δt a sub-step), would sweep into an observed rack or wall
        segment or come within the radii sum of an observed person (constant velocity over the braking time; with
        ``"cautious"`` also standing still). Default False (the paper's lookahead); refused for a world without an
        acceleration limit, where it could not act.
    """

    PEDESTRIAN_MODELS = ("constant_velocity", "cautious")

    def __init__(self, world: World, history_length: int, gamma: float,
                 pedestrian_model: str = "constant_velocity", stopping_check: bool = False) -> None:
        if not isinstance(world, World):
            raise TypeError(f"world must be a World, got {type(world).__name__}")
        if pedestrian_model not in self.PEDESTRIAN_MODELS:
            raise ValueError(f"pedestrian_model must be one of {self.PEDESTRIAN_MODELS}, got {pedestrian_model!r}")
        check_stopping_check(stopping_check, world)
        self.pedestrian_model = pedestrian_model
        self.stopping_check = bool(stopping_check)
        self.world = world
        self.time_step = world.time_step
        self.reward = world.reward
        self.history_length = history_length
        self.gamma = gamma
        speeds, self.directions = world.action_table(1.0)
        self.speed_fractions = speeds  # speeds at v_pref = 1, scaled per state

    def __call__(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray,
                 static: dict[str, np.ndarray] | None = None) -> Propagated:
        """:param robot: (B, 9); :param humans: (B, T*M*5); :param mask: (B, M); :param static: the warehouse's
        ``obstacles`` (B, S*4), ``obstacles_mask`` (B, S) and ``waypoints`` (B, K*2), when the observation has them."""
        robot = np.asarray(robot, dtype=np.float64)
        humans = np.asarray(humans, dtype=np.float64)
        mask = np.asarray(mask) > 0.5
        b, m = mask.shape
        if robot.ndim != 2 or robot.shape[0] != b or humans.shape != (b, self.history_length * m * HUMAN_DIM):
            raise ValueError(
                f"expected robot (B, 9), humans (B, {self.history_length}*M*{HUMAN_DIM}), mask (B, M); got "
                f"{robot.shape}, {humans.shape}, {mask.shape}"
            )
        schema = ObservationSchema(self.history_length, m)
        hist = schema.humans_view(humans)  # (B, T, M, 5)
        pos0, goal = robot[:, Robot.POS], robot[:, Robot.GOAL]
        heading0, v_pref, radius = robot[:, Robot.HEADING], robot[:, Robot.V_PREF], robot[:, Robot.RADIUS]

        table = (self.speed_fractions, self.directions)
        new_pos, new_heading, vel = robot_moves(self.world, robot, table)  # (B, A, 2), (B, A), (B, A, 2)

        latest = hist[:, -1].copy()  # (B, M, 5)
        hpos0 = hist[:, -1, :, Human.POS]
        latest[:, :, Human.POS] = hpos0 + hist[:, -1, :, Human.VEL] * self.time_step
        latest[:, :, Human.POS] = np.where(mask[..., None], latest[:, :, Human.POS], 0.0)
        new_hist = np.concatenate([hist[:, 1:], latest[:, None]], axis=1)  # (B, T, M, 5)

        hpos1 = latest[:, :, Human.POS]
        dirs = None  # walking directions only matter to the comfort ellipses of the social term
        if self.reward.uses_social:
            dirs = walking_direction(new_hist[:, None, :, :, Human.VEL], hpos1[:, None], new_pos)  # (B, A, M, 2)
        n_actions = self.world.n_actions
        full = (b, n_actions)
        robot_args = (np.broadcast_to(pos0[:, None, :], (*full, 2)), new_pos, np.broadcast_to(heading0[:, None], full),
                      new_heading, np.broadcast_to(goal[:, None, :], (*full, 2)),
                      np.broadcast_to(radius[:, None], full))
        start = np.broadcast_to(hpos0[:, None], (*full, m, 2))
        human_args = (np.broadcast_to(latest[:, None, :, Human.RADIUS], (*full, m)),
                      np.broadcast_to(mask[:, None], (*full, m)))
        terms = compute_reward(self.reward, self.time_step, *robot_args, start,
                               np.broadcast_to(hpos1[:, None], (*full, m, 2)), dirs, *human_args)
        if self.pedestrian_model == "cautious":  # and if they stand still instead (a picker stopping at a shelf)
            terms = worse_of(terms, compute_reward(self.reward, self.time_step, *robot_args, start, start, dirs,
                                                   *human_args))
        propagated_static: dict[str, np.ndarray] = {}
        if not self.world.has_static_world:  # the open floor's goal-progress shaping (unchanged when it has none)
            terms = with_route_progress(terms, np.broadcast_to(pos0[:, None, :], (*full, 2)), new_pos, goal[:, None, :],
                                        self.world.progress_reward)
        elif static:  # the same segment geometry as the env, the same waypoint rule, the route's progress shaping
            seg_mask = np.asarray(static["obstacles_mask"]).reshape(b, 1, -1)
            hit = swept_hits(pos0, new_pos, radius, static)
            terms = with_obstacle_collision(terms, hit, self.world.obstacle_collision_penalty)
            waypoints = np.asarray(static["waypoints"], dtype=np.float64).reshape(b, 1, -1, 2)
            terms = with_route_progress(terms, np.broadcast_to(pos0[:, None, :], (*full, 2)), new_pos,
                                        waypoints[:, :, 0], self.world.progress_reward)
            moved = next_waypoints(np.broadcast_to(waypoints, (*full, waypoints.shape[2], 2)), new_pos,
                                   self.world.waypoint_radius)
            propagated_static = {"obstacles": np.asarray(static["obstacles"]), "obstacles_mask": seg_mask[:, 0],
                                 "waypoints": moved.reshape(b, n_actions, -1)}
        if self.stopping_check:  # after the step's own terms: the braking path and the people over its time
            path = braking_path(self.world, new_pos, new_heading, vel, goal[:, None, :])  # (n + 1, B, A, 2)
            starts, velocities = [hpos1], [hist[:, -1, :, Human.VEL]]
            if self.pedestrian_model == "cautious":  # or they stand where they are
                starts.append(hpos0)
                velocities.append(np.zeros_like(hpos0))
            person_hit = braking_hits(path, radius, starts, velocities, latest[:, :, Human.RADIUS], mask,
                                      self.time_step)
            rack_hit = np.zeros_like(person_hit)
            if self.world.has_static_world and static:  # the path is straight: one swept disc from start to end
                seg_mask = np.asarray(static["obstacles_mask"]).reshape(b, 1, -1)
                rack_hit = swept_clearance(path[0], path[-1], segments_of(static, b), seg_mask) < radius[:, None]
            # a filter, not a verdict: where every action collides within the step or cannot brake, the robot is in
            # an inevitable state by this (conservative) test, and the lookahead chooses as it would without it
            hopeless = np.all(terms.collision | person_hit | rack_hit, axis=1, keepdims=True)  # (B, 1)
            terms = with_braking_collision(terms, person_hit & ~hopeless, self.reward.collision_penalty)
            terms = with_braking_collision(terms, rack_hit & ~hopeless, self.world.obstacle_collision_penalty or 0.0)
        new_robot = np.repeat(robot[:, None, :], n_actions, axis=1)
        new_robot[:, :, Robot.POS] = new_pos
        new_robot[:, :, Robot.VEL] = vel
        new_robot[:, :, Robot.HEADING] = new_heading
        return Propagated(
            robot=new_robot,
            humans=schema.flatten_humans(new_hist),
            humans_mask=mask.astype(np.float32),
            reward=terms.reward,
            terminal=terms.success | terms.collision,
            discount=self.gamma ** (self.time_step * v_pref),
            static=propagated_static,
        )
