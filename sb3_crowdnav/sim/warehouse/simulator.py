"""``WarehouseSimulator``: the robot, its route and the pickers in a warehouse layout; no RL API."""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import LineString, Point

from sb3_crowdnav.sim.actions import N_ACTIONS, _apply_action_scalar, action_table
from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
from sb3_crowdnav.sim.geometry import nearest_segments, polygon_segments, swept_clearance
from sb3_crowdnav.sim.observation import HUMAN_DIM, ROBOT_DIM, Human, Robot
from sb3_crowdnav.sim.rewards import RewardTerms, compute_reward, walking_direction, with_obstacle_collision
from sb3_crowdnav.sim.warehouse.config import WarehouseConfig, check_feasible
from sb3_crowdnav.sim.warehouse.layout import Roadmap, WarehouseLayout, generate_layout
from sb3_crowdnav.sim.warehouse.pickers import PickerCrowd, pick_slots

ROUTE_CLEARANCE = 0.1  # [m] the robot's route keeps this much beyond its radius from racks and walls
PICKER_CLEARANCE = 0.02  # [m] likewise for the pickers' routes
START_GAP = 1.0  # [m] no picker starts, or picks, this close (surface to surface) to the robot's start or goal
MAX_TRIES = 100


def next_waypoints(waypoints: np.ndarray, position: np.ndarray, radius: float) -> np.ndarray:
    """The observed waypoints (..., K, 2) after the robot moved to ``position`` (..., 2): drop leading ones within
    ``radius`` (never the last, the goal) and repeat the last. The env's rule and the lookahead's."""
    out = np.array(waypoints, dtype=np.float64, copy=True)
    for _ in range(out.shape[-2] - 1):
        reached = (np.linalg.norm(out[..., 0, :] - position, axis=-1) < radius) & \
                  np.any(out[..., 0, :] != out[..., -1, :], axis=-1)
        if not reached.any():
            break
        shifted = np.concatenate([out[..., 1:, :], out[..., -1:, :]], axis=-2)
        out = np.where(reached[..., None, None], shifted, out)
    return out


