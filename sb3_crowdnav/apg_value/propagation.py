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

from dataclasses import dataclass, field

import numpy as np

from sb3_crowdnav.sim.actions import apply_action
from sb3_crowdnav.sim.geometry import SEGMENT_DIM, swept_clearance
from sb3_crowdnav.sim.observation import HUMAN_DIM, Human, ObservationSchema, Robot
from sb3_crowdnav.sim.rewards import (
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
    """

    PEDESTRIAN_MODELS = ("constant_velocity", "cautious")

    def __init__(self, world: World, history_length: int, gamma: float,
                 pedestrian_model: str = "constant_velocity") -> None:
        if not isinstance(world, World):
            raise TypeError(f"world must be a World, got {type(world).__name__}")
        if pedestrian_model not in self.PEDESTRIAN_MODELS:
            raise ValueError(f"pedestrian_model must be one of {self.PEDESTRIAN_MODELS}, got {pedestrian_model!r}")
        self.pedestrian_model = pedestrian_model
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
