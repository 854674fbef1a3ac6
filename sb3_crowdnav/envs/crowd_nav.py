"""The ``CrowdNav-v0`` Gymnasium environment: a robot crossing an open floor among ORCA pedestrians."""

from __future__ import annotations

import dataclasses
from typing import Any

from sb3_crowdnav.envs.base import (
    ENV_KEYS,
    REWARD_KEYS,
    SCENE_KEYS,
    CrowdEnvBase,
    check_env_arguments,
    refuse_unused,
    split_env_kwargs,
    unused_reward_weights,
)
from sb3_crowdnav.sim.config import MAX_PROGRESS_REWARD, RewardConfig, SceneConfig
from sb3_crowdnav.sim.observation import ObservationSchema
from sb3_crowdnav.sim.simulator import CrowdSimulator
from sb3_crowdnav.sim.validation import check_choice, check_range
from sb3_crowdnav.sim.world import World

ORCA_KEYS = ("orca_neighbor_dist", "orca_max_neighbors", "orca_time_horizon")  # what ORCA pedestrians read
# what a recording decides (crowd="replay")
REPLAY_DECIDES = ("num_humans", "robot_visible", "human_speed", "human_v_pref", "stop_probability", "stop_duration")
OPEN_FLOOR_KEYS = ("progress_reward",)  # the open floor's own keyword arguments beside the configs' and the envs'


