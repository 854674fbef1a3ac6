"""The ``CrowdNavWarehouse-v0`` Gymnasium environment: a robot following a route among pickers, racks and walls."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from sb3_crowdnav.envs import base
from sb3_crowdnav.envs.base import CrowdEnvBase
from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
from sb3_crowdnav.sim.observation import ObservationSchema
from sb3_crowdnav.sim.validation import check_choice
from sb3_crowdnav.sim.warehouse import LayoutRanges, WarehouseLayout
from sb3_crowdnav.sim.warehouse.config import (
    PEOPLE_SENSOR_RANGE,
    PICKER_CROWDS,
    PICKERS_SEE_ROBOT,
    ROBOT_DEFAULTS,
    SOCIAL_FORCE_VISIBLE,
    WarehouseConfig,
)
from sb3_crowdnav.sim.warehouse.simulator import WarehouseSimulator
from sb3_crowdnav.sim.world import World

WAREHOUSE_KEYS = {f.name for f in dataclasses.fields(WarehouseConfig)}
# the open floor's scene fields, which a warehouse never reads (its hall and stations come from the layout)
UNUSED_SCENE = {
    "circle_radius": "sets the open floor's circle; the warehouse's hall comes from its layout",
    "square_width": "sets the open floor's square; the warehouse's hall comes from its layout",
    "start_noise": "sets the open floor's starts; the warehouse draws its stations from its layout",
    # the open floor's population (the pickers' stops are their jobs' dwells)
    "stop_probability": "makes people on the open floor stop; pickers stand at pick faces for dwell_time",
    "stop_duration": "is how long people on the open floor stand; pickers stand at pick faces for dwell_time",
}
ROUTE_TIME_KEYS = ("time_limit_factor", "time_limit_slack")
# what ORCA pickers read, unused with crowd="social_force"
ORCA_KEYS = ("orca_neighbor_dist", "orca_max_neighbors", "orca_time_horizon", "orca_time_horizon_obst")


class CrowdNavWarehouseEnv(CrowdEnvBase):
    """
    ## Description

    A robot drives from a start to a goal through a warehouse: a walled hall with rows of racks,
    main aisles between the rows and cross aisles between the racks of a row. Pickers (the
    pedestrians, ORCA agents that see the racks through ``pyrvo``'s obstacles) walk routes between
    pick faces along the aisles and stand at each for a dwell time, so some stand still at any moment.
    The robot gets a global route from a planner on the static map (A* with ``networkx`` on a visibility
    roadmap: the corners of the racks grown by the robot's radius and a clearance); the observation carries
    its next waypoints and the nearest rack and wall segments, in world coordinates like the pedestrians, so
    that a lookahead can propagate them.

    A layout is drawn per episode from ``layout_ranges`` (rows of racks, racks per row, rack length and
    depth, aisle widths; see :class:`~sb3_crowdnav.sim.warehouse.LayoutRanges`), or fixed by ``layout``
    (a :class:`~sb3_crowdnav.sim.warehouse.WarehouseLayout`, a mapping, or the path of a YAML/JSON layout
    file). Every setting is checked at construction: an infeasible layout or value (aisles narrower
    than the robot's diameter + 0.2 m, free space split, more pickers than pick faces, a start-goal
    distance the hall cannot hold) raises ``ValueError`` naming the parameter.

    ## Action Space

    ``Discrete(81)``: ``CrowdNav-v0``'s 80 actions and a stop (action 80, ``actions="with_stop"``); the robot is a
    warehouse AMR's, its commands clipped to ``max_acceleration`` = 1 m/s² and ``max_turn_rate`` = 1.5 rad/s (the rule
    of :mod:`sb3_crowdnav.sim.actions`). ``actions="paper", max_acceleration=None, max_turn_rate=None`` give the
    paper's robot (``Discrete(80)``, no limits), the world the shipped ``apg_warehouse`` and ``ppo_warehouse`` were
    trained in. With ``kinematics="holonomic"`` the turn rate is not limited (its default is then None).

    ## Observation Space

    ``CrowdNav-v0``'s keys, unchanged in meaning, plus the static world (float32, world coordinates):

    ==================  =====================  ==============================================================================
    key                 shape                  content
    ==================  =====================  ==============================================================================
    ``robot``           (9,)                   px, py, vx, vy, radius, gx, gy (the final goal), v_pref, heading
    ``humans``          (T * max_humans * 5,)  the seen pickers' px, py, vx, vy, radius for the last T = 5 steps (2)
    ``humans_mask``     (max_humans,)          1 for a picker seen now
    ``obstacles``       (max_obstacles * 4,)   the nearest rack and wall segments (1), [x0, y0, x1, y1]
    ``obstacles_mask``  (max_obstacles,)       1 for an observed segment, 0 for padding (zeros)
    ``waypoints``       (num_waypoints * 2,)   the current route waypoint and the next ones (3), the goal repeated at the end
    ==================  =====================  ==============================================================================

    (1) the ``max_obstacles`` (16) segments nearest the robot within ``sensor_range`` (4 m), nearest first.
    Positions are bounded by ± (the largest hall's half diagonal + 1 m).

    (2) the robot sees a picker when a line of sight reaches their disc past the racks (``occlusion``) and the disc
    is within ``people_sensor_range`` (8 m), with optional ``people_sensor_noise`` and ``people_sensor_latency``
    (:mod:`sb3_crowdnav.sim.sensing`); an unseen picker's slot is zeros over the window, one seen again starts a
    new history.

    ## Rewards

    As ``CrowdNav-v0`` (``reward="crowdnav"``, ``"comfort"``, ``"comfort_angular"``), plus
    ``obstacle_collision_penalty`` (-0.25) when the robot's swept disc touches a rack or a wall
    during the step, and, when ``progress_reward`` k > 0 (default 0: the paper's reward, no shaping), the
    route-progress shaping k x (metres gained on the current waypoint during the step), zero on terminal steps.
    ``info`` reports every term (``reward_progress`` the shaping).

    ## Starting State

    The robot at rest at a free roadmap point, facing its first waypoint; its goal another free point at
    least ``min_route_distance`` (6 m) away. About half of the pickers stand at pick faces, the others
    walk to their first; none starts or picks within 1 m of the robot's start or goal.

    ## Episode End

    Terminated on success (the robot's centre within its radius of the goal) or collision:
    ``info["outcome"] == "collision"`` with ``info["collision_with"]`` ``"human"`` (a picker) or
    ``"obstacle"`` (a rack or a wall). Truncated ("timeout") after
    ``time_limit_slack + time_limit_factor x`` (route length / v_pref) seconds (10 s + twice the route time), or,
    when ``time_limit`` is given, after ``time_limit`` seconds whatever the route; the reset's ``info["time_limit"]``
    says which [s]. ``info["episode_stats"]`` as ``CrowdNav-v0``'s, plus ``route_length`` [m], ``replans`` and
    ``min_clearance`` [m] (the smallest distance from the robot's disc to a rack or wall over the episode's swept
    steps; below 0 after an obstacle collision).

    ## Arguments

    ``gym.make("CrowdNavWarehouse-v0", num_humans=6, layout=None, ...)``: every field of
    :class:`~sb3_crowdnav.sim.config.SceneConfig` that concerns the agents (radii, speeds, ``num_humans``,
    ``max_humans``, ``time_step``, kinematics, ORCA), of :class:`~sb3_crowdnav.sim.config.RewardConfig`, and of
    :class:`~sb3_crowdnav.sim.warehouse.config.WarehouseConfig` (``layout``, ``layout_ranges``,
    ``max_obstacles``, ``sensor_range``, ``num_waypoints``, ``waypoint_radius``, ``replan_distance``,
    ``dwell_time``, ``min_route_distance``, ``obstacle_collision_penalty``, ``time_limit_factor``,
    ``time_limit_slack``, ``progress_reward``).

    Every argument changes the episodes or is refused at construction (``ValueError`` naming it):

    * ``crowd``: the pickers' model, ``"orca"`` (default) or ``"social_force"`` (JuPedSim's, the racks and walls its
      walkable area's boundary), with ``crowd_kwargs`` as on the open floor (``"orca"``'s ``safety_space`` too);
    * ``robot_visible``: who of the pickers sees the robot and avoids it, a share in [0, 1] (each picker sees it with
      that probability, drawn per episode after the reset's other draws but the speeds; the others are distracted and
      walk as if it were not there) or a bool (all or none). Default 0.8 with ORCA, where a picker who sees it has it
      as one more agent, at its actual position and velocity each step. Social force takes a bool (its forces act on
      everyone; default True: the robot is an agent following its path). False: no picker yields (the shipped models'
      world);
    * ``human_speed``: ``"fixed"`` (default: every picker at ``human_v_pref``, 1 m/s) or ``"measured"``: each picker's
      preferred walking speed drawn per episode as on the open floor, Normal(1.34, 0.26) m/s clipped to [0.5, 2.0]
      (the reset's last draw: the layout, the stations, the pickers' jobs and who sees the robot stay those of
      ``"fixed"``); ``human_v_pref`` is then refused;
    * ``actions``, ``max_acceleration`` and ``max_turn_rate``: the robot (defaults above; None is unlimited);
    * ``occlusion`` (default True), ``people_sensor_range`` (8 m; None: unlimited), ``people_sensor_noise`` (0 m) and
      ``people_sensor_latency`` (0 steps): what the robot sees of the pickers; collisions count with everyone;
    * ``time_limit`` [s] replaces the route-based limit, so it excludes ``time_limit_factor`` and
      ``time_limit_slack``;
    * ``circle_radius``, ``square_width`` and ``start_noise`` (the open floor's) are refused, as are
      ``human_policy`` other than ``"orca"``, ``crowd="linear"``, a share for ``robot_visible`` with social force,
      the ORCA fields with ``crowd="social_force"``, the open floor's stops (``stop_probability``, ``stop_duration``:
      pickers stand at pick faces for ``dwell_time``), ``scenario`` other
      than ``"warehouse"`` and a reward weight of another reward (as in ``CrowdNav-v0``).

    ## Version History

    * v0: initial version. Since the kinematic limits: the robot defaults to a warehouse AMR's (a stop, 1 m/s²,
      1.5 rad/s); the earlier episodes are those of ``actions="paper", max_acceleration=None, max_turn_rate=None``.
      Since the pickers see the robot: 4 in 5 ORCA pickers see it by default (all with social force); the earlier
      episodes also need ``robot_visible=False``. Since the people sensor: racks hide pickers and the range is 8 m;
      the earlier observations also need ``occlusion=False, people_sensor_range=None`` (all of these:
      ``sim.warehouse.config.PAPER_WAREHOUSE``).
    """

    def __init__(self, render_mode: str | None = None, reward: str = "crowdnav", gamma: float = 0.9,
                 **kwargs: Any) -> None:
        name = type(self).__name__
        base.check_env_arguments(self.metadata["render_modes"], render_mode, gamma)
        warehouse = {k: kwargs[k] for k in kwargs if k in WAREHOUSE_KEYS}
        scene_kwargs, reward_kwargs = base.split_env_kwargs(kwargs, name, WAREHOUSE_KEYS)
        if scene_kwargs.setdefault("scenario", "warehouse") != "warehouse":
            raise ValueError(f"scenario must be 'warehouse' in CrowdNavWarehouse-v0, got {scene_kwargs['scenario']!r}")
        if scene_kwargs.get("human_policy", "orca") != "orca":
            raise ValueError(f"human_policy must be 'orca' in CrowdNavWarehouse-v0 (pickers see the racks; choose "
                             f"their model with crowd), got {scene_kwargs['human_policy']!r}")
        if scene_kwargs.get("crowd") == "replay":
            raise ValueError("crowd='replay' replays recorded people on the open floor (CrowdNav-v0 and its variants); "
                             f"the warehouse's pickers are moved by one of {PICKER_CROWDS}")
        check_choice("crowd", scene_kwargs.get("crowd", "orca"), PICKER_CROWDS)
        for key, value in ROBOT_DEFAULTS.items():  # a warehouse AMR (a holonomic robot has no turn rate to limit)
            if not (key == "max_turn_rate" and scene_kwargs.get("kinematics") == "holonomic"):
                scene_kwargs.setdefault(key, value)
        scene_kwargs.setdefault("people_sensor_range", PEOPLE_SENSOR_RANGE)  # (and the racks hide pickers: occlusion)
        # who sees the robot: a share of ORCA pickers; social force takes a bool (its forces act on everyone)
        scene_kwargs.setdefault("robot_visible", SOCIAL_FORCE_VISIBLE if scene_kwargs.get("crowd") == "social_force"
                                else PICKERS_SEE_ROBOT)
        fixed_time_limit = "time_limit" in kwargs
        both = [key for key in ROUTE_TIME_KEYS if key in kwargs]
        if fixed_time_limit and both:
            raise ValueError(f"time_limit and {both[0]} exclude each other: time_limit truncates every episode at a "
                             f"fixed time, {' and '.join(ROUTE_TIME_KEYS)} by its route's length; pass one or the other")
        scene = SceneConfig(**scene_kwargs)
        reward_config = RewardConfig(name=reward, **reward_kwargs)
        unused_crowd = {key: "concerns ORCA pickers; crowd='social_force' sets its forces in crowd_kwargs"
                        for key in ORCA_KEYS if scene.crowd == "social_force"}
        if scene.human_speed == "measured":
            unused_crowd["human_v_pref"] = "is the pickers' speed with human_speed='fixed'; 'measured' draws each one's"
        base.refuse_unused(kwargs, {**UNUSED_SCENE, **unused_crowd, **base.unused_reward_weights(reward_config)}, name)
        self.warehouse = WarehouseConfig(**_layout_objects(warehouse))
        sim = WarehouseSimulator(scene, reward_config, self.warehouse, fixed_time_limit)
        largest = max(math.hypot(layout.width, layout.height) / 2 for layout in self._largest_layouts())
        schema = ObservationSchema(scene.history_length, scene.max_humans, self.warehouse.max_obstacles,
                                   self.warehouse.num_waypoints)
        super().__init__(scene, reward_config, sim, schema, largest + 1.0, gamma, render_mode)

    @classmethod
    def option_names(cls) -> set[str]:
        """Every keyword argument the constructor knows (each changes the episodes or is refused)."""
        return base.SCENE_KEYS | base.REWARD_KEYS | WAREHOUSE_KEYS | base.ENV_KEYS

    def _largest_layouts(self) -> list[WarehouseLayout]:
        if self.warehouse.layout is not None:
            return [self.warehouse.layout]
        from sb3_crowdnav.sim.warehouse.layout import layout_from_sizes

        r = self.warehouse.layout_ranges
        return [layout_from_sizes(r.rows[1], r.segments[1], r.rack_length[1], r.rack_depth[1], r.aisle_width[1],
                                  r.cross_aisle_width[1])]

    @property
    def layout(self) -> WarehouseLayout | None:
        """The current episode's layout (its obstacles: ``layout.polygons``)."""
        return self.sim.layout

    @property
    def world(self) -> World:
        """The crowd's world with the warehouse's static-world rules and route shaping."""
        w = self.warehouse
        return dataclasses.replace(super().world, obstacle_collision_penalty=w.obstacle_collision_penalty,
                                   waypoint_radius=w.waypoint_radius, progress_reward=w.progress_reward)

    def _static_obs(self) -> dict[str, np.ndarray]:
        segments, mask = self.sim.observed_obstacles()
        return {"obstacles": segments, "obstacles_mask": mask, "waypoints": self.sim.observed_waypoints()}

    def _reset_info(self) -> dict[str, Any]:
        return {"route_length": self.sim.route_length, "time_limit": self.max_steps * self.scene.time_step}

    def _extra_info(self) -> dict[str, Any]:
        return {"reward_progress": self.sim.progress_term}

    def _extra_stats(self) -> dict[str, Any]:
        return {"route_length": self.sim.route_length, "replans": self.sim.replans, "min_clearance": self.sim.min_clearance}

    def _render_extras(self) -> dict[str, Any]:
        return {"obstacles": self.sim.layout.polygons, "route": self.sim.route, "standing": self.sim.standing}


def _layout_objects(warehouse: dict[str, Any]) -> dict[str, Any]:
    """``warehouse``'s settings with a layout given as a file path or a mapping, and layout ranges given as a
    mapping, made into their objects (what :class:`WarehouseConfig` takes)."""
    out = dict(warehouse)
    layout = out.get("layout")
    if isinstance(layout, str) or hasattr(layout, "__fspath__"):
        out["layout"] = WarehouseLayout.from_file(layout)
    elif isinstance(layout, dict):
        out["layout"] = WarehouseLayout.from_dict(layout)
    if isinstance(out.get("layout_ranges"), dict):
        out["layout_ranges"] = LayoutRanges(**out["layout_ranges"])
    return out


__all__ = ["CrowdNavWarehouseEnv"]