class WarehouseSimulator:
    """State of one warehouse episode and its dynamics (see ``CrowdNavWarehouse-v0``).

    Observation-form state as :class:`~sb3_crowdnav.sim.simulator.CrowdSimulator` (``robot``, ``history``,
    ``mask``), plus the layout, the robot's route and the observed obstacle segments and waypoints.
    """

    def __init__(self, scene: SceneConfig, reward: RewardConfig, config: WarehouseConfig) -> None:
        check_feasible(scene, config, pick_slots)
        self.scene, self.reward_cfg, self.config = scene, reward, config
        self.speeds, self.directions = action_table(scene.robot_v_pref, scene.rotation_range)
        self.robot = np.zeros(ROBOT_DIM)
        self.history = np.zeros((scene.history_length, scene.max_humans, HUMAN_DIM))
        self.mask = np.zeros(scene.max_humans, dtype=bool)
        self.num_humans, self.steps, self.max_steps = 0, 0, 1
        self.layout: WarehouseLayout | None = config.layout
        self._fixed: tuple[Roadmap, Roadmap, np.ndarray] | None = None
        self.route = np.zeros((1, 2))
        self.route_index = 0
        self.route_length = 0.0
        self.replans = 0

    # ------------------------------------------------------------------ reset
    def _maps(self, layout: WarehouseLayout) -> tuple[Roadmap, Roadmap, np.ndarray]:
        """The robot's roadmap, the pickers' roadmap and the pick slots of ``layout`` (cached for a fixed layout)."""
        if self.config.layout is not None and self._fixed is not None:
            return self._fixed
        s = self.scene
        maps = (Roadmap(layout, s.robot_radius + ROUTE_CLEARANCE), Roadmap(layout, s.human_radius + PICKER_CLEARANCE),
                pick_slots(layout, s))
        if self.config.layout is not None:
            self._fixed = maps
        return maps

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode drawn from ``rng``: layout, robot start, goal and route, pickers."""
        cfg, s = self.config, self.scene
        self.layout = cfg.layout if cfg.layout is not None else generate_layout(rng, cfg.layout_ranges)
        self.robot_map, picker_map, slots = self._maps(self.layout)
        self.segments = np.concatenate([polygon_segments(list(self.layout.racks)),
                                        polygon_segments([np.asarray(self.layout.hall.exterior.coords)[:-1]])])
        self._free = self.robot_map.free
        shapely.prepare(self._free)
        start, goal = self._stations(rng)
        self.route = self.robot_map.route(start, goal)
        self.route_index, self.replans = 1, 0
        self.route_length = self.robot_map.route_length(self.route)
        self.max_steps = math.ceil((cfg.time_limit_slack + cfg.time_limit_factor * self.route_length / s.robot_v_pref)
                                   / s.time_step)
        first = self.route[1]
        self.robot = np.zeros(ROBOT_DIM)
        self.robot[Robot.POS], self.robot[Robot.GOAL] = start, goal
        self.robot[Robot.RADIUS], self.robot[Robot.V_PREF] = s.robot_radius, s.robot_v_pref
        self.robot[Robot.HEADING] = math.atan2(first[1] - start[1], first[0] - start[0])

        lo, hi = s.humans_range
        n = int(rng.integers(lo, hi + 1))
        keep = (np.linalg.norm(slots - start, axis=1) >= s.robot_radius + s.human_radius + START_GAP) & \
               (np.linalg.norm(slots - goal, axis=1) >= s.robot_radius + s.human_radius + START_GAP)
        usable = slots[keep]
        starts = self._spread(rng, usable, n, 2 * s.human_radius + 0.2)
        self.num_humans = len(starts)
        self.pickers = PickerCrowd(s, self.layout, usable, picker_map, starts, rng, cfg.dwell_time) if n else None
        current = np.zeros((s.max_humans, HUMAN_DIM))
        current[: self.num_humans, Human.POS] = usable[starts] if n else np.zeros((0, 2))
        current[: self.num_humans, Human.RADIUS] = s.human_radius
        self.history = np.repeat(current[None], s.history_length, axis=0)
        self.mask = np.zeros(s.max_humans, dtype=bool)
        self.mask[: self.num_humans] = True
        self.steps = 0

    def _stations(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Start and goal: free points (uniform) at least ``min_route_distance`` apart."""
        for _ in range(MAX_TRIES):
            start = self.robot_map.sample_free(rng)
            for _ in range(MAX_TRIES):
                goal = self.robot_map.sample_free(rng)
                if np.linalg.norm(goal - start) >= self.config.min_route_distance:
                    return start, goal
        raise RuntimeError("no start and goal min_route_distance apart (check_feasible should have refused this)")

    @staticmethod
    def _spread(rng: np.random.Generator, slots: np.ndarray, n: int, spacing: float) -> np.ndarray:
        """``n`` slot indices, pairwise at least ``spacing`` apart, in random order."""
        chosen: list[int] = []
        for i in rng.permutation(len(slots)) if n else ():
            if all(np.hypot(*(slots[i] - slots[j])) >= spacing for j in chosen):
                chosen.append(int(i))
                if len(chosen) == n:
                    break
        if len(chosen) < n:
            raise RuntimeError(f"only {len(chosen)} of {n} pickers fit (check_feasible should have refused this)")
        return np.asarray(chosen, dtype=np.int64)

    # ------------------------------------------------------------------ observation
    def observed_obstacles(self) -> tuple[np.ndarray, np.ndarray]:
        """The ``max_obstacles`` segments nearest the robot within ``sensor_range``: (M, 4), mask (M,)."""
        return nearest_segments(self.robot[Robot.POS], self.segments, self.config.max_obstacles,
                                self.config.sensor_range)

    def observed_waypoints(self) -> np.ndarray:
        """The current waypoint and the next ones, (K, 2), the goal repeated at the end."""
        k = self.config.num_waypoints
        ahead = self.route[self.route_index : self.route_index + k]
        return np.concatenate([ahead, np.repeat(self.route[-1:], k - len(ahead), axis=0)])

    # ------------------------------------------------------------------ step
    def _advance_route(self) -> None:
        """Pass reached waypoints (:func:`next_waypoints`' rule); plan again when the route was lost."""
        pos = self.robot[Robot.POS]
        radius, last = self.config.waypoint_radius, len(self.route) - 1
        while self.route_index < last and np.linalg.norm(self.route[self.route_index] - pos) < radius:
            self.route_index += 1
        current = self.route[self.route_index]
        off_route = LineString(self.route[self.route_index - 1 : self.route_index + 1]).distance(Point(pos)) \
            > self.config.replan_distance
        if off_route or not self._free.contains(LineString([pos, current])):
            if self._free.contains(Point(pos)):
                self.route = self.robot_map.route(pos, self.route[-1])
                self.route_index, self.replans = 1, self.replans + 1

    def step(self, action: int) -> tuple[RewardTerms, bool]:
        """Apply ``action`` (0..79), move the pickers; the reward terms and whether the robot hit an obstacle."""
        s, n = self.scene, self.num_humans
        if not (0 <= action < N_ACTIONS):
            raise ValueError(f"action must be in [0, {N_ACTIONS}), got {action!r}")
        robot, hist = self.robot, self.history
        r = robot.tolist()
        (px, py), (gx, gy), heading0 = r[Robot.POS], r[Robot.GOAL], r[Robot.HEADING]
        x, y, heading, vx, vy = _apply_action_scalar(px, py, heading0, gx, gy, float(self.speeds[action]),
                                                     float(self.directions[action]), s.kinematics, s.time_step)
        human_pos0 = hist[-1, :n, Human.POS].copy()
        if n:
            new_pos, new_vel = self.pickers.step(human_pos0)
        hist[:-1] = hist[1:]
        if n:
            hist[-1, :n, Human.POS], hist[-1, :n, Human.VEL] = new_pos, new_vel
        robot[Robot.POS], robot[Robot.VEL], robot[Robot.HEADING] = (x, y), (vx, vy), heading
        self.steps += 1
        pos0, pos1 = np.array([px, py]), robot[Robot.POS].copy()
        directions = walking_direction(hist[:, :n, Human.VEL], hist[-1, :n, Human.POS], pos1)
        terms = compute_reward(self.reward_cfg, s.time_step, pos0, pos1, np.float64(heading0), np.float64(heading),
                               robot[Robot.GOAL], np.float64(s.robot_radius), human_pos0, hist[-1, :n, Human.POS],
                               directions, hist[-1, :n, Human.RADIUS], self.mask[:n])
        hit = bool(swept_clearance(pos0, pos1, self.segments, np.ones(len(self.segments))) < s.robot_radius)
        terms = with_obstacle_collision(terms, np.bool_(hit), self.config.obstacle_collision_penalty)
        if not (terms.collision or terms.success):
            self._advance_route()
        return terms, hit and not (terms.min_distance < 0)

    @property
    def time(self) -> float:
        return self.steps * self.scene.time_step

    @property
    def standing(self) -> np.ndarray:
        """(num_humans,) bool: pickers standing at a pick face."""
        return self.pickers.standing if self.pickers is not None else np.zeros(0, dtype=bool)
