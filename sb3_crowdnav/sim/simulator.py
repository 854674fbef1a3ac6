"""``CrowdSimulator``: one robot among ORCA pedestrians, no RL API (numpy + pyrvo only)."""

from __future__ import annotations

import numpy as np

from sb3_crowdnav.sim.actions import N_ACTIONS, action_table, apply_action, wrap_angle
from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
from sb3_crowdnav.sim.layout import HUMAN_DIM, ROBOT_DIM, Human, Robot
from sb3_crowdnav.sim.orca import OrcaCrowd, preferred_velocity
from sb3_crowdnav.sim.rewards import RewardTerms, compute_reward, walking_direction
from sb3_crowdnav.sim.scenarios import generate_scenario


class CrowdSimulator:
    """State of one episode and its dynamics.

    The state is kept in observation form: ``robot`` (9,) and the pedestrian history
    ``history`` (T, max_humans, 5), oldest first, padded slots all zero with ``mask`` 0.
    """

    def __init__(self, scene: SceneConfig, reward: RewardConfig) -> None:
        self.scene = scene
        self.reward_cfg = reward
        self.speeds, self.directions = action_table(scene.robot_v_pref, scene.rotation_range)
        self.robot = np.zeros(ROBOT_DIM)
        self.history = np.zeros((scene.history_length, scene.max_humans, HUMAN_DIM))
        self.mask = np.zeros(scene.max_humans, dtype=bool)
        self.human_goals = np.zeros((0, 2))
        self.num_humans = 0
        self.steps = 0
        self._crowd: OrcaCrowd | None = None

    # ------------------------------------------------------------------ reset
    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode drawn from ``rng``."""
        cfg = self.scene
        lo, hi = cfg.humans_range
        n = int(rng.integers(lo, hi + 1))
        sc = generate_scenario(cfg, n, rng)
        self.num_humans = n
        self.robot = np.zeros(ROBOT_DIM)
        self.robot[Robot.POS] = sc.robot_start
        self.robot[Robot.RADIUS] = cfg.robot_radius
        self.robot[Robot.GOAL] = sc.robot_goal
        self.robot[Robot.V_PREF] = cfg.robot_v_pref
        self.robot[Robot.HEADING] = sc.robot_heading
        current = np.zeros((cfg.max_humans, HUMAN_DIM))
        current[:n, Human.POS] = sc.human_starts
        current[:n, Human.RADIUS] = cfg.human_radius
        self.history = np.repeat(current[None], cfg.history_length, axis=0)
        self.mask = np.zeros(cfg.max_humans, dtype=bool)
        self.mask[:n] = True
        self.human_goals = sc.human_goals
        self.steps = 0
        self._crowd = None
        if cfg.human_policy == "orca" and n > 0:
            robot = None
            if cfg.robot_visible:
                robot = (sc.robot_start, np.zeros(2), cfg.robot_radius)
            self._crowd = OrcaCrowd(cfg, sc.human_starts, np.full(n, cfg.human_radius), np.full(n, cfg.human_v_pref),
                                    robot)

    # ------------------------------------------------------------------ step
    def _move_humans(self) -> tuple[np.ndarray, np.ndarray]:
        cfg, n = self.scene, self.num_humans
        pos = self.history[-1, :n, Human.POS]
        pref = preferred_velocity(pos, self.human_goals, cfg.human_v_pref)
        if self._crowd is None:  # "linear": constant preferred velocity, exact integration
            return pos + pref * cfg.time_step, pref
        robot_state = (self.robot[Robot.POS].copy(), self.robot[Robot.VEL].copy()) if cfg.robot_visible else None
        return self._crowd.step(pref, robot_state)

    def step(self, action: int) -> RewardTerms:
        """Apply ``action`` (0..79) and advance the pedestrians; return the reward terms of the transition."""
        cfg, n = self.scene, self.num_humans
        if not (0 <= action < N_ACTIONS):
            raise ValueError(f"action must be in [0, {N_ACTIONS}), got {action!r}")
        pos0 = self.robot[Robot.POS].copy()
        heading0 = float(self.robot[Robot.HEADING])
        new_pos, new_heading, velocity = apply_action(
            pos0, np.float64(heading0), self.robot[Robot.GOAL], self.speeds[action], self.directions[action],
            cfg.kinematics, cfg.time_step,
        )
        human_pos0 = self.history[-1, :, Human.POS].copy()
        new_hpos, new_hvel = self._move_humans() if n else (np.zeros((0, 2)), np.zeros((0, 2)))

        latest = self.history[-1].copy()
        latest[:n, Human.POS] = new_hpos
        latest[:n, Human.VEL] = new_hvel
        self.history = np.concatenate([self.history[1:], latest[None]], axis=0)
        self.robot[Robot.POS] = new_pos
        self.robot[Robot.VEL] = velocity
        self.robot[Robot.HEADING] = float(new_heading)
        self.steps += 1

        directions = walking_direction(self.history[:, :, Human.VEL], latest[:, Human.POS], new_pos)
        return compute_reward(
            self.reward_cfg, cfg.time_step, pos0, new_pos, np.float64(heading0), np.float64(new_heading),
            self.robot[Robot.GOAL], np.float64(cfg.robot_radius), human_pos0, latest[:, Human.POS], directions,
            latest[:, Human.RADIUS], self.mask,
        )

    @property
    def time(self) -> float:
        return self.steps * self.scene.time_step

    def heading_change(self, previous_heading: float) -> float:
        return float(abs(wrap_angle(self.robot[Robot.HEADING] - previous_heading)))
