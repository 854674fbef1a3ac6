"""The ORCA robot's velocity-to-action mappings, and its statistics (slow)."""

from __future__ import annotations

import collections

import gymnasium as gym
import numpy as np
import pytest

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav import OrcaPolicy, SceneConfig
from sb3_crowdnav.sim.actions import action_table
from sb3_crowdnav.sim.observation import HUMAN_DIM, Human, Robot


def _head_on(scene: SceneConfig):
    """Robot at the origin heading +y towards (0, 4); one pedestrian 1.5 m ahead walking straight at it."""
    robot = np.zeros(9)
    robot[Robot.POS] = 0.0, 0.0
    robot[Robot.VEL] = 0.0, 1.0
    robot[Robot.RADIUS] = 0.3
    robot[Robot.GOAL] = 0.0, 4.0
    robot[Robot.V_PREF] = 1.0
    robot[Robot.HEADING] = np.pi / 2
    humans = np.zeros((scene.history_length, scene.max_humans, HUMAN_DIM))
    humans[:, 0, Human.POS] = 0.0, 1.5
    humans[:, 0, Human.VEL] = 0.0, -1.0
    humans[:, 0, Human.RADIUS] = 0.3
    mask = np.zeros(scene.max_humans)
    mask[0] = 1
    return {"robot": robot, "humans": humans.ravel(), "humans_mask": mask}


def _closest_approach_if_held(action: int, seconds: float = 3.0) -> float:
    """Closest centre distance to the head-on pedestrian if the robot held ``action``."""
    speeds, directions = action_table()
    angle = np.pi / 2 + directions[action]
    v = speeds[action] * np.array([np.cos(angle), np.sin(angle)])
    t = np.linspace(0.0, seconds, 601)
    rel = np.array([0.0, 1.5]) + np.outer(t, np.array([0.0, -1.0]) - v)
    return float(np.linalg.norm(rel, axis=1).min())


def test_constrained_mapping_leaves_the_collision_course():
    scene = SceneConfig()
    obs = _head_on(scene)
    nearest = int(OrcaPolicy(scene, mapping="nearest").predict(obs)[0])
    constrained = int(OrcaPolicy(scene, mapping="constrained").predict(obs)[0])
    assert constrained != nearest
    # held, the nearest action still overlaps the pedestrian (< 0.6 m between centres); the constrained one swerves wider
    assert _closest_approach_if_held(nearest) < 0.6 * 0.75
    assert _closest_approach_if_held(constrained) > _closest_approach_if_held(nearest) + 0.1
    # and with no pedestrian around both mappings drive straight to the goal at full speed
    empty = dict(obs, humans_mask=np.zeros(scene.max_humans))
    for mapping in OrcaPolicy.MAPPINGS:
        assert int(OrcaPolicy(scene, mapping=mapping).predict(empty)[0]) == 4 * 16


def test_bad_mapping_raises():
    with pytest.raises(ValueError, match="mapping"):
        OrcaPolicy(mapping="closest")


def _success_rate(visible: bool, mapping: str, episodes: int) -> float:
    env = gym.make("CrowdNav-v0", robot_visible=visible)
    policy = OrcaPolicy.from_env(env, mapping=mapping)
    outcomes = collections.Counter()
    for i in range(episodes):
        obs, _ = env.reset(seed=1_000_000 + i)
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
            done = terminated or truncated
        outcomes[info["outcome"]] += 1
    return outcomes["success"] / episodes


@pytest.mark.slow
def test_orca_statistics_invisible_and_visible():
    """Issue 2's acceptance: invisible robot 0.25-0.55 (paper 0.33); visible >= 0.95."""
    assert 0.25 <= _success_rate(False, "nearest", 500) <= 0.55
    assert _success_rate(True, "constrained", 500) >= 0.95
