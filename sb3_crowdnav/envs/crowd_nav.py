"""The ``CrowdNav-v0`` Gymnasium environment."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_crowdnav.sim.actions import N_ACTIONS, wrap
from sb3_crowdnav.sim.config import REWARDS, RewardConfig, SceneConfig
from sb3_crowdnav.sim.observation import HUMAN_DIM, Human, ObservationSchema, Robot
from sb3_crowdnav.sim.rewards import is_sharp_turn
from sb3_crowdnav.sim.simulator import CrowdSimulator

SCENE_KEYS = {f.name for f in dataclasses.fields(SceneConfig)}
REWARD_KEYS = {f.name for f in dataclasses.fields(RewardConfig)} - {"name"}
_INT_TYPES = (int, np.int64, np.int32)  # checked without building a Discrete.contains() call on the hot path


def split_env_kwargs(kwargs: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Split keyword arguments into scene and reward fields; unknown keys raise ``TypeError``."""
    unknown = sorted(set(kwargs) - SCENE_KEYS - REWARD_KEYS)
    if unknown:
        raise TypeError(
            f"unknown keyword argument(s) {unknown} for CrowdNavEnv; allowed: "
            f"{sorted(SCENE_KEYS | REWARD_KEYS | {'reward', 'gamma', 'render_mode'})}"
        )
    return ({k: v for k, v in kwargs.items() if k in SCENE_KEYS}, {k: v for k, v in kwargs.items() if k in REWARD_KEYS})


