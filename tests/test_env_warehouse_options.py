"""CrowdNavWarehouse-v0's robot_visible (pickers avoid the robot) and time_limit (a fixed truncation time)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.crowd import RobotAgent
from sb3_crowdnav.sim.warehouse.config import FULL_SIGHT
from sb3_crowdnav.sim.warehouse.layout import layout_from_sizes
from sb3_crowdnav.sim.warehouse.pickers import PickerCrowd, PickSlots

SPEED = 1.0  # [m/s] the scripted robot's


def _head_on(robot_visible: bool, robot_start_x: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """A picker walks along a rack's north face from its west end to its east end while a scripted robot drives
    west along the same line at full speed, straight at it. The picker's positions (steps, 2) and the robot's."""
    layout = layout_from_sizes(1, 1, 8.0, 1.0, 2.0, 2.0)  # one 8 x 1 m rack, 2 m aisles around it
    scene = SceneConfig(scenario="warehouse", num_humans=1, robot_visible=robot_visible)
    slots = PickSlots(layout, scene, scene.human_radius + 0.02)
    face = np.flatnonzero(np.isclose(slots.points[:, 1], slots.points[:, 1].max()))  # the north face's slots
    west, east = face[np.argmin(slots.points[face, 0])], face[np.argmax(slots.points[face, 0])]
    usable = np.array([west, east])  # two slots: the picker's next one is the other end
    for seed in range(20):  # a picker that starts walking (not standing at its slot)
        crowd = PickerCrowd(scene, slots, usable, np.array([0]), np.random.default_rng(seed), (2.0, 8.0),
                            (np.array([robot_start_x, slots.points[east, 1]]), np.zeros(2), scene.robot_radius)
                            if robot_visible else None)
        if not crowd.standing[0]:
            break
    y = float(slots.points[east, 1])
    picker, robot = [slots.points[west]], [np.array([robot_start_x, y])]
    for _ in range(40):
        position, velocity = robot[-1], np.array([-SPEED, 0.0])
        positions, _ = crowd.step(picker[-1][None], RobotAgent(tuple(position.tolist()), tuple(velocity.tolist()),
                                                                 scene.robot_radius))
        picker.append(positions[0])
        robot.append(position + velocity * scene.time_step)
    return np.array(picker), np.array(robot)


def _min_separation(picker: np.ndarray, robot: np.ndarray, radius_sum: float = 0.6) -> float:
    return float(np.min(np.linalg.norm(picker - robot, axis=1)) - radius_sum)


def test_a_picker_who_sees_the_robot_coming_head_on_steps_aside():
    blind, blind_robot = _head_on(robot_visible=False)
    seeing, seeing_robot = _head_on(robot_visible=True)
    np.testing.assert_array_equal(blind_robot, seeing_robot)  # the same scripted robot
    assert _min_separation(blind, blind_robot) < 0  # walks straight through it
    assert np.ptp(blind[:, 1]) < 1e-6  # without a sideways step
    assert not np.allclose(seeing, blind)
    assert np.ptp(seeing[:, 1]) > 0.1  # the seeing picker leaves the line
    assert _min_separation(seeing, seeing_robot) > _min_separation(blind, blind_robot) + 0.3
    # the blind picker ignores the robot: its path is the same with the robot far away
    far, _ = _head_on(robot_visible=False, robot_start_x=-50.0)
    np.testing.assert_array_equal(far, blind)


def test_robot_visible_puts_the_robot_into_the_pickers_orca_and_changes_their_paths():
    paths = {}
    for visible in (False, True):
        env = gym.make("CrowdNavWarehouse-v0", robot_visible=visible, **FULL_SIGHT)  # (every picker observed)
        obs, _ = env.reset(seed=3)
        assert (env.unwrapped.sim.pickers.crowd.crowds[0].robot_id is not None) == visible
        humans = [obs["humans"]]
        for _ in range(60):
            obs, _, terminated, truncated, _ = env.step(72)  # slowly straight on (never ends the episode sooner)
            humans.append(obs["humans"])
            if terminated or truncated:
                break
        paths[visible] = np.array(humans)
    assert paths[False].shape != paths[True].shape or not np.array_equal(paths[False], paths[True])


@pytest.mark.parametrize("time_limit", [3.0, 7.5])
def test_time_limit_truncates_the_warehouse_episode_at_that_time(time_limit):
    env = gym.make("CrowdNavWarehouse-v0", time_limit=time_limit, num_humans=0)
    _, info = env.reset(seed=0)
    assert info["time_limit"] == time_limit
    steps, terminated, truncated = 0, False, False
    while not (terminated or truncated):
        _, _, terminated, truncated, info = env.step(8)  # back and forth on the spot: no goal, no rack
        steps += 1
    assert truncated and not terminated and info["outcome"] == "timeout"
    assert steps == round(time_limit / env.unwrapped.scene.time_step)


def test_without_time_limit_the_warehouse_truncates_by_route():
    env = gym.make("CrowdNavWarehouse-v0")
    _, info = env.reset(seed=0)
    w = env.unwrapped.warehouse
    route_time = w.time_limit_slack + w.time_limit_factor * info["route_length"] / env.unwrapped.scene.robot_v_pref
    assert route_time <= info["time_limit"] < route_time + env.unwrapped.scene.time_step


def test_time_limit_and_the_route_based_limit_exclude_each_other():
    with pytest.raises(ValueError, match="time_limit and time_limit_factor exclude each other"):
        gym.make("CrowdNavWarehouse-v0", time_limit=30.0, time_limit_factor=3.0)
