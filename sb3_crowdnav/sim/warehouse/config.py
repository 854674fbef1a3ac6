"""The warehouse's own settings, and the feasibility checks that refuse an impossible world at construction."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sb3_crowdnav.sim.config import MAX_PROGRESS_REWARD, SceneConfig
from sb3_crowdnav.sim.validation import (
    check_at_most,
    check_bool,
    check_choice,
    check_instance,
    check_int,
    check_number,
    check_range,
)
from sb3_crowdnav.sim.warehouse.layout import LayoutRanges, WarehouseLayout, layout_from_sizes

AISLE_MARGIN = 0.2  # [m] an aisle must be at least the robot's diameter + this wide
# the warehouse robot's defaults, a typical warehouse AMR's (docs/decisions.md, "Kinematics"): a stop, a_max [m/s²],
# ω_max [rad/s] (unicycle only); its speed is robot_v_pref, 1 m/s
ROBOT_DEFAULTS = {"actions": "with_stop", "max_acceleration": 1.0, "max_turn_rate": 1.5}
# the robot the shipped warehouse models were trained with (the paper's): pass these to run them in their world
PAPER_ROBOT = {"actions": "paper", "max_acceleration": None, "max_turn_rate": None}
# the share of pickers who see the robot by default with ORCA pickers (docs/decisions.md, "Pickers who see the robot");
# social force takes a bool, its default SOCIAL_FORCE_VISIBLE
PICKERS_SEE_ROBOT = 0.8
SOCIAL_FORCE_VISIBLE = True
# the pickers the shipped warehouse models met (none saw the robot): with PAPER_ROBOT, their world's episodes
BLIND_PICKERS = {"robot_visible": False}
# the warehouse's people sensor by default (docs/decisions.md, "Sensing"): racks hide pickers (WarehouseConfig's
# occlusion, True) and people farther than this [m] are not observed
PEOPLE_SENSOR_RANGE = 8.0
# how the shipped warehouse models saw the pickers: through racks, at any range
FULL_SIGHT = {"occlusion": False, "people_sensor_range": None}
# the warehouse before the realistic robot: the paper's robot, blind pickers, full sight (the shipped models' world)
PAPER_WAREHOUSE = {**PAPER_ROBOT, **BLIND_PICKERS, **FULL_SIGHT}


@dataclass(frozen=True)
class WarehouseConfig:
    """Settings of ``CrowdNavWarehouse-v0`` beyond the crowd's :class:`~sb3_crowdnav.sim.config.SceneConfig`.

    :param layout: a fixed layout for every episode; None draws one per episode from ``layout_ranges``
    :param layout_ranges: the ranges of generated layouts
    :param max_obstacles: M, obstacle segments in the observation (the nearest within ``sensor_range``)
    :param sensor_range: [m] obstacle segments farther than this from the robot are not observed
    :param occlusion: pickers behind racks are not observed (:mod:`sb3_crowdnav.sim.sensing`); False: the robot sees
        through racks (the world of the shipped warehouse models)
    :param num_waypoints: K, route waypoints in the observation (the current one first; the goal repeats)
    :param waypoint_radius: [m] a waypoint counts as passed when the robot's centre comes this close
    :param replan_distance: [m] the route is planned again from the robot when it strays farther than this
        from it or loses sight of its current waypoint
    :param dwell_time: (min, max) [s] a picker stands at a pick face, drawn uniformly per pick
    :param min_route_distance: [m] the robot's start and goal are at least this far apart (straight line)
    :param obstacle_collision_penalty: reward of hitting a rack or a wall (ends the episode)
    :param time_limit_factor: the episode is truncated after ``time_limit_slack + time_limit_factor x`` the time
        the route takes at ``robot_v_pref``
    :param time_limit_slack: [s]
    :param progress_reward: [1/m] route-progress shaping, beyond the paper: each step earns this times the metres
        it gained on the route's current waypoint (negative when it loses them); 0 (the default) is the paper's
        reward. The ``apg_warehouse`` training variant sets 0.1.
    """

    layout: WarehouseLayout | None = None
    layout_ranges: LayoutRanges = field(default_factory=LayoutRanges)
    max_obstacles: int = 16
    sensor_range: float = 4.0
    occlusion: bool = True
    num_waypoints: int = 3
    waypoint_radius: float = 0.6
    replan_distance: float = 1.5
    dwell_time: tuple[float, float] = (2.0, 8.0)
    min_route_distance: float = 6.0
    obstacle_collision_penalty: float = -0.25
    time_limit_factor: float = 2.0
    time_limit_slack: float = 10.0
    progress_reward: float = 0.0

    def __post_init__(self) -> None:
        check_instance("layout", self.layout, (WarehouseLayout, type(None)), "a WarehouseLayout or None")
        check_instance("layout_ranges", self.layout_ranges, LayoutRanges, "a LayoutRanges")
        check_int("max_obstacles", self.max_obstacles, 1)
        check_bool("occlusion", self.occlusion)
        check_int("num_waypoints", self.num_waypoints, 1)
        for name in ("sensor_range", "waypoint_radius", "replan_distance", "min_route_distance", "time_limit_factor"):
            check_number(name, getattr(self, name))
        check_number("time_limit_slack", self.time_limit_slack, allow_zero=True)
        check_range("progress_reward", self.progress_reward, 0, MAX_PROGRESS_REWARD)  # [1/m]
        check_number("obstacle_collision_penalty", self.obstacle_collision_penalty, positive=False)
        check_at_most("obstacle_collision_penalty", self.obstacle_collision_penalty, 0)  # a penalty, never a reward
        check_instance("dwell_time", self.dwell_time, (tuple, list), "a (min, max) pair [s]")
        if len(self.dwell_time) != 2:
            raise ValueError(f"dwell_time must be a (min, max) pair [s], got {self.dwell_time!r}")
        check_number("dwell_time[0]", self.dwell_time[0], allow_zero=True)
        check_number("dwell_time[1]", self.dwell_time[1], allow_zero=True)
        if self.dwell_time[1] < self.dwell_time[0]:
            raise ValueError(f"dwell_time must satisfy min <= max, got {self.dwell_time!r}")

    def smallest_layouts(self) -> list[tuple[str, WarehouseLayout]]:
        """The layouts every feasibility check must pass: the fixed one, or the generator's extremes."""
        if self.layout is not None:
            return [("layout", self.layout)]
        r = self.layout_ranges
        small = layout_from_sizes(r.rows[0], r.segments[0], r.rack_length[0], r.rack_depth[1], r.aisle_width[0],
                                  r.cross_aisle_width[0])
        crowded = layout_from_sizes(r.rows[1], r.segments[1], r.rack_length[0], r.rack_depth[1], r.aisle_width[0],
                                    r.cross_aisle_width[0])
        return [("layout_ranges", small), ("layout_ranges", crowded)]