class CrowdNavEnv(gym.Env):
    """
    ## Description

    A robot crosses a circle of radius 4 m from (0, -4) to (0, 4) while pedestrians, driven by
    ORCA (the RVO2 library through ``pyrvo``), cross the same circle towards their antipodes
    (paper §3). By default the robot is invisible to the pedestrians: they do not
    yield, so the robot must avoid them.

    ## Action Space

    ``Discrete(80)``: 5 speeds ``v_pref * {0.2, 0.4, 0.6, 0.8, 1.0}`` x 16 directions. Action
    ``a`` has speed index ``a // 16`` and direction index ``a % 16``. Under ``"unicycle"``
    kinematics the direction ``k * 2π/16`` rotates the heading; under ``"holonomic"`` it is an
    absolute angle from the robot-to-goal axis (see :mod:`sb3_crowdnav.sim.actions`).

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
    under every reward), the discounted return and the number of pedestrians. A collision step's
    ``info`` (and its ``episode_stats``) says ``collision_with="human"`` (the warehouse also has
    ``"obstacle"``).

    ## Arguments

    ``gym.make("CrowdNav-v0", reward="comfort", num_humans=6, robot_visible=False, ...)``; every
    field of :class:`~sb3_crowdnav.sim.config.SceneConfig` and of
    :class:`~sb3_crowdnav.sim.config.RewardConfig` is a keyword argument. ``gamma`` (0.9) is the
    discount of the ``discounted_return`` episode statistic, Σ gamma^(t·Δt·v_pref) r_t.
    ``render_mode`` is ``"rgb_array"`` or ``"human"``.

    ## Version History

    * v0: initial version.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 4}

    def __init__(self, render_mode: str | None = None, reward: str = "crowdnav", gamma: float = 0.9,
                 **kwargs: Any) -> None:
        scene_kwargs, reward_kwargs = split_env_kwargs(kwargs)
        self._configure(render_mode, reward, gamma, scene_kwargs, reward_kwargs)
        if self.scene.scenario == "warehouse":
            raise ValueError("scenario 'warehouse' is CrowdNavWarehouse-v0's: gym.make('CrowdNavWarehouse-v0')")
        self.sim = CrowdSimulator(self.scene, self.reward_config)
        s = self.scene
        half = max(s.circle_radius + s.start_noise, s.square_width / 2)
        self._build_spaces(ObservationSchema(s.history_length, s.max_humans),
                           half + max(s.robot_v_pref, s.human_v_pref) * s.time_limit + 1.0)

    def _configure(self, render_mode: str | None, reward: str, gamma: float, scene_kwargs: dict[str, Any],
                   reward_kwargs: dict[str, Any]) -> None:
        """Check and store the settings every crowd env has (subclasses call it first)."""
        if reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        if isinstance(gamma, bool) or not isinstance(gamma, (int, float)) or not 0 < gamma <= 1:
            raise ValueError(f"gamma must be in (0, 1], got {gamma!r}")
        self.scene = SceneConfig(**scene_kwargs)
        self.reward_config = RewardConfig(name=reward, **reward_kwargs)
        self.gamma = float(gamma)
        self.render_mode = render_mode

    def _build_spaces(self, schema: ObservationSchema, pos_bound: float) -> None:
        """The Dict observation space of ``schema`` with positions within ±``pos_bound``, and the 80 actions."""
        s = self.scene
        vel_bound = max(s.robot_v_pref, s.human_v_pref) * 1.5 + 1.0
        rad_bound = max(s.robot_radius, s.human_radius) + 1.0
        self.schema = schema
        bounds = schema.bounds(pos_bound, vel_bound, rad_bound, s.robot_v_pref + 1.0)
        self.observation_space = spaces.Dict({key: spaces.Box(low, high, dtype=np.float32)
                                              for key, (low, high) in bounds.items()})
        self.action_space = spaces.Discrete(N_ACTIONS)
        self._pos_bound = pos_bound
        self._renderer = None
        self._reset_stats()

    # ------------------------------------------------------------------ helpers
    def _reset_stats(self) -> None:
        self._path_length = 0.0
        self._min_sep = np.inf
        self._discomfort_steps = 0
        self._discomfort_dist_sum = 0.0
        self._comfort_steps = 0
        self._comfort_dist_sum = 0.0
        self._heading_change = 0.0
        self._sharp_turns = 0
        self._discounted_return = 0.0
        self.trajectory: list[tuple[np.ndarray, np.ndarray]] = []

    def _static_obs(self) -> dict[str, np.ndarray]:
        """Keyword arguments of :meth:`ObservationSchema.observation` beyond the crowd (the warehouse's world)."""
        return {}

    def _simulate(self, action: int):
        """One step of the simulator: its reward terms and whether the robot hit a static obstacle."""
        return self.sim.step(action), False

    def _render_extras(self) -> dict[str, Any]:
        """More to draw than the crowd (the warehouse's racks, route and standing pickers)."""
        return {}

    @property
    def max_steps(self) -> int:
        """Steps after which the episode is truncated."""
        return self.scene.max_steps

    def _get_obs(self) -> dict[str, np.ndarray]:
        sim = self.sim
        obs = self.schema.observation(sim.robot, sim.history, sim.mask, **self._static_obs())
        robot, humans = obs["robot"], obs["humans"]
        b = np.float32(self._pos_bound)
        # Agents cannot leave the bounds within the time limit (|start| + v_pref * time_limit < bound), so
        # the clips below are a guard that costs two reductions rather than two clips on every step.
        if not (-b <= robot.min() and robot.max() <= b):
            robot[Robot.POS] = np.clip(robot[Robot.POS], -b, b)
        if not (-b <= humans.min() and humans.max() <= b):
            flat = humans.reshape(-1, HUMAN_DIM)
            flat[:, Human.POS] = np.clip(flat[:, Human.POS], -b, b)
        return obs

    def _record(self) -> None:
        sim = self.sim
        self.trajectory.append((sim.robot.copy(), sim.history[-1, : sim.num_humans].copy()))

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if options:
            raise ValueError(f"reset options {sorted(options)} are not supported (the scene is set at construction)")
        super().reset(seed=seed)
        self.sim.reset(self.np_random)
        self._reset_stats()
        self._record()
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), {"num_humans": self.sim.num_humans}

    def step(self, action):
        if not (type(action) in _INT_TYPES and 0 <= action < N_ACTIONS) and not self.action_space.contains(action):
            raise ValueError(f"action must be an int in [0, {N_ACTIONS}), got {action!r}")
        sim = self.sim
        prev = sim.robot.tolist()
        terms, hit_obstacle = self._simulate(int(action))
        robot = sim.robot.tolist()
        reward = float(terms.reward)
        success, collision = bool(terms.success), bool(terms.collision)
        terminated = success or collision
        truncated = not terminated and sim.steps >= self.max_steps
        outcome = "success" if success else "collision" if collision else "timeout" if truncated else "running"

        min_dist = float(terms.min_distance)
        (x0, y0), (x1, y1) = prev[Robot.POS], robot[Robot.POS]
        self._path_length += math.hypot(x1 - x0, y1 - y0)
        self._min_sep = min(self._min_sep, min_dist)
        if min_dist < self.reward_config.discomfort_dist:
            self._discomfort_steps += 1
            self._discomfort_dist_sum += min_dist
        if terms.in_comfort_zone:
            self._comfort_steps += 1
            self._comfort_dist_sum += min_dist
        turn = wrap(robot[Robot.HEADING] - prev[Robot.HEADING])
        self._heading_change += abs(turn)
        self._sharp_turns += is_sharp_turn(turn, self.reward_config)
        self._discounted_return += self.gamma ** ((sim.steps - 1) * self.scene.time_step * self.scene.robot_v_pref) * reward
        self._record()

        info: dict[str, Any] = {
            "is_success": success,
            "outcome": outcome,
            "reward_success": float(terms.success_term),
            "reward_collision": float(terms.collision_term),
            "reward_discomfort": float(terms.discomfort_term),
            "reward_social": float(terms.social_term),
            "reward_angular": float(terms.angular_term),
            "min_distance": min_dist,
            "in_comfort_zone": bool(terms.in_comfort_zone),
            "time": sim.time,
        }
        if collision:
            info["collision_with"] = "obstacle" if hit_obstacle else "human"
        if terminated or truncated:
            info["episode_stats"] = {
                "outcome": outcome,
                "navigation_time": sim.time,
                "path_length": self._path_length,
                "min_separation": self._min_sep,
                "discomfort_frequency": self._discomfort_steps / sim.steps,
                "comfort_zone_time": self._comfort_steps * self.scene.time_step,
                "discomfort_separation": (self._discomfort_dist_sum / self._discomfort_steps
                                          if self._discomfort_steps else math.nan),
                "comfort_zone_separation": (self._comfort_dist_sum / self._comfort_steps
                                            if self._comfort_steps else math.nan),
                "heading_change": self._heading_change,
                "sharp_turns": self._sharp_turns,
                "discounted_return": self._discounted_return,
                "num_humans": sim.num_humans,
            }
            if collision:
                info["episode_stats"]["collision_with"] = info["collision_with"]
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), reward, terminated, truncated, info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human' to gym.make")
            return None
        from sb3_crowdnav.envs.rendering import CrowdRenderer  # lazy: matplotlib only when rendering

        if self._renderer is None:
            self._renderer = CrowdRenderer(self.scene, human=self.render_mode == "human")
        frame = self._renderer.draw(self.trajectory, self.sim.human_goals, self.sim.robot[Robot.GOAL], self.sim.time,
                                    **self._render_extras())
        return None if self.render_mode == "human" else frame  # Gymnasium: "human" draws on screen, returns None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