class CrowdNavEnv(CrowdEnvBase):
    """
    ## Description

    A robot crosses a circle of radius 4 m from (0, -4) to (0, 4) while pedestrians, driven by
    ORCA (the RVO2 library through ``pyrvo``; another crowd model with ``crowd=``), cross the same
    circle towards their antipodes (paper §3). By default the robot is invisible to the pedestrians: they do not
    yield, so the robot must avoid them.

    ## Action Space

    ``Discrete(80)``: 5 speeds ``v_pref * {0.2, 0.4, 0.6, 0.8, 1.0}`` x 16 directions. Action
    ``a`` has speed index ``a // 16`` and direction index ``a % 16``. Under ``"unicycle"``
    kinematics the direction ``k * 2π/16`` rotates the heading; under ``"holonomic"`` it is an
    absolute angle from the robot-to-goal axis (see :mod:`sb3_crowdnav.sim.actions`). ``actions="with_stop"`` adds a
    stop, action 80 (``Discrete(81)``). ``max_acceleration`` [m/s²] and ``max_turn_rate`` [rad/s] (default None:
    unlimited, the paper's robot) clip each command to what the robot reaches from its current velocity within the
    step (the rule of :mod:`sb3_crowdnav.sim.actions`; ``max_turn_rate`` is refused with ``"holonomic"``).

    ## Observation Space

    A ``Dict`` in world coordinates (everything the lookahead needs; float32):

    ===============  =====================  ====================================================================
    key              shape                  content
    ===============  =====================  ====================================================================
    ``robot``        (9,)                   px, py, vx, vy, radius, gx, gy, v_pref, heading
    ``humans``       (T * max_humans * 5,)  px, py, vx, vy, radius of every slot for the last T = 5 steps (1)
    ``humans_mask``  (max_humans,)          1 for a present pedestrian, 0 for a padded slot (whose values are 0)
    ===============  =====================  ====================================================================

    (1) oldest first, flat; view it as (T, max_humans, 5). At reset the first state is repeated.

    Positions are bounded by ``±(scene half-size + v_pref * time_limit + 1)`` m.

    ## Rewards

    ``reward="crowdnav"`` (default; the field's reward, Table 3), ``"comfort"`` (APG_CRL, Eq. 9-12)
    or ``"comfort_angular"`` (APG_CARL, + Eq. 13). See :mod:`sb3_crowdnav.sim.rewards` for every
    term and the decisions on the paper's ambiguities. ``info`` reports each term separately.

    ``progress_reward`` k > 0 (default 0: the paper's reward, no shaping) adds goal-progress shaping, beyond the paper:
    k x (the metres the robot gained on its goal during the step; lost metres cost as much), zero on terminal steps,
    the warehouse's route-progress term with the goal as the only waypoint. ``info["reward_progress"]`` reports it
    (only when k > 0: the default ``info`` is the paper env's).

    ## Starting State

    Robot at (0, -R) facing its goal (0, R), at rest. Pedestrians start on the circle (±0.5 m
    noise per axis) with goals at the antipodes; starts and goals at least two radii + 0.2 m apart.

    ## Episode End

    Terminated on collision (the robot and a pedestrian overlap at any moment of the step) or
    success (robot centre within its radius of the goal). Truncated at the time limit (25 s =
    100 steps) — the env truncates by itself, so changing ``time_limit`` changes the episode length.
    On the last step ``info["episode_stats"]`` holds the episode's metrics: outcome, navigation time,
    path length, minimum separation, discomfort frequency, comfort-zone time, the mean separation
    over the discomfort steps and over the comfort-zone steps, the total heading change, the number
    of sharp turns (steps turning by at least ``angular_penalty_threshold``, Eq. 13's trigger, counted
    under every reward), the discounted return, the number of pedestrians and of steps with someone present, and
    the safety figures from the people's true state (minimum time-to-collision capped at 10 s, near misses, speed
    near people, peak acceleration and turn rate; :meth:`~sb3_crowdnav.envs.statistics.EpisodeStatistics.summary`).
    A collision step's ``info`` (and its ``episode_stats``) says ``collision_with="human"`` (the warehouse also has
    ``"obstacle"``).

    ## Arguments

    ``gym.make("CrowdNav-v0", reward="comfort", num_humans=6, robot_visible=False, ...)``; every
    field of :class:`~sb3_crowdnav.sim.config.SceneConfig` and of
    :class:`~sb3_crowdnav.sim.config.RewardConfig` is a keyword argument. ``gamma`` (0.9) is the
    discount of the ``discounted_return`` episode statistic, Σ gamma^(t·Δt·v_pref) r_t.
    ``render_mode`` is ``"rgb_array"`` or ``"human"``. ``scenario`` is ``"circle_crossing"`` (default) or
    ``"square_crossing"`` (``CrowdNavSquare-v0``). ``progress_reward`` [1/m] in [0, 10] (default 0) is the
    goal-progress shaping (Rewards above); a model trained with it acts unchanged without it (a reward is not part of
    the motion), but further training needs an env with the same value.

    The crowd (:mod:`sb3_crowdnav.sim.crowd`, :mod:`sb3_crowdnav.sim.population`); the defaults are the paper's:

    * ``crowd``: the model that moves the people, ``"orca"`` (default; RVO2), ``"social_force"`` (Helbing's social
      force model, JuPedSim's; installed apart, see the installation docs) or ``"linear"`` (straight to the goal,
      seeing no one; for tests). ``crowd_kwargs``: a dict of the model's settings, each checked, an unknown one
      refused: ``"orca"`` takes ``safety_space`` [m] (extra radius each person's ORCA keeps, default 0),
      ``"social_force"`` the fields of :class:`~sb3_crowdnav.sim.crowd_settings.SocialForceCrowdSettings`
      (``person_strength``, ``wall_strength``, ``force_range``, ``relaxation_time``, ``sub_steps``; with it the ORCA
      fields and a share for ``robot_visible`` are refused), ``"linear"`` none. ``human_policy`` is the old name
      of ``crowd``, kept for existing scripts (the same values and effect); passing both is refused. ``"replay"``
      replays recorded people (``crowd_kwargs``: ``path``, ``frame_rate`` for the ETH/UCY text format,
      ``robot_start``/``robot_goal``, ``start_time``, ``time_window``, ``crossing_length``, ``tracked``; see the docs'
      replay page); the recording then decides ``num_humans`` and the population, which are refused.
    * ``human_speed``: ``"fixed"`` (default: everyone at ``human_v_pref``, 1 m/s) or ``"measured"``: each person's
      preferred speed drawn at reset from Normal(1.34, 0.26) m/s clipped to [0.5, 2.0], the desired walking speeds
      of Helbing et al. (2001, after Henderson 1971 and Weidmann 1993); ``human_v_pref`` is then refused.
    * ``stop_probability`` (default 0): the probability that a person stops once on its walk, at a time drawn
      uniformly over the time it needs to walk straight to its goal, and stands (preferred velocity zero; ORCA
      people still step aside) for ``stop_duration`` = (min, max) seconds, drawn uniformly (default (2, 8));
      ``stop_duration`` is refused while ``stop_probability`` is 0.
    * ``robot_visible``: False (default: no one yields to the robot), True (everyone sees it: the robot is one more
      ORCA agent, moved each step to its actual position and velocity), or a share in [0, 1]: each person sees it
      with that probability, drawn at reset; the others ignore it (0.0 and 1.0 are False and True).
    * ``num_humans`` may be 0 (or a range from 0): the observation's mask is all 0, and a step's
      ``info["min_distance"]`` (and ``episode_stats["min_separation"]``) is the diagonal of the observation's
      position box, ``2·√2·pos_bound`` (``env.no_one_distance``, 87.7 m in ``CrowdNav-v0``), finite and farther than
      anyone can be.
    * ``people_sensor_range`` [m] (default None: unlimited), ``people_sensor_noise`` [m] (σ on each observed
      position, default 0) and ``people_sensor_latency`` [steps] (default 0): what the robot sees of the people
      (:mod:`sb3_crowdnav.sim.sensing`; ``humans_mask`` is 1 for those seen now, an unseen slot is zeros over the
      window). The people, rewards and collisions stay those of the true state; the noise is drawn from a child of
      the episode's generator, so no other draw moves.

    * ``observed``: who fills the observation's ``max_humans`` slots, ``"all"`` (default: everyone has a slot of
      their own; ``num_humans`` <= ``max_humans``) or ``"nearest"``: the ``max_humans`` people nearest to the robot
      among those the sensor sees, each keeping their slot while among them, so that more people than slots may walk
      (``num_humans`` up to what the scenario can place); rewards and collisions count with everyone.

    Random draws come from the env's ``np_random`` at reset, after the scenario's and only for a setting away from
    its default (speeds, visibility, stops in this order), so the default episodes are the paper env's.

    Every argument changes the episodes or is refused at construction (``ValueError`` naming it) where the
    setting never reads it: ``square_width`` on the circle, ``circle_radius`` and ``start_noise`` on the square,
    ``orca_time_horizon_obst`` (no static obstacles here), the ORCA fields and ``robot_visible`` with
    ``crowd="linear"``, ``human_v_pref`` with ``human_speed="measured"``, ``stop_duration`` with
    ``stop_probability=0``, and a reward weight of another reward (``discomfort_factor`` is ``"crowdnav"``'s,
    ``social_penalty`` the comfort rewards', ``angular_penalty`` ``"comfort_angular"``'s).

    ## Version History

    * v0: initial version. Since the goal-progress shaping, ``progress_reward`` (its default 0 plays the earlier
      episodes, rewards and ``info``).
    """

    SCENARIOS = ("circle_crossing", "square_crossing")  # the open floor's; the warehouse is another env

    def __init__(self, render_mode: str | None = None, reward: str = "crowdnav", gamma: float = 0.9,
                 progress_reward: float = 0.0, **kwargs: Any) -> None:
        name = type(self).__name__
        check_env_arguments(self.metadata["render_modes"], render_mode, gamma)
        check_range("progress_reward", progress_reward, 0, MAX_PROGRESS_REWARD)  # [1/m]
        self.progress_reward = float(progress_reward)
        scene_kwargs, reward_kwargs = split_env_kwargs(kwargs, name, OPEN_FLOOR_KEYS)
        if "crowd" in kwargs and "human_policy" in kwargs:
            raise ValueError("human_policy is the old name of crowd: pass crowd only")
        check_choice("scenario", scene_kwargs.get("scenario", "circle_crossing"), self.SCENARIOS)
        scene = SceneConfig(**scene_kwargs)
        reward_config = RewardConfig(name=reward, **reward_kwargs)
        refuse_unused(kwargs, {**unused_options(scene), **unused_reward_weights(reward_config)}, name)
        half = max(scene.circle_radius + scene.start_noise, scene.square_width / 2)
        if scene.crowd == "replay":  # the recording's frame
            half = scene.crowd_kwargs.extent
        # no agent gets farther than its start plus v_pref x time_limit: the clip in _get_obs is only a guard
        pos_bound = half + max(scene.robot_v_pref, scene.max_human_speed) * scene.time_limit + 1.0
        super().__init__(scene, reward_config, CrowdSimulator(scene, reward_config, self.progress_reward),
                         ObservationSchema(scene.history_length, scene.max_humans), pos_bound, gamma, render_mode)

    @classmethod
    def option_names(cls) -> set[str]:
        """Every keyword argument the constructor knows (each changes the episodes or is refused)."""
        return SCENE_KEYS | REWARD_KEYS | ENV_KEYS | set(OPEN_FLOOR_KEYS)

    @property
    def world(self) -> World:
        """The crowd's world with the goal-progress shaping."""
        return dataclasses.replace(super().world, progress_reward=self.progress_reward)

    def _extra_info(self) -> dict[str, Any]:
        return {"reward_progress": self.sim.progress_term} if self.progress_reward else {}


