"""Start and goal positions of the robot and the pedestrians, drawn from a ``np.random.Generator``."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from sb3_crowdnav.sim.config import SceneConfig

MIN_GAP = 0.2  # [m] extra clearance between starts (and between goals) on top of the two radii
MAX_TRIES = 1000


class Scenario(NamedTuple):
    """Positions of one episode (world frame) [m]."""

    robot_start: np.ndarray  # (2,)
    robot_goal: np.ndarray  # (2,)
    robot_heading: float  # [rad]
    human_starts: np.ndarray  # (N, 2)
    human_goals: np.ndarray  # (N, 2)


def _draw_circle(cfg: SceneConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    angle = rng.uniform(0.0, 2 * np.pi)
    (nx, ny) = rng.uniform(-1, 1, 2).tolist()
    r, noise = cfg.circle_radius, cfg.start_noise
    start = np.array([r * math.cos(angle) + nx * noise, r * math.sin(angle) + ny * noise])
    return start, -start


def _draw_square(cfg: SceneConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    sign = -1.0 if rng.random() > 0.5 else 1.0
    start = np.array([rng.random() * cfg.square_width * 0.5 * sign, (rng.random() - 0.5) * cfg.square_width])
    goal = np.array([rng.random() * cfg.square_width * 0.5 * -sign, (rng.random() - 0.5) * cfg.square_width])
    return start, goal


def generate_scenario(cfg: SceneConfig, num_humans: int, rng: np.random.Generator) -> Scenario:
    """Robot from (0, -R) to (0, R) facing its goal; pedestrians as the field's circle/square crossing.

    A pedestrian whose start or goal lies closer than two radii + 0.2 m to another agent's
    start or goal is redrawn.
    """
    r = cfg.circle_radius if cfg.scenario == "circle_crossing" else cfg.square_width / 2
    robot_start, robot_goal = np.array([0.0, -r]), np.array([0.0, r])
    draw = _draw_circle if cfg.scenario == "circle_crossing" else _draw_square
    starts = [robot_start]
    goals = [robot_goal]
    placed = [(0.0, -r, 0.0, r, cfg.robot_radius + cfg.human_radius + MIN_GAP)]  # start, goal, clearance in floats
    for _ in range(num_humans):
        for _ in range(MAX_TRIES):
            start, goal = draw(cfg, rng)
            (sx, sy), (gx, gy) = start.tolist(), goal.tolist()
            ok = all(
                math.sqrt((sx - px) ** 2 + (sy - py) ** 2) >= gap and math.sqrt((gx - qx) ** 2 + (gy - qy) ** 2) >= gap
                for px, py, qx, qy, gap in placed
            )
            if ok:
                break
        else:
            raise RuntimeError(
                f"could not place {num_humans} pedestrians without overlap in {cfg.scenario}; "
                "lower num_humans or enlarge the scene"
            )
        starts.append(start)
        goals.append(goal)
        placed.append((sx, sy, gx, gy, 2 * cfg.human_radius + MIN_GAP))
    human_starts = np.array(starts[1:]).reshape(num_humans, 2)
    human_goals = np.array(goals[1:]).reshape(num_humans, 2)
    return Scenario(robot_start, robot_goal, np.pi / 2, human_starts, human_goals)
