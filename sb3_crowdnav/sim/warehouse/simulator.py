"""``WarehouseSimulator``: the robot, its route and the pickers in a warehouse layout; no RL API."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import LineString

from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
from sb3_crowdnav.sim.draws import uniform
from sb3_crowdnav.sim.geometry import SEGMENT_DIM
from sb3_crowdnav.sim.observation import HUMAN_DIM, ROBOT_DIM, Human, Robot
from sb3_crowdnav.sim.rewards import RewardTerms, with_obstacle_collision, with_route_progress
from sb3_crowdnav.sim.sensing import PeopleSensor, sensing_on
from sb3_crowdnav.sim.simulator import CrowdSimulator
from sb3_crowdnav.sim.warehouse import kernels
from sb3_crowdnav.sim.warehouse.config import WarehouseConfig, check_feasible, check_pickers
from sb3_crowdnav.sim.warehouse.layout import Roadmap, WarehouseLayout, generate_layout
from sb3_crowdnav.sim.warehouse.pickers import PICKER_CLEARANCE, PickerCrowd, PickSlots, pick_slots
from sb3_crowdnav.sim.warehouse.sight import RackSight

ROUTE_CLEARANCE = 0.1  # [m] the robot's route keeps this much beyond its radius from racks and walls
START_GAP = 1.0  # [m] no picker starts, or picks, this close (surface to surface) to the robot's start or goal
MAX_TRIES = 100
STATION_BATCH = 16  # points drawn at once for the robot's start and goal


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


class WarehouseSimulator(CrowdSimulator):
    """State of one warehouse episode and its dynamics (see ``CrowdNavWarehouse-v0``).

    A :class:`~sb3_crowdnav.sim.simulator.CrowdSimulator` (the same robot kinematics, reward, history and walking
    directions) whose pedestrians are :class:`PickerCrowd` pickers, plus the layout, the robot's route, the
    obstacle segments and the swept-disc collision with them.

    With ``scene.robot_visible`` (True, or a share of the pickers drawn per episode) the pickers who see the robot
    have it as one more agent of their model (they avoid it). An episode is
    truncated after ``time_limit_slack + time_limit_factor x`` its route's time at ``robot_v_pref``, or, with
    ``fixed_time_limit``, after ``scene.time_limit`` whatever the route.
    """

    def __init__(self, scene: SceneConfig, reward: RewardConfig, config: WarehouseConfig,
                 fixed_time_limit: bool = False) -> None:
        check_feasible(scene, config, pick_slots)
        check_pickers(scene)
        super().__init__(scene, reward)
        self.config = config
        self.fixed_time_limit = fixed_time_limit
        if sensing_on(scene, config.occlusion):  # the racks hide pickers (the occluder is set per layout by reset)
            self.sensor = PeopleSensor(scene)
        self.max_steps = 1  # set per episode by reset (by route), unless fixed_time_limit
        self.pickers: PickerCrowd | None = None
        self.segments = np.zeros((0, 4))
        self._segments_of: WarehouseLayout | None = None  # the layout whose segments are cached (see reset)
        self._seg_dist = np.zeros(0)  # distance from the robot's centre to every segment, kept current (_sense_obstacles)
        self._seg_order = np.zeros(0, dtype=np.int64)  # their order (nearest first, ties by index)
        self._observed = [np.zeros((config.max_obstacles, SEGMENT_DIM)), np.zeros(config.max_obstacles, dtype=bool)]
        self.hit_obstacle = False
        # [m] the smallest distance from the robot's disc to a rack or wall this episode (its steps swept: below 0 exactly
        # when the robot hit one); the start's at reset
        self.min_clearance = math.inf
        self.layout: WarehouseLayout | None = config.layout
        self._fixed: tuple[Roadmap, PickSlots] | None = None
        self.route = np.zeros((1, 2))
        self.route_index = 0
        self.route_length = 0.0
        self.replans = 0
        self._waypoints_of: tuple[np.ndarray | None, int, np.ndarray] = (None, 0, np.zeros((0, 2)))
        self._route_points: list[list[float]] = []  # self.route in floats, for the per-step checks

    # ------------------------------------------------------------------ reset
    def _maps(self, layout: WarehouseLayout) -> tuple[Roadmap, PickSlots]:
        """The robot's roadmap and the pick slots (with the pickers' roadmap and routes) of ``layout``; kept for a
        fixed layout, with the routes planned so far."""
        if self.config.layout is not None and self._fixed is not None:
            return self._fixed
        s = self.scene
        maps = (Roadmap(layout, s.robot_radius + ROUTE_CLEARANCE), PickSlots(layout, s, s.human_radius + PICKER_CLEARANCE))
        if self.config.layout is not None:
            self._fixed = maps
        return maps

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode drawn from ``rng``: layout, robot start, goal and route, pickers."""
        cfg, s = self.config, self.scene
        self.layout = cfg.layout if cfg.layout is not None else generate_layout(rng, cfg.layout_ranges)
        self.robot_map, picks = self._maps(self.layout)
        if self._segments_of is not self.layout:  # the segments and what the steps compute from them, per layout
            self._segments_of, self.segments = self.layout, self.layout.segments
            self._sight = None  # where the robot's centre may go (shapely), built when _in_sight needs it
            self._boxes = self.layout.boxes
            # filled by every sensing: the distance from the robot's centre to every segment, their order
            self._seg_dist, self._seg_order = np.zeros(len(self.segments)), np.zeros(len(self.segments), dtype=np.int64)
            if self.sensor is not None and cfg.occlusion:
                self.sensor.occluder = RackSight(self.layout)
        start, goal = self._stations(rng)
        self._set_route(self.robot_map.waypoints(start, goal))
        self.route_index, self.replans = 1, 0
        self.route_length = self.robot_map.route_length(self._route_points)
        if self.fixed_time_limit:
            self.max_steps = s.max_steps
        else:
            self.max_steps = math.ceil(
                (cfg.time_limit_slack + cfg.time_limit_factor * self.route_length / s.robot_v_pref) / s.time_step)
        first = self.route[1]
        self.robot = np.zeros(ROBOT_DIM)
        self.robot[Robot.POS], self.robot[Robot.GOAL] = start, goal
        self.robot[Robot.RADIUS], self.robot[Robot.V_PREF] = s.robot_radius, s.robot_v_pref
        self.robot[Robot.HEADING] = math.atan2(first[1] - start[1], first[0] - start[0])

        lo, hi = s.humans_range
        n = int(rng.integers(lo, hi + 1))
        slots, gap = picks.points, s.robot_radius + s.human_radius + START_GAP
        usable = kernels.far_from_both(slots, start[0], start[1], goal[0], goal[1], gap)  # np.hypot of each to both
        starts = self._spread(rng, slots[usable], n, 2 * s.human_radius + 0.2)
        self.num_humans = len(starts)
        # at rest, as on the open floor; a share is drawn per picker by PickerCrowd, after its other draws
        robot = (start, np.zeros(2), s.robot_radius) if s.robot_visible else None
        self.pickers = PickerCrowd(s, picks, usable, starts, rng, cfg.dwell_time, robot, self.crowd) if n else None
        current = np.zeros((s.max_humans, HUMAN_DIM))
        current[: self.num_humans, Human.POS] = slots[usable[starts]] if n else np.zeros((0, 2))
        current[: self.num_humans, Human.RADIUS] = s.human_radius
        self.history = current[None].repeat(s.history_length, axis=0)
        self.mask = np.zeros(s.max_humans, dtype=bool)
        self.mask[: self.num_humans] = True
        self.human_goals = np.full((self.num_humans, 2), np.nan)  # pickers have no fixed goal (figures draw none)
        self._forget_walks(self.num_humans)
        self.steps = 0
        self._sense_obstacles(*start.tolist())
        self.min_clearance = float(self._seg_dist.min()) - s.robot_radius if len(self._seg_dist) else math.inf
        if self.sensor is not None:
            self._sense_people(rng)

    def _stations(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Start and goal: free points (uniform) at least ``min_route_distance`` apart. Points are drawn uniformly
        in the hall, ``STATION_BATCH`` at a time: the first free one is the start, the first free one after it far
        enough away the goal (a new start after ``MAX_TRIES`` free ones too close)."""
        w, h, far = self.layout.width / 2, self.layout.height / 2, self.config.min_route_distance
        start, tries = None, 0
        for _ in range(MAX_TRIES * MAX_TRIES // STATION_BATCH):
            points = uniform(rng, (-w, -h), (w, h), (STATION_BATCH, 2))
            for (x, y), free in zip(points.tolist(), self.robot_map.free_points(points), strict=True):
                if not free:
                    continue
                if start is None:
                    start, tries = (x, y), 0
                elif math.hypot(x - start[0], y - start[1]) >= far:
                    return np.array(start), np.array([x, y])
                else:
                    tries += 1
                    start = start if tries < MAX_TRIES else None
        raise RuntimeError("no start and goal min_route_distance apart (check_feasible should have refused this)")

    @staticmethod
    def _spread(rng: np.random.Generator, slots: np.ndarray, n: int, spacing: float) -> np.ndarray:
        """``n`` slot indices, pairwise at least ``spacing`` apart, in random order."""
        if not n:
            return np.zeros(0, dtype=np.int64)
        chosen = kernels.spread(slots, rng.permutation(len(slots)), n, spacing)  # greedily, in the permutation's order
        if len(chosen) < n:
            raise RuntimeError(f"only {len(chosen)} of {n} pickers fit (check_feasible should have refused this)")
        return chosen

    # ------------------------------------------------------------------ observation
    def _sense_obstacles(self, x: float, y: float) -> None:
        """Sense from the robot's centre at (x, y) at the start of an episode (:func:`kernels.sense` of no move): the
        distances to every segment, their order, the observed segments; a step senses in
        :func:`kernels.sense_and_follow`."""
        radius = self.scene.robot_radius
        _, *self._observed = kernels.sense(self.segments, x, y, x, y, radius, radius, self.config.sensor_range,
                                           self.config.max_obstacles, self._seg_dist, self._seg_order)

    def observed_obstacles(self) -> tuple[np.ndarray, np.ndarray]:
        """The ``max_obstacles`` segments nearest the robot within ``sensor_range``: (M, 4), mask (M,)
        (:func:`~sb3_crowdnav.sim.geometry.nearest_segments`' rule on the sensed distances: the first of their order,
        as many as are within range, zeros after them; :func:`~sb3_crowdnav.sim.warehouse.kernels.sense`)."""
        return self._observed[0], self._observed[1]

    def observed_waypoints(self) -> np.ndarray:
        """The current waypoint and the next ones, (K, 2), the goal repeated at the end (kept until the route or the
        index changes; the observation copies it)."""
        if self._waypoints_of[0] is not self.route or self._waypoints_of[1] != self.route_index:
            k = self.config.num_waypoints
            ahead = self.route[self.route_index : self.route_index + k]
            waypoints = np.concatenate([ahead, np.repeat(self.route[-1:], k - len(ahead), axis=0)])
            self._waypoints_of = (self.route, self.route_index, waypoints)
        return self._waypoints_of[2]

    # ------------------------------------------------------------------ step
    def _in_sight(self, a: Sequence[float], b: Sequence[float]) -> bool:
        """Whether the robot's disc fits all along the segment ``a``-``b`` (to within 1 µm): with boxes for racks by
        the exact distance to the racks and walls, else shapely's ``covers`` by the free space of its radius + 1 µm."""
        radius = self.scene.robot_radius
        if self._boxes is not None:  # (kernels.segment_clearance: boxes.segment_clearance's operations)
            (ax, ay), (bx, by) = a, b
            return kernels.segment_clearance(ax, ay, bx, by, self._boxes, self.layout.width / 2, self.layout.height / 2,
                                             radius) >= radius - 1e-6
        if self._sight is None:
            self._sight = self.layout.free_space(radius).buffer(1e-6)
            shapely.prepare(self._sight)
        return bool(self._sight.covers(LineString([a, b])))

    def _set_route(self, points: list[list[float]]) -> None:
        self.route, self._route_points = np.array(points, dtype=np.float64), points

    def _advance_route(self, pos: list[float], index: int, off: bool, blocked: bool) -> None:
        """Pass reached waypoints (:func:`next_waypoints`' rule: ``index`` the new current one); plan again when the
        route is lost: the robot at ``pos`` strayed more than ``replan_distance`` from it (``off``), or the way to the
        current waypoint is ``blocked`` (asked here of shapely when the racks are not boxes)
        (:func:`~sb3_crowdnav.sim.warehouse.kernels.sense_and_follow` answers both)."""
        self.route_index = index
        if off or blocked or (self._boxes is None and not self._in_sight(pos, self._route_points[index])):
            try:
                self._set_route(self.robot_map.waypoints(pos, self._route_points[-1]))
                self.route_index, self.replans = 1, self.replans + 1
            except ValueError:  # the robot is cornered: keep the old route
                pass

    def _move_humans(self, robot_end: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """The pickers' step; the robot (its state at the start of the step, where its move ends) is what a picker who
        sees it avoids."""
        return self.pickers.step(self.history[-1, : self.num_humans, Human.POS], self._robot_agent(robot_end))

    def step(self, action: int) -> RewardTerms:  # type: ignore[override]
        """Apply ``action`` (0..79), move the pickers; the reward terms (a rack or wall hit is a collision).

        :attr:`hit_obstacle` tells whether this step's collision was with a rack or a wall.
        """
        p0 = self.robot[Robot.POS].tolist()
        waypoint = self._route_points[self.route_index]  # the observed current waypoint (replanning replaces the route)
        terms = super().step(action)
        p1 = self.robot[Robot.POS].tolist()
        (x0, y0), (x1, y1), radius, cfg = p0, p1, self.scene.robot_radius, self.config
        # the sensing of the step (the candidates of the swept test: the segments closer than the radius + the step)
        # and the route's bookkeeping at p1, applied below unless the step ends the episode
        # (kernels.sense_and_follow, then kernels.swept_segment_distance: the smallest distance of the step's path)
        hit, observed, mask, index, off, blocked, swept = kernels.step_sensing(
            self.segments, x0, y0, x1, y1, radius + math.dist(p0, p1), radius, cfg.sensor_range,
            cfg.max_obstacles, self._seg_dist, self._seg_order, self.route, self.route_index, cfg.waypoint_radius,
            cfg.replan_distance, self._boxes, self.layout.width / 2, self.layout.height / 2)
        self._observed = [observed, mask]
        self.min_clearance = min(self.min_clearance, swept - radius)
        if hit:  # (without a hit, with_obstacle_collision returns the terms unchanged)
            terms = with_obstacle_collision(terms, np.bool_(hit), self.config.obstacle_collision_penalty)
        self.hit_obstacle = hit and not bool(terms.min_distance < 0)
        if self.config.progress_reward:  # (with_route_progress returns the terms unchanged without shaping)
            terms = with_route_progress(terms, np.array(p0), np.array(p1), np.array(waypoint), self.config.progress_reward)
        self.progress_term = float(terms.progress_term)
        if not (terms.collision or terms.success):
            self._advance_route(p1, index, off, blocked)
        return terms

    @property
    def sees_robot(self) -> np.ndarray:
        """(n,) bool: the pickers who see the robot (a share of ``robot_visible``, drawn per episode)."""
        return self.pickers.sees_robot.copy() if self.pickers is not None else np.zeros(0, dtype=bool)

    @property
    def standing(self) -> np.ndarray:
        """(num_humans,) bool: pickers standing at a pick face."""
        return self.pickers.standing if self.pickers is not None else np.zeros(0, dtype=bool)