def unused_options(scene: SceneConfig) -> dict[str, str]:
    """The scene fields the open floor never reads in ``scene``'s setting, each with the reason."""
    unused = {"orca_time_horizon_obst": "is ORCA's horizon for static obstacles, and the open floor has none"}
    if scene.scenario == "circle_crossing":
        unused["square_width"] = "is the side of scenario 'square_crossing'; the circle never reads it"
    else:
        for key in ("circle_radius", "start_noise"):
            unused[key] = "sets scenario 'circle_crossing'; the square never reads it"
    if scene.crowd == "linear":
        for key in (*ORCA_KEYS, "robot_visible"):
            unused[key] = "concerns ORCA pedestrians; crowd='linear' walk straight to their goals"
    elif scene.crowd == "social_force":
        for key in ORCA_KEYS:
            unused[key] = "concerns ORCA pedestrians; crowd='social_force' sets its forces in crowd_kwargs"
    if scene.human_speed == "measured":
        unused["human_v_pref"] = "is the speed of human_speed='fixed'; 'measured' draws each person's speed"
    if scene.stop_probability == 0:
        unused["stop_duration"] = "is how long stopping people stand, and with stop_probability=0 no one stops"
    if scene.crowd == "replay":
        for key in (*ORCA_KEYS, *REPLAY_DECIDES):
            unused[key] = "is decided by the recording with crowd='replay'"
        for key in ("circle_radius", "start_noise", "square_width"):
            unused[key] = "places the scenario's people, and crowd='replay' replaces them by the recording's"
    return unused


__all__ = ["CrowdNavEnv"]
