"""Frozen, validated configuration of a crowd scene and of the reward.

Every field is checked in ``__post_init__`` with :mod:`sb3_crowdnav.sim.validation`: a wrong type
raises ``TypeError``, a wrong value ``ValueError``, naming the field and what is allowed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Literal

import numpy as np

from sb3_crowdnav.sim.actions import ACTION_SETS
from sb3_crowdnav.sim.crowd_settings import crowd_settings
from sb3_crowdnav.sim.validation import (
    check_at_least,
    check_at_most,
    check_choice,
    check_instance,
    check_int,
    check_number,
    check_probability,
    check_share,
)

SCENARIOS = ("circle_crossing", "square_crossing", "warehouse")  # "warehouse": CrowdNavWarehouse-v0 only
MAX_EPISODE_STEPS = 10_000
# sensible upper bounds (name, limit, unit): beyond them the physics, the observation bounds or the rewards overflow
SCENE_LIMITS = (
    ("max_humans", 100, ""), ("history_length", 50, ""), ("time_step", 2.0, " s"), ("time_limit", 3600.0, " s"),
    ("robot_radius", 2.0, " m"), ("human_radius", 2.0, " m"), ("robot_v_pref", 10.0, " m/s"),
    ("human_v_pref", 10.0, " m/s"), ("circle_radius", 100.0, " m"), ("square_width", 200.0, " m"),
    ("start_noise", 10.0, " m"), ("orca_neighbor_dist", 100.0, " m"), ("orca_max_neighbors", 100, ""),
    ("orca_time_horizon", 100.0, " s"), ("orca_time_horizon_obst", 100.0, " s"),
)
REWARD_LIMITS = (  # on the absolute value
    ("success_reward", 100.0, ""), ("collision_penalty", 100.0, ""), ("discomfort_dist", 5.0, " m"),
    ("discomfort_factor", 100.0, ""), ("comfort_person", 10.0, " m"), ("comfort_side", 10.0, " m"),
    ("social_penalty", 100.0, ""), ("angular_penalty", 100.0, ""), ("angular_penalty_threshold", math.pi, " rad"),
)
# sensible lower bounds of the comfort ellipse's semi-axes: the social term scales by (d_side / d_person)² (Eq. 11),
# which overflows for d_person near 1e-155 m; a centimetre is far below any person's body
REWARD_MINIMA = (("comfort_person", 0.01, " m"), ("comfort_side", 0.01, " m"))
# [1/m] the largest progress shaping (``progress_reward`` of both envs): beyond it the shaping swamps the success
# reward (1) within centimetres
MAX_PROGRESS_REWARD = 10.0
KINEMATICS = ("unicycle", "holonomic")
HUMAN_POLICIES = ("orca", "linear")  # the values of the old name of ``crowd``
HUMAN_SPEEDS = ("fixed", "measured")
OBSERVED = ("all", "nearest")  # who fills the observation's max_humans slots (:mod:`sb3_crowdnav.sim.sensing`)
# human_speed="measured": each person's preferred speed ~ Normal(mean, sd) clipped to [low, high] [m/s]; the desired
# speeds of Helbing, Molnár, Farkas & Bolay (2001), "Self-organizing pedestrian movement", Environment and Planning B
# 28: 1.34 ± 0.26 m/s (after Henderson 1971 and Weidmann 1993's 1.34 m/s free walking speed)
MEASURED_SPEED = (1.34, 0.26, 0.5, 2.0)
MAX_STOP_DURATION = 3600.0  # [s]
MAX_PEOPLE = 100  # the most people a scene simulates (max_humans's bound too)
# the people sensor's bounds (:mod:`sb3_crowdnav.sim.sensing`): range [m], position noise σ [m], latency [steps]
MAX_SENSOR_RANGE, MAX_SENSOR_NOISE, MAX_SENSOR_LATENCY = 1000.0, 5.0, 20
REWARDS = ("crowdnav", "comfort", "comfort_angular")


def _to_python_scalars(config: Any) -> None:
    """Replace NumPy scalars (accepted like Python's) by Python ones in a frozen dataclass: plain reprs and JSON."""
    for f in fields(config):
        value = getattr(config, f.name)
        if isinstance(value, np.generic):
            object.__setattr__(config, f.name, value.item())
        elif isinstance(value, (tuple, list)) and any(isinstance(v, np.generic) for v in value):
            object.__setattr__(config, f.name, type(value)(v.item() if isinstance(v, np.generic) else v for v in value))


def check_robot_limits(actions: str, max_acceleration: Any, max_turn_rate: Any, kinematics: str) -> None:
    """The action set and the robot's limits (of a :class:`SceneConfig` and of a :class:`~sb3_crowdnav.sim.world.World`):
    ``ValueError`` for an unknown set, a limit <= 0 or a turn-rate limit on a holonomic robot; ``TypeError`` for a
    limit that is neither None nor a real number."""
    check_choice("actions", actions, ACTION_SETS)
    for name, value in (("max_acceleration", max_acceleration), ("max_turn_rate", max_turn_rate)):
        if value is not None:
            check_number(name, value)
    if max_turn_rate is not None and kinematics == "holonomic":
        raise ValueError(f"max_turn_rate must be None with kinematics='holonomic' (a holonomic robot moves in any "
                         f"direction without turning), got {max_turn_rate!r}")


@dataclass(frozen=True)
class SceneConfig:
    """Geometry, agents and dynamics of a crowd scene (defaults: the paper's Table 1).

    :param num_humans: number of pedestrians, an int or an inclusive ``(min, max)`` range drawn per episode; at most
        ``max_humans`` unless ``observed="nearest"``
    :param max_humans: observation capacity (padded slots are masked)
    :param observed: who fills the observation's ``max_humans`` slots: ``"all"`` (the default: every person has a
        slot of their own, so ``num_humans`` <= ``max_humans``) or ``"nearest"`` (the ``max_humans`` people nearest to
        the robot among those the sensor sees, each keeping their slot while among them, as a tracker's N nearest
        tracks; more people than slots may then walk, and collisions count with everyone; :mod:`sb3_crowdnav.sim.sensing`)
    :param time_step: Δt [s]
    :param time_limit: episode time limit [s]; reaching it truncates the episode
    :param robot_radius: [m]
    :param human_radius: [m]
    :param robot_v_pref: robot preferred (and maximum) speed [m/s]
    :param human_v_pref: pedestrian preferred speed [m/s]
    :param scenario: ``"circle_crossing"`` or ``"square_crossing"``
    :param circle_radius: radius of the crossing circle [m]
    :param square_width: side of the square-crossing area [m]
    :param start_noise: uniform noise on each start coordinate, ± [m]
    :param robot_visible: whether pedestrians see (and avoid) the robot: a bool (everyone or no one), or a share in
        [0, 1], each person seeing it with that probability, drawn at reset (0.0 and 1.0 are stored as the bools)
    :param kinematics: ``"unicycle"`` (direction = rotation of the heading) or ``"holonomic"``
    :param rotation_range: width of the direction fan [rad]; 2π = all directions
    :param actions: the action set, ``"paper"`` (the 80 actions) or ``"with_stop"`` (those and a stop, action 80;
        :mod:`sb3_crowdnav.sim.actions`)
    :param max_acceleration: the robot's a_max [m/s²], None: unlimited (the paper's); a command beyond it is clipped
        by the rule of :mod:`sb3_crowdnav.sim.actions`
    :param max_turn_rate: the robot's ω_max [rad/s], None: unlimited (the paper's); ``"unicycle"`` only
    :param crowd: the crowd model that moves the people (``sb3_crowdnav.sim.crowd.CROWD_MODELS``): ``"orca"``
        (pyrvo), ``"social_force"`` (JuPedSim), ``"linear"`` (constant velocity towards the goal; for tests) or
        ``"replay"`` (recorded people; the population settings and ``num_humans`` then stay at their defaults)
    :param crowd_kwargs: the model's settings, a dict (``sb3_crowdnav.sim.crowd_settings``); stored as its frozen
        settings object
    :param human_policy: the old name of ``crowd`` (``"orca"`` or ``"linear"``), kept for existing scripts; folded
        into ``crowd`` (and stored as None); a ``crowd`` other than the default beside it must agree
    :param human_speed: ``"fixed"`` (everyone at ``human_v_pref``, the paper's) or ``"measured"`` (each person's
        preferred speed drawn at reset from :data:`MEASURED_SPEED`, Normal(1.34, 0.26) m/s clipped to [0.5, 2.0])
    :param stop_probability: the probability that a person stops once during its walk and stands for a while, drawn
        per person at reset (when: uniform over the time it needs to walk straight to its goal)
    :param stop_duration: (min, max) [s] how long a stopping person stands, drawn uniformly per person
    :param history_length: T, number of past pedestrian states in the observation
    :param people_sensor_range: [m] people whose disc is farther than this from the robot's centre are not observed;
        None (the default): unlimited (:mod:`sb3_crowdnav.sim.sensing`)
    :param people_sensor_noise: [m] σ of the Normal noise on each observed position, per axis; 0: exact
    :param people_sensor_latency: [steps] the observation shows the people as sensed this many steps ago; 0: now
    :param orca_neighbor_dist: [m]
    :param orca_max_neighbors:
    :param orca_time_horizon: [s]
    :param orca_time_horizon_obst: [s]
    """

    # (declared in an order of our own; pass them by keyword)
    num_humans: int | tuple[int, int] = 6
    max_humans: int = 10
    observed: Literal["all", "nearest"] = "all"
    time_step: float = 0.25
    time_limit: float = 25.0
    history_length: int = 5
    people_sensor_range: float | None = None  # [m]
    people_sensor_noise: float = 0.0  # [m]
    people_sensor_latency: int = 0  # [steps]
    kinematics: Literal["unicycle", "holonomic"] = "unicycle"
    rotation_range: float = 2 * math.pi
    actions: Literal["paper", "with_stop"] = "paper"
    max_acceleration: float | None = None  # [m/s²]
    max_turn_rate: float | None = None  # [rad/s]
    robot_radius: float = 0.3
    robot_v_pref: float = 1.0
    human_radius: float = 0.3
    human_v_pref: float = 1.0
    robot_visible: bool = False
    scenario: Literal["circle_crossing", "square_crossing", "warehouse"] = "circle_crossing"
    circle_radius: float = 4.0
    start_noise: float = 0.5
    human_policy: Literal["orca", "linear"] | None = None
    crowd: str = "orca"
    crowd_kwargs: Any = None
    human_speed: Literal["fixed", "measured"] = "fixed"
    stop_probability: float = 0.0
    stop_duration: tuple[float, float] = (2.0, 8.0)
    square_width: float = 10.0
    orca_neighbor_dist: float = 10.0
    orca_max_neighbors: int = 10
    orca_time_horizon: float = 5.0
    orca_time_horizon_obst: float = 5.0

    def __post_init__(self) -> None:
        check_int("max_humans", self.max_humans, 1)
        check_choice("observed", self.observed, OBSERVED)
        lo, hi = self.humans_range
        for name, v in (("num_humans", lo), ("num_humans", hi)):
            check_int(name, v, 0)
        if lo > hi:
            raise ValueError(f"num_humans range must satisfy min <= max, got {self.num_humans!r}")
        if hi > self.max_humans and self.observed == "all":
            raise ValueError(f"num_humans must be <= max_humans ({self.max_humans}) unless observed='nearest' (the "
                             f"robot then observes the max_humans nearest), got {self.num_humans!r}")
        if self.observed == "nearest":  # (else max_humans, checked below, bounds it)
            check_at_most("num_humans", hi, MAX_PEOPLE, "")
        for name in ("time_step", "time_limit", "robot_radius", "human_radius", "robot_v_pref", "human_v_pref",
                     "circle_radius", "square_width", "orca_neighbor_dist", "orca_time_horizon",
                     "orca_time_horizon_obst"):
            check_number(name, getattr(self, name))
        check_number("start_noise", self.start_noise, allow_zero=True)
        check_number("rotation_range", self.rotation_range)
        if self.rotation_range > 2 * math.pi + 1e-9:  # (the tolerance admits 2π computed in another order)
            raise ValueError(f"rotation_range must be in (0, 2π], got {self.rotation_range!r}")
        if self.time_step > self.time_limit:
            raise ValueError(f"time_step ({self.time_step}) must not exceed time_limit ({self.time_limit})")
        check_share("robot_visible", self.robot_visible)
        _to_python_scalars(self)
        if self.robot_visible in (0.0, 1.0):  # all or no one: the bool (nothing drawn)
            object.__setattr__(self, "robot_visible", bool(self.robot_visible))
        check_choice("scenario", self.scenario, SCENARIOS)
        if self.observed == "nearest" and self.scenario == "warehouse":
            raise ValueError("observed='nearest' is the open floor's: in the warehouse every picker has a slot of "
                             "their own (num_humans <= max_humans)")
        check_choice("kinematics", self.kinematics, KINEMATICS)
        check_robot_limits(self.actions, self.max_acceleration, self.max_turn_rate, self.kinematics)
        for name in ("max_acceleration", "max_turn_rate"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, float(getattr(self, name)))
        self._check_crowd()
        check_int("history_length", self.history_length, 1)
        self._check_sensor()
        check_int("orca_max_neighbors", self.orca_max_neighbors, 1)
        for name, limit, unit in SCENE_LIMITS:
            check_at_most(name, getattr(self, name), limit, unit)
        steps = self.time_limit / self.time_step  # inf for a time_step of a few ulps: compared before rounding
        if not steps <= MAX_EPISODE_STEPS:
            raise ValueError(f"time_limit / time_step must be <= {MAX_EPISODE_STEPS} steps per episode, got "
                             f"{self.time_limit} / {self.time_step} = {steps:.6g}")
        self._check_placement()

    def _check_sensor(self) -> None:
        """The people sensor: a range > 0 or None, a noise >= 0, a latency of whole steps >= 0, each within bounds."""
        if self.people_sensor_range is not None:
            check_number("people_sensor_range", self.people_sensor_range)
            check_at_most("people_sensor_range", self.people_sensor_range, MAX_SENSOR_RANGE, " m")
            object.__setattr__(self, "people_sensor_range", float(self.people_sensor_range))
        check_number("people_sensor_noise", self.people_sensor_noise, allow_zero=True)
        check_at_most("people_sensor_noise", self.people_sensor_noise, MAX_SENSOR_NOISE, " m")
        check_int("people_sensor_latency", self.people_sensor_latency, 0, MAX_SENSOR_LATENCY)

    def _check_crowd(self) -> None:
        """The crowd model (``human_policy`` folded into ``crowd``), its settings and the population."""
        if self.human_policy is not None:
            check_choice("human_policy", self.human_policy, HUMAN_POLICIES)
            if self.crowd not in ("orca", self.human_policy):
                raise ValueError(f"human_policy is the old name of crowd; got crowd={self.crowd!r} and "
                                 f"human_policy={self.human_policy!r}: pass crowd only")
            object.__setattr__(self, "crowd", self.human_policy)
            object.__setattr__(self, "human_policy", None)
        object.__setattr__(self, "crowd_kwargs", crowd_settings(self.crowd, self.crowd_kwargs))
        check_choice("human_speed", self.human_speed, HUMAN_SPEEDS)
        check_probability("stop_probability", self.stop_probability)
        check_instance("stop_duration", self.stop_duration, (tuple, list), "a (min, max) pair [s]")
        if len(self.stop_duration) != 2:
            raise ValueError(f"stop_duration must be a (min, max) pair [s], got {self.stop_duration!r}")
        for value in self.stop_duration:
            check_number("stop_duration", value, allow_zero=True)
            check_at_most("stop_duration", value, MAX_STOP_DURATION, " s")
        if self.stop_duration[1] < self.stop_duration[0]:
            raise ValueError(f"stop_duration must satisfy min <= max, got {self.stop_duration!r}")
        object.__setattr__(self, "stop_duration", tuple(float(v) for v in self.stop_duration))
        if self.crowd == "replay":
            self._check_replay()

    def _check_replay(self) -> None:
        """``crowd="replay"``: the recording decides who walks, how fast and how many; its most people present at
        once must fit ``max_humans`` unless only the nearest are tracked."""
        population = (("num_humans", 6, "the recording decides how many people walk"),
                      ("observed", "all", "a recording's tracker chooses whom the robot observes: give "
                                          "crowd_kwargs['tracked']='nearest'"),
                      ("robot_visible", False, "recorded people cannot see the robot"),
                      ("human_speed", "fixed", "the recording decides how fast people walk"),
                      ("stop_probability", 0.0, "the recording decides who stops"))
        for name, default, why in population:
            value = getattr(self, name)
            if value != default:
                raise ValueError(f"{name} must stay {default!r} with crowd='replay' ({why}), got {value!r}")
        settings = self.crowd_kwargs
        most = settings.recording.max_present(settings.window, settings.lead_in)
        if most > self.max_humans and settings.tracked == "all":
            raise ValueError(f"max_humans: the recording {settings.path} has up to {most} people present at once, "
                             f"more than max_humans = {self.max_humans}; raise max_humans, choose a time_window, or "
                             "observe the nearest with crowd_kwargs['tracked']='nearest'")

    @property
    def max_human_speed(self) -> float:
        """The fastest preferred speed a person can have [m/s] (the observation's bounds)."""
        if self.crowd == "replay":  # (the recording's fastest)
            return max(self.crowd_kwargs.max_speed, self.human_v_pref)
        return MEASURED_SPEED[3] if self.human_speed == "measured" else self.human_v_pref

    def _check_placement(self) -> None:
        """``ValueError`` unless the largest crowd can be placed (starts and goals apart) with room to spare.

        The scenario draws starts at random and redraws on overlap; random sequential placement fills about
        75 % of a line (and 55 % of an area) before it jams, so at most 60 % of the circle's capacity
        (30 % of the square's) is accepted: a reset then never fails in practice.
        """
        _, n = self.humans_range
        if n == 0 or self.scenario == "warehouse":  # the warehouse checks its own pick faces
            return
        gap = 2 * self.human_radius + 0.2  # two pedestrians' starts (or goals) at least this far apart
        robot_gap = self.robot_radius + self.human_radius + 0.2
        if self.scenario == "circle_crossing":
            room = 2 * math.pi * self.circle_radius - 4 * robot_gap
            capacity = int(0.6 * room / gap) if room > 0 else 0
            where = f"the {self.circle_radius} m circle"
        else:
            capacity = int(0.3 * self.square_width**2 / gap**2)
            where = f"the {self.square_width} m square"
        if n > capacity:
            raise ValueError(f"num_humans: {n} pedestrians of radius {self.human_radius} m cannot be placed reliably on "
                             f"{where} beside a robot of radius {self.robot_radius} m (at most {capacity}); lower "
                             "num_humans or the radii, or enlarge the scene")

    @property
    def crowd_capacity(self) -> int:
        """The slots of the crowd's true state: ``max_humans``, or with ``observed="nearest"`` the largest crowd when it
        is larger (the observation keeps ``max_humans``)."""
        return max(self.max_humans, self.humans_range[1]) if self.observed == "nearest" else self.max_humans

    @property
    def humans_range(self) -> tuple[int, int]:
        """Inclusive (min, max) number of pedestrians."""
        n = self.num_humans
        if isinstance(n, (tuple, list)):
            if len(n) != 2:
                raise ValueError(f"num_humans must be an int or a (min, max) pair, got {n!r}")
            return n[0], n[1]
        return n, n

    @property
    def max_steps(self) -> int:
        """Number of steps before truncation (25 s / 0.25 s = 100)."""
        return round(self.time_limit / self.time_step)


@dataclass(frozen=True)
class RewardConfig:
    """Reward setting (paper Eq. 9-14).

    :param name: ``"crowdnav"`` (Table 3), ``"comfort"`` (APG_CRL) or ``"comfort_angular"`` (APG_CARL)
    :param success_reward: reward for reaching the goal (Eq. 12 prints 2; Table 3's returns imply 1)
    :param collision_penalty: reward on collision (negative)
    :param discomfort_dist: surface distance of the ``"crowdnav"`` discomfort term [m]
    :param discomfort_factor: slope of the discomfort term, times Δt
    :param comfort_person: d_person, comfort-ellipse semi-axis along the walking direction [m]
    :param comfort_side: d_side, comfort-ellipse semi-axis to the side [m]
    :param social_penalty: r_p of Eq. 11
    :param angular_penalty: r_angle of Eq. 13 (subtracted)
    :param angular_penalty_threshold: heading change per step that triggers Eq. 13 [rad]
    """

    name: str = "crowdnav"
    success_reward: float = 1.0
    collision_penalty: float = -0.25
    discomfort_dist: float = 0.2
    discomfort_factor: float = 0.5
    comfort_person: float = 1.2
    comfort_side: float = 0.7
    social_penalty: float = 0.02
    angular_penalty: float = 0.02
    angular_penalty_threshold: float = math.pi / 2

    def __post_init__(self) -> None:
        check_choice("reward", self.name, REWARDS)
        check_number("success_reward", self.success_reward, positive=False)
        check_number("collision_penalty", self.collision_penalty, positive=False)
        check_at_most("collision_penalty", self.collision_penalty, 0)  # a penalty, never a reward
        for name in ("discomfort_dist", "discomfort_factor", "social_penalty", "angular_penalty"):
            check_number(name, getattr(self, name), allow_zero=True)
        for name in ("comfort_person", "comfort_side", "angular_penalty_threshold"):
            check_number(name, getattr(self, name))
        for name, limit, unit in REWARD_LIMITS:
            check_at_most(name, abs(getattr(self, name)), limit, unit)
        for name, limit, unit in REWARD_MINIMA:
            check_at_least(name, getattr(self, name), limit, unit)
        _to_python_scalars(self)

    @property
    def uses_social(self) -> bool:
        return self.name in ("comfort", "comfort_angular")

    @property
    def uses_angular(self) -> bool:
        return self.name == "comfort_angular"

    @property
    def uses_discomfort(self) -> bool:
        return self.name == "crowdnav"
