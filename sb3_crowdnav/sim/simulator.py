"""``CrowdSimulator``: one robot among a crowd (a :mod:`~sb3_crowdnav.sim.crowd` model), no RL API (numpy + pyrvo only)."""

from __future__ import annotations

import numpy as np

from sb3_crowdnav.sim.actions import action_table, move, step_limits
from sb3_crowdnav.sim.config import MAX_PROGRESS_REWARD, RewardConfig, SceneConfig
from sb3_crowdnav.sim.crowd import CrowdModel, RecordedCrowd, RobotAgent, make_crowd
from sb3_crowdnav.sim.observation import HUMAN_DIM, ROBOT_DIM, Human, Robot
from sb3_crowdnav.sim.population import People, PreferredVelocities, draw_people
from sb3_crowdnav.sim.rewards import RewardTerms, transition_terms, walking_directions_step, with_route_progress
from sb3_crowdnav.sim.scenarios import generate_scenario
from sb3_crowdnav.sim.sensing import PeopleSensor, sensing_on
from sb3_crowdnav.sim.validation import check_range


class CrowdSimulator:
    """State of one episode and its dynamics.

    The state is kept in observation form: ``robot`` (9,) and the pedestrian history
    ``history`` (T, N, 5), oldest first, padded slots all zero with ``mask`` 0, where N is the scene's
    ``crowd_capacity`` (``max_humans``, or more people than the observation holds with ``observed="nearest"``).
    Both arrays are updated in place by :meth:`step` (copy them to keep a snapshot), and the
    walking directions of the comfort reward are tracked incrementally from the steps, so the
    state is meant to be changed through :meth:`reset` and :meth:`step` only.

    The kinematics (:func:`~sb3_crowdnav.sim.actions.move`) and :func:`compute_reward` are the
    compiled functions the lookahead uses too. The people are drawn by :func:`draw_people` (``people``) and moved by
    the scene's crowd model (``crowd``, built once). Preferred velocities and walking directions run in
    Python floats: on 2-vectors and N <= 10 pedestrians NumPy's per-call overhead costs more than
    the arithmetic. Tests check these against the NumPy functions the lookahead uses.

    :param scene: the scene's settings
    :param reward: the reward's terms and weights
    :param progress_reward: [1/m] goal-progress shaping: each non-terminal step also earns this times the metres it
        gained on the goal (:func:`~sb3_crowdnav.sim.rewards.with_route_progress` with the goal as the waypoint;
        :attr:`progress_term` the step's); 0 (the default) is the paper's reward. A world with a route shapes
        progress on its waypoints instead, and passes 0 here.
    """

    # the open floor has no static obstacles: every collision is with a pedestrian (the warehouse sets it per step)
    hit_obstacle = False

    def __init__(self, scene: SceneConfig, reward: RewardConfig, progress_reward: float = 0.0) -> None:
        self.scene = scene
        self.reward_cfg = reward
        check_range("progress_reward", progress_reward, 0, MAX_PROGRESS_REWARD)  # [1/m]
        self.progress_reward = float(progress_reward)
        self.progress_term = 0.0  # the last step's shaping (0 without it)
        self.speeds, self.directions = action_table(scene.robot_v_pref, scene.rotation_range, scene.actions)
        self.n_actions = len(self.speeds)
        self._limits = step_limits(scene.max_acceleration, scene.max_turn_rate, scene.time_step)  # per step
        self._speed_list, self._direction_list = self.speeds.tolist(), self.directions.tolist()
        self.robot = np.zeros(ROBOT_DIM)
        self.history = np.zeros((scene.history_length, scene.crowd_capacity, HUMAN_DIM))
        self.mask = np.zeros(scene.crowd_capacity, dtype=bool)
        self.human_goals = np.zeros((0, 2))
        self.crowd: CrowdModel = make_crowd(scene)
        self.recorded = isinstance(self.crowd, RecordedCrowd)  # its own episodes, people who come and go
        self.people: People | None = None  # the episode's population (set by reset)
        self._preferred: PreferredVelocities | None = None
        # walking direction of each pedestrian (n, 2) and the steps since it last walked (n,) (see _walking_directions)
        self._walk_dir, self._walk_age = np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
        self.num_humans = 0
        self.steps = 0
        self.max_steps = scene.max_steps  # the episode is truncated after this many steps (the env reads it)
        # what the robot sees of the people (None: their true state, CrowdNav-v0's default)
        self.sensor: PeopleSensor | None = PeopleSensor(scene) if sensing_on(scene) else None

    def observed(self) -> tuple[np.ndarray, np.ndarray]:
        """The pedestrian history (T, max_humans, 5) and mask (max_humans,) the robot observes: the sensor's
        (:mod:`sb3_crowdnav.sim.sensing`), or the true ones without a sensor."""
        if self.sensor is None:
            return self.history, self.mask
        return self.sensor.history, self.sensor.mask

    @property
    def seen_people(self) -> np.ndarray:
        """(num_humans,) bool: the people in the observation (its ``humans_mask``), whichever slots they hold."""
        if self.sensor is None:
            return self.mask[: self.num_humans].copy()
        return self.sensor.seen_people(self.num_humans)

    def _sense_people(self, rng: np.random.Generator | None = None) -> None:
        """Let the sensor see the people after a reset (with its ``rng``) or a step."""
        (x, y), row = self.robot[Robot.POS].tolist(), self.history[-1]
        if rng is not None:
            self.sensor.reset(rng, x, y, row, self.mask)
        else:
            self.sensor.step(x, y, row, self.mask)

    # ------------------------------------------------------------------ reset
    @property
    def sees_robot(self) -> np.ndarray:
        """(n,) bool: the present episode's people who see the robot (it is one of the agents their crowd model avoids;
        ``robot_visible``); a recording's people never do."""
        if self.recorded or self.people is None:
            return np.zeros(self.num_humans, dtype=bool)
        return self.people.sees_robot[: self.num_humans].copy()

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new episode drawn from ``rng``."""
        cfg = self.scene
        if self.recorded:
            sc = self.crowd.draw_scenario(rng)
            n = len(sc.human_starts)
        else:
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
        current = np.zeros((cfg.crowd_capacity, HUMAN_DIM))
        current[:n, Human.POS] = sc.human_starts
        current[:n, Human.RADIUS] = cfg.human_radius
        self.mask = np.zeros(cfg.crowd_capacity, dtype=bool)
        self.mask[:n] = True
        if self.recorded:
            self.mask[:n] = self.crowd.present
            current[:n, Human.VEL] = self.crowd.velocities
            current[:n][~self.crowd.present] = 0.0  # empty slots padded
        self.history = np.repeat(current[None], cfg.history_length, axis=0)
        self.human_goals = sc.human_goals
        self._forget_walks(n)
        self.steps = 0
        self.people = draw_people(cfg, sc.human_starts, sc.human_goals, rng)
        self._preferred = PreferredVelocities(self.people)
        if n > 0:
            self.crowd.reset(rng, self.people, self._robot_agent())
        if self.sensor is not None:
            self._sense_people(rng)

    # ------------------------------------------------------------------ step
    def _robot_agent(self, end: tuple[float, float] | None = None) -> RobotAgent:
        """The robot at the start of the step; ``end``: where its move through the step ends."""
        r = self.robot.tolist()
        return RobotAgent(tuple(r[Robot.POS]), tuple(r[Robot.VEL]), r[Robot.RADIUS], end)

    def _move_humans(self, robot_end: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """New positions and velocities (n, 2) of the present pedestrians; the robot's move ends at ``robot_end``."""
        pos = self.history[-1, : self.num_humans, Human.POS].tolist()
        return self.crowd.step(self._preferred.at(pos, self.time), self._robot_agent(robot_end))

    def _forget_walks(self, n: int) -> None:
        """Start the walking directions of ``n`` pedestrians: everyone still over the whole initial window."""
        self._walk_dir, self._walk_age = np.zeros((n, 2)), np.full(n, self.scene.history_length, dtype=np.int64)
        self._walk_dir[:, 0] = 1.0

    def _walking_directions(self, robot_x: float, robot_y: float) -> np.ndarray:
        """:func:`walking_direction` of the present pedestrians (n, 2) from the newest history row.

        Incremental form of the same rule (:func:`~sb3_crowdnav.sim.rewards.walking_directions_step`): the last
        velocity faster than ``STILL_SPEED`` within the window of T steps (kept with its age), else the direction
        towards the robot.
        """
        return walking_directions_step(self.history[-1, : self.num_humans], self._walk_dir, self._walk_age,
                                       self.scene.history_length, robot_x, robot_y)

    def _update_presence(self, human_pos0: np.ndarray) -> None:
        """Take who is present from a :class:`RecordedCrowd` after its step: a vanished person's slot padded over the
        whole window (zeros, mask 0); a slot a person arrived in starts its history anew (its state repeated, as at
        reset), its walking direction forgotten, and it appears where it is (``human_pos0``: no sweep from elsewhere
        in this step's collision check)."""
        present, arrivals, n = self.crowd.present, self.crowd.arrivals, self.num_humans
        mask = self.mask[:n]
        gone = mask & ~present
        if not (gone.any() or arrivals.any()):
            return
        hist = self.history
        hist[:, :n][:, gone] = 0.0
        came = np.flatnonzero(arrivals)
        hist[-1, came, Human.RADIUS] = self.scene.human_radius
        hist[:-1, came] = hist[-1, came]
        human_pos0[came] = hist[-1, came, Human.POS]
        self._walk_dir[came] = (1.0, 0.0)
        self._walk_age[came] = self.scene.history_length
        mask[:] = present

    def step(self, action: int) -> RewardTerms:
        """Apply ``action`` (an index of the scene's action set) and advance the pedestrians; return the reward terms of
        the transition. The robot moves by :func:`~sb3_crowdnav.sim.actions.move` within the scene's limits."""
        cfg, n = self.scene, self.num_humans
        if not (0 <= action < self.n_actions):
            raise ValueError(f"action must be in [0, {self.n_actions}), got {action!r}")
        robot, hist = self.robot, self.history
        r = robot.tolist()
        (px, py), (vx0, vy0), (gx, gy), heading0 = r[Robot.POS], r[Robot.VEL], r[Robot.GOAL], r[Robot.HEADING]
        x, y, heading, vx, vy = move(
            px, py, heading0, vx0, vy0, gx, gy, self._speed_list[action], self._direction_list[action],
            cfg.kinematics == "holonomic", cfg.time_step, *self._limits,
        )
        human_pos0 = hist[-1, :n, Human.POS].copy()
        if n:
            new_hpos, new_hvel = self._move_humans((x, y))  # reads the robot's state at the start of the step
        hist[:-1] = hist[1:]  # shift the window in place; the newest row keeps radii and padding
        if n:
            hist[-1, :n, Human.POS] = new_hpos
            hist[-1, :n, Human.VEL] = new_hvel
            if self.recorded:
                self._update_presence(human_pos0)
        robot[Robot.POS] = x, y
        robot[Robot.VEL] = vx, vy
        robot[Robot.HEADING] = heading
        self.steps += 1
        if self.sensor is not None:
            self._sense_people()

        terms = transition_terms(
            self.reward_cfg, float(cfg.time_step), np.array([px, py]), robot[Robot.POS], heading0, heading,
            robot[Robot.GOAL], float(cfg.robot_radius), human_pos0, hist[-1, :n, Human.POS], self._walking_directions(x, y),
            hist[-1, :n, Human.RADIUS], self.mask[:n],
        )
        if self.progress_reward:  # (the paper's reward without it: the terms as they are)
            terms = with_route_progress(terms, np.array([px, py]), robot[Robot.POS], robot[Robot.GOAL],
                                        self.progress_reward)
            self.progress_term = float(terms.progress_term)
        return terms

    @property
    def time(self) -> float:
        return self.steps * self.scene.time_step

