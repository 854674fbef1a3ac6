"""``CrowdEnvBase``: what every crowd env does, whatever its world (the open floor, the warehouse).

A crowd env is a simulator (``reset(rng)``, ``step(action) -> RewardTerms``, the robot's state, the crowd's history)
seen through an :class:`~sb3_crowdnav.sim.observation.ObservationSchema`. The base holds the spaces, the seeding,
the step template (simulate, reward, end, info), the episode statistics, the trajectory and the rendering; a
subclass builds its settings and its simulator and says what its world adds (:meth:`CrowdEnvBase._static_obs`,
:meth:`CrowdEnvBase._extra_info` and the like). Neither env knows the other.

Every keyword argument of an env either changes its episodes or is refused at construction:
:func:`refuse_unused` raises for an option the chosen setting never reads (a reward weight of another reward, the
square's width on the circle), so that a typo in an experiment's settings cannot pass for a result.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_crowdnav.envs.statistics import EpisodeStatistics
from sb3_crowdnav.sim.actions import ACTION_SETS
from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
from sb3_crowdnav.sim.geometry import within
from sb3_crowdnav.sim.observation import HUMAN_DIM, Human, ObservationSchema, Robot
from sb3_crowdnav.sim.rewards import RewardTerms
from sb3_crowdnav.sim.validation import check_range
from sb3_crowdnav.sim.world import World

SCENE_KEYS = {f.name for f in dataclasses.fields(SceneConfig)}
REWARD_KEYS = {f.name for f in dataclasses.fields(RewardConfig)} - {"name"}  # the env spells ``name`` ``reward=``
ENV_KEYS = {"reward", "gamma", "render_mode"}  # the env's own arguments beside the configs' fields
# the rewards that read each weight (the other weights and distances feed the info and the episode statistics too)
REWARD_WEIGHTS = {
    "discomfort_factor": ("crowdnav",),
    "social_penalty": ("comfort", "comfort_angular"),
    "angular_penalty": ("comfort_angular",),
}
_INT_TYPES = (int, np.int64, np.int32)  # checked without building a Discrete.contains() call on the hot path


def split_env_kwargs(kwargs: Mapping[str, Any], env_name: str,
                     extra: Iterable[str] = ()) -> tuple[dict[str, Any], dict[str, Any]]:
    """Split keyword arguments into scene and reward fields; ``TypeError`` for a key that is neither nor in
    ``extra`` (the env's own settings, which the caller takes out)."""
    allowed = SCENE_KEYS | REWARD_KEYS | set(extra)
    unknown = sorted(set(kwargs) - allowed)
    if unknown:
        raise TypeError(f"unknown keyword argument(s) {unknown} for {env_name}; allowed: {sorted(allowed | ENV_KEYS)}")
    return ({k: v for k, v in kwargs.items() if k in SCENE_KEYS}, {k: v for k, v in kwargs.items() if k in REWARD_KEYS})


def check_env_arguments(render_modes: list[str], render_mode: str | None, gamma: float) -> None:
    """``ValueError`` for a render mode the env does not have or a discount outside (0, 1] (``TypeError``: not a number)."""
    if render_mode is not None and render_mode not in render_modes:
        raise ValueError(f"render_mode must be one of {render_modes} or None, got {render_mode!r}")
    check_range("gamma", gamma, 0, 1, low_open=True)


def unused_reward_weights(reward: RewardConfig) -> dict[str, str]:
    """The reward weights ``reward`` never reads, each with the reason."""
    return {name: f"is a weight of reward {' and '.join(map(repr, rewards))} only; reward={reward.name!r} never reads it"
            for name, rewards in REWARD_WEIGHTS.items() if reward.name not in rewards}


def refuse_unused(given: Iterable[str], unused: Mapping[str, str], env_name: str) -> None:
    """``ValueError`` for the first of the ``given`` keyword arguments that the env's setting never reads."""
    for name in sorted(given):
        if name in unused:
            raise ValueError(f"{name} has no effect in {env_name}: it {unused[name]}")


class CrowdEnvBase(gym.Env):
    """The Gymnasium side of a crowd simulator: spaces, seeding, the step template, statistics and rendering.

    :param scene: the crowd's settings
    :param reward: the reward setting
    :param sim: the simulator (a :class:`~sb3_crowdnav.sim.simulator.CrowdSimulator` or one shaped like it)
    :param schema: the observation's shapes
    :param pos_bound: [m] positions in the observation lie within ± this (the space's bounds)
    :param gamma: discount of the ``discounted_return`` statistic
    :param render_mode: ``"rgb_array"``, ``"human"`` or None
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 4}

    def __init__(self, scene: SceneConfig, reward: RewardConfig, sim: Any, schema: ObservationSchema,
                 pos_bound: float, gamma: float = 0.9, render_mode: str | None = None) -> None:
        super().__init__()
        self.scene = scene
        self.reward_config = reward
        self.sim = sim
        self.gamma = float(gamma)
        self.render_mode = render_mode
        self.schema = schema
        vel_bound = max(scene.robot_v_pref, scene.max_human_speed) * 1.5 + 1.0
        rad_bound = max(scene.robot_radius, scene.human_radius) + 1.0
        bounds = schema.bounds(pos_bound, vel_bound, rad_bound, scene.robot_v_pref + 1.0)
        self.observation_space = spaces.Dict({key: spaces.Box(low, high, dtype=np.float32)
                                              for key, (low, high) in bounds.items()})
        self.n_actions = ACTION_SETS[scene.actions]
        self.action_space = spaces.Discrete(self.n_actions)
        self._pos_bound = pos_bound
        self._bound32 = float(np.float32(pos_bound))  # the bound as the float32 observation compares with it
        # the separation reported while no one is present: the diagonal of the observable positions' box, farther
        # than any two agents can be (finite in info; the metrics leave episodes without people out of the gap)
        self.no_one_distance = float(2 * np.sqrt(2) * pos_bound)
        self.stats = EpisodeStatistics(reward, self.gamma, scene.time_step, scene.robot_v_pref, self.no_one_distance)
        self.trajectory: list[tuple[np.ndarray, np.ndarray]] = []  # (robot (9,), humans (n, 5)) per state
        self._renderer = None

    # ------------------------------------------------------------------ what a world adds
    @property
    def world(self) -> World:
        """What a model acting in this env must agree on with it (checked by every loader and the runner)."""
        s = self.scene
        return World(time_step=s.time_step, kinematics=s.kinematics, rotation_range=s.rotation_range,
                     actions=s.actions, max_acceleration=s.max_acceleration, max_turn_rate=s.max_turn_rate,
                     reward=self.reward_config)

    @property
    def max_steps(self) -> int:
        """Steps after which the episode is truncated (the simulator's: fixed, or set per episode)."""
        return self.sim.max_steps

    def _static_obs(self) -> dict[str, np.ndarray]:
        """Keyword arguments of :meth:`ObservationSchema.observation` beyond the crowd (a world's static part)."""
        return {}

    def _reset_info(self) -> dict[str, Any]:
        """More of the reset's ``info`` than the number of pedestrians."""
        return {}

    def _extra_info(self) -> dict[str, Any]:
        """More of a step's ``info`` than the reward terms."""
        return {}

    def _extra_stats(self) -> dict[str, Any]:
        """More of ``info["episode_stats"]`` than :class:`EpisodeStatistics` (the world's own metrics)."""
        return {}

    def _render_extras(self) -> dict[str, Any]:
        """More to draw than the crowd (the warehouse's racks, route and standing pickers)."""
        return {}

    # ------------------------------------------------------------------ observation
    def _get_obs(self) -> dict[str, np.ndarray]:
        sim = self.sim
        obs = self.schema.observation(sim.robot, *sim.observed(), **self._static_obs())
        robot, humans = obs["robot"], obs["humans"]
        # Agents cannot leave the bounds within the time limit (|start| + v_pref * time_limit < bound), so
        # the clips below are a guard that costs one compiled test rather than two clips on every step.
        b = np.float32(self._pos_bound)
        if not within(robot, self._bound32):
            robot[Robot.POS] = np.clip(robot[Robot.POS], -b, b)
        if not within(humans, self._bound32):
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
        self.stats.reset()
        self.trajectory = []
        self._record()
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), {"num_humans": self.sim.num_humans, **self._reset_info()}

    def step(self, action):
        """One step of Δt: simulate, reward, end (success or collision terminates, the time limit truncates), info."""
        if not (type(action) in _INT_TYPES and 0 <= action < self.n_actions) and not self.action_space.contains(action):
            raise ValueError(f"action must be an int in [0, {self.n_actions}), got {action!r}")
        sim = self.sim
        before = sim.robot.tolist()
        terms = sim.step(int(action))  # simulate
        reward = float(terms.reward)  # reward
        self.stats.update(before, sim.robot.tolist(), terms, reward, sim.history[-1], sim.mask)  # the true people
        self._record()
        success, collision = bool(terms.success), bool(terms.collision)  # end
        terminated = success or collision
        truncated = not terminated and sim.steps >= self.max_steps  # a timeout is truncation: SB3 bootstraps it
        outcome = "success" if success else "collision" if collision else "timeout" if truncated else "running"
        info = self._info(terms, outcome)  # info
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), reward, terminated, truncated, info

    def _info(self, terms: RewardTerms, outcome: str) -> dict[str, Any]:
        """A step's ``info``: the outcome, every reward term, the separation; the statistics on the last step."""
        info: dict[str, Any] = {
            "is_success": outcome == "success",
            "outcome": outcome,
            "reward_success": float(terms.success_term),
            "reward_collision": float(terms.collision_term),
            "reward_discomfort": float(terms.discomfort_term),
            "reward_social": float(terms.social_term),
            "reward_angular": float(terms.angular_term),
            "min_distance": min(float(terms.min_distance), self.no_one_distance),
            "in_comfort_zone": bool(terms.in_comfort_zone),
            "time": self.sim.time,
        }
        if outcome == "collision":
            info["collision_with"] = "obstacle" if self.sim.hit_obstacle else "human"
        info.update(self._extra_info())
        if outcome != "running":
            stats = self.stats.summary(outcome, self.sim.num_humans)
            if outcome == "collision":
                stats["collision_with"] = info["collision_with"]
            info["episode_stats"] = {**stats, **self._extra_stats()}
        return info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human' to gym.make")
            return None
        from sb3_crowdnav.envs.rendering import CrowdRenderer  # lazy: matplotlib only when rendering

        if self._renderer is None:
            self._renderer = CrowdRenderer(self.scene, human=self.render_mode == "human")
        sim = self.sim
        unseen = None if sim.sensor is None else ~sim.seen_people  # who the robot does not see
        frame = self._renderer.draw(self.trajectory, sim.human_goals, sim.robot[Robot.GOAL], sim.time, unseen=unseen,
                                    **self._render_extras())
        return None if self.render_mode == "human" else frame  # Gymnasium: "human" draws on screen, returns None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
