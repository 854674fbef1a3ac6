"""The episode statistics of the crowd envs: one accumulator fed every step (as Gymnasium's ``RecordEpisodeStatistics``).

The env feeds :meth:`EpisodeStatistics.update` with each transition and asks :meth:`EpisodeStatistics.summary` for
``info["episode_stats"]`` on the last step. Evaluation records are built from that dict, so its keys and the
arithmetic of its values are a contract: the same floats in the same order of operations.

The safety figures (:mod:`sb3_crowdnav.sim.proximity`'s thresholds) are taken from the people's true state, whatever
the robot observes: the step's minimum surface distance of the reward (the whole step swept), and the people's newest
positions, velocities and radii with the mask of who is present (``sim.history[-1]``, ``sim.mask``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sb3_crowdnav.sim.actions import wrap
from sb3_crowdnav.sim.config import RewardConfig
from sb3_crowdnav.sim.observation import Robot
from sb3_crowdnav.sim.proximity import NEAR_MISS_DISTANCE, NEAR_PERSON_DISTANCE, TTC_HORIZON, min_time_to_collision
from sb3_crowdnav.sim.rewards import RewardTerms, is_sharp_turn


class EpisodeStatistics:
    """The metrics of one episode, accumulated step by step.

    :param reward: the reward setting (the discomfort distance, the sharp-turn threshold)
    :param gamma: discount of ``discounted_return``, Σ gamma^(t·Δt·v_pref) r_t
    :param time_step: Δt [s]
    :param v_pref: the robot's preferred speed [m/s] (the discount is per metre at full speed, as the lookahead's)
    :param no_one_distance: [m] the separation of a step with no one present (finite, farther than anyone can be)
    """

    def __init__(self, reward: RewardConfig, gamma: float, time_step: float, v_pref: float,
                 no_one_distance: float = math.inf) -> None:
        self.reward = reward
        self.gamma = gamma
        self.time_step = time_step
        self.v_pref = v_pref
        self.no_one_distance = no_one_distance
        self.reset()

    def reset(self) -> None:
        """Forget the episode (called at every env reset)."""
        self.steps = 0
        self.steps_with_people = 0  # steps with someone present (a recorded scene can have none)
        self.path_length = 0.0
        self.min_separation = math.inf
        self.discomfort_steps = 0
        self.discomfort_sum = 0.0  # of the minimum separations of the discomfort steps
        self.comfort_steps = 0
        self.comfort_sum = 0.0  # of the minimum separations of the comfort-zone steps
        self.heading_change = 0.0
        self.sharp_turns = 0
        self.discounted_return = 0.0
        # the safety figures
        self.min_ttc = TTC_HORIZON
        self.near_misses = 0
        self.near_person_steps = 0
        self.near_person_speed_sum = 0.0  # of the robot's speeds over the steps with a person within 1 m
        self.peak_acceleration = 0.0
        self.peak_turn_rate = 0.0

    def update(self, before: list[float], after: list[float], terms: RewardTerms, reward: float,
               humans: np.ndarray, mask: np.ndarray) -> None:
        """Add one transition: the robot's state (9 floats) ``before`` and ``after`` it, its reward terms and reward, and
        the people's true state after it: ``humans`` (max_humans, 5) [px, py, vx, vy, radius], ``mask`` (max_humans,)
        bool, who is present."""
        closest = float(terms.min_distance)  # inf with no one present
        min_dist = min(closest, self.no_one_distance)
        self.steps_with_people += closest < math.inf
        (x0, y0), (x1, y1) = before[Robot.POS], after[Robot.POS]
        self.path_length += math.hypot(x1 - x0, y1 - y0)
        self.min_separation = min(self.min_separation, min_dist)
        if min_dist < self.reward.discomfort_dist:
            self.discomfort_steps += 1
            self.discomfort_sum += min_dist
        if terms.in_comfort_zone:
            self.comfort_steps += 1
            self.comfort_sum += min_dist
        turn = wrap(after[Robot.HEADING] - before[Robot.HEADING])
        self.heading_change += abs(turn)
        self.sharp_turns += is_sharp_turn(turn, self.reward)  # Eq. 13's trigger, counted under every reward
        self._update_safety(before, after, turn, min_dist, humans, mask)
        self.discounted_return += self.gamma ** (self.steps * self.time_step * self.v_pref) * reward
        self.steps += 1

    def _update_safety(self, before: list[float], after: list[float], turn: float, min_dist: float,
                       humans: np.ndarray, mask: np.ndarray) -> None:
        """The safety figures of one step (``min_dist`` the step's minimum surface distance, ``turn`` its heading
        change [rad])."""
        (vx0, vy0), (vx, vy) = before[Robot.VEL], after[Robot.VEL]
        (x, y), dt = after[Robot.POS], self.time_step
        if min_dist <= 0:  # touched during the step: no time left
            self.min_ttc = 0.0
        elif self.min_ttc > 0:
            self.min_ttc = min(self.min_ttc, min_time_to_collision(x, y, vx, vy, after[Robot.RADIUS], humans, mask,
                                                                   TTC_HORIZON))
        self.near_misses += 0 < min_dist < NEAR_MISS_DISTANCE
        if min_dist < NEAR_PERSON_DISTANCE:
            self.near_person_steps += 1
            self.near_person_speed_sum += math.hypot(vx, vy)
        self.peak_acceleration = max(self.peak_acceleration, math.hypot(vx - vx0, vy - vy0) / dt)
        self.peak_turn_rate = max(self.peak_turn_rate, abs(turn) / dt)

    def summary(self, outcome: str, num_humans: int) -> dict[str, Any]:
        """``info["episode_stats"]`` of the episode so far (``nan`` for a mean over no steps).

        The safety figures: ``min_time_to_collision`` [s] (the smallest over the steps' end states, at constant
        velocity, capped at ``TTC_HORIZON`` = 10 s, 0 once the robot touched a person), ``near_misses`` (steps closer
        than 0.2 m to a person's surface without touching), ``speed_near_people`` [m/s] (the robot's mean speed over
        the ``steps_near_people``, those with a person's surface within 1 m), ``peak_acceleration`` [m/s²] (the largest
        ``|v_t - v_{t-1}| / Δt``, velocity vectors) and ``peak_turn_rate`` [rad/s] (the largest ``|heading change| / Δt``).
        """
        return {
            "outcome": outcome,
            "navigation_time": self.steps * self.time_step,
            "path_length": self.path_length,
            "min_separation": self.min_separation,
            "discomfort_frequency": self.discomfort_steps / self.steps,
            "comfort_zone_time": self.comfort_steps * self.time_step,
            "discomfort_separation": self.discomfort_sum / self.discomfort_steps if self.discomfort_steps else math.nan,
            "comfort_zone_separation": self.comfort_sum / self.comfort_steps if self.comfort_steps else math.nan,
            "heading_change": self.heading_change,
            "sharp_turns": self.sharp_turns,
            "discounted_return": self.discounted_return,
            "num_humans": num_humans,
            "steps_with_people": self.steps_with_people,
            "min_time_to_collision": self.min_ttc,
            "near_misses": self.near_misses,
            "steps_near_people": self.near_person_steps,
            "speed_near_people": (self.near_person_speed_sum / self.near_person_steps if self.near_person_steps
                                  else math.nan),
            "peak_acceleration": self.peak_acceleration,
            "peak_turn_rate": self.peak_turn_rate,
        }