def check_feasible(scene: SceneConfig, config: WarehouseConfig, pick_slots) -> None:
    """``ValueError`` naming the parameter when some episode could not be set up or driven.

    :param pick_slots: ``pick_slots(layout, scene) -> (n, 2)`` candidate picker positions of a layout
    """
    diameter = 2 * max(scene.robot_radius, scene.human_radius)
    for name, layout in config.smallest_layouts():
        layout.validate(max(scene.robot_radius, scene.human_radius), AISLE_MARGIN, name=name)
        slots = pick_slots(layout, scene)
        _, hi = scene.humans_range
        capacity = _packing(slots, 2 * scene.human_radius + 0.2)
        if hi > capacity:
            raise ValueError(f"num_humans: at most {capacity} pickers fit at the pick faces of the smallest layout "
                             f"({layout.width:.1f} x {layout.height:.1f} m) from {name}, got up to {hi}")
        reach = np.hypot(layout.width, layout.height) - 2 * diameter
        if config.min_route_distance > reach:
            raise ValueError(f"min_route_distance: {config.min_route_distance} m does not fit in the "
                             f"{layout.width:.1f} x {layout.height:.1f} m hall from {name} (at most {reach:.1f} m)")


def _packing(points: np.ndarray, spacing: float) -> int:
    """How many of ``points`` can be taken greedily with pairwise distances >= ``spacing``."""
    kept: list[np.ndarray] = []
    for p in points:
        if all(np.hypot(*(p - q)) >= spacing for q in kept):
            kept.append(p)
    return len(kept)


OPEN_FLOOR_ONLY = ("stop_probability", "stop_duration")
PICKER_CROWDS = ("orca", "social_force")  # the crowd models that see walls


def check_pickers(scene: SceneConfig) -> None:
    """``ValueError`` naming a crowd setting the pickers do not have (yet): a crowd model that does not see walls,
    the open floor's stops (pickers stand at pick faces for their dwells). (``human_speed`` is theirs too; a share of
    pickers seeing the robot is ORCA's; social force refuses it.)"""
    check_choice("crowd", scene.crowd, PICKER_CROWDS)
    default = SceneConfig()
    for name in OPEN_FLOOR_ONLY:
        if getattr(scene, name) != getattr(default, name):
            raise ValueError(f"{name} is the open floor's; the warehouse's pickers are its own ORCA crowd, got "
                             f"{getattr(scene, name)!r}")
