"""Pickers who see the robot: ``robot_visible`` in ``CrowdNavWarehouse-v0`` as a bool or a share of the pickers."""

from __future__ import annotations

import importlib.util
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.crowd import RobotAgent, Walls, make_crowd
from sb3_crowdnav.sim.population import People
from sb3_crowdnav.sim.warehouse.config import PICKERS_SEE_ROBOT

ENV = "CrowdNavWarehouse-v0"
HAS_JUPEDSIM = importlib.util.find_spec("jupedsim") is not None


def _box(xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
    return np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]], dtype=np.float64)


def _head_on(sees: list[bool], steps: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Picker 0 walks +x along a 2.2 m aisle between two racks while the robot drives -x through it at 1 m/s, straight
    at it (scripted, not avoiding); picker 1 stands in the other aisle. Picker 0's positions (steps, 2) and its
    distances to the robot's centre (steps,) [m]."""
    scene = SceneConfig(scenario="warehouse", num_humans=2, robot_visible=0.5)
    walls = Walls(_box(-8.0, -3.0, 8.0, 3.0), (_box(-6.0, 1.1, 6.0, 1.7), _box(-6.0, -1.7, 6.0, -1.1)))
    starts = np.array([[-4.0, 0.05], [0.0, 2.3]])  # (a hair off the axis: no exactly symmetric ORCA problem)
    goals = np.array([[7.5, 0.05], [0.0, 2.3]])
    people = People(starts, goals, np.full(2, scene.human_radius), np.full(2, 1.0), np.array(sees),
                    np.full(2, np.inf), np.full(2, np.inf))
    crowd = make_crowd(scene)
    robot, velocity = np.array([4.0, 0.0]), np.array([-1.0, 0.0])
    crowd.reset(np.random.default_rng(0), people, RobotAgent(tuple(robot), (0.0, 0.0), scene.robot_radius), walls)
    positions, distances = [], []
    here = starts.copy()
    for _ in range(steps):
        preferred = goals - here
        preferred /= np.maximum(np.linalg.norm(preferred, axis=1, keepdims=True), 1.0)  # at most 1 m/s
        here, _ = crowd.step([tuple(v) for v in preferred.tolist()],
                             RobotAgent(tuple(robot.tolist()), tuple(velocity.tolist()), scene.robot_radius))
        robot = robot + velocity * scene.time_step
        positions.append(here[0].copy())
        distances.append(float(np.linalg.norm(here[0] - robot)))
    return np.array(positions), np.array(distances)


def test_in_a_head_on_approach_a_picker_who_sees_the_robot_avoids_it_and_a_distracted_one_does_not():
    contact = SceneConfig().robot_radius + SceneConfig().human_radius
    seeing, seeing_distance = _head_on([True, False])  # a mixed crowd both times (two RVO2 simulators)
    distracted, distracted_distance = _head_on([False, True])
    assert seeing_distance.min() >= contact - 0.02  # (ORCA's time step lets it touch by a couple of centimetres)
    assert np.abs(seeing[:, 1]).max() > 0.3  # it stepped aside, inside the aisle
    assert np.abs(seeing[:, 1]).max() < 1.1 - 0.3 + 1e-6
    assert distracted_distance.min() < contact - 0.2  # it walked into the robot
    assert np.abs(distracted[:, 1]).max() < 0.1  # without leaving the aisle's middle


def _reset(seed: int, **kwargs):
    env = gym.make(ENV, **kwargs)
    obs, _ = env.reset(seed=seed)
    return env.unwrapped, obs


def test_the_warehouse_default_is_a_share_of_orca_pickers_drawn_per_episode():
    env = gym.make(ENV, num_humans=10)
    assert env.unwrapped.scene.robot_visible == PICKERS_SEE_ROBOT
    seen = []
    for seed in range(30):
        env.reset(seed=seed)
        sees = env.unwrapped.sim.pickers.sees_robot
        np.testing.assert_array_equal(env.unwrapped.sim.crowd.seeing, sees)  # what the crowd model got
        seen.append(sees)
    share = np.mean(seen)
    assert abs(share - PICKERS_SEE_ROBOT) < 0.1  # 300 draws: the standard error is 0.023
    assert any(s.all() for s in seen) and not all(s.all() for s in seen)
    for visible, expected in ((True, True), (False, False)):
        env = gym.make(ENV, robot_visible=visible)
        env.reset(seed=0)
        assert (env.unwrapped.sim.pickers.sees_robot == expected).all()


def test_visibility_is_drawn_after_the_other_draws_of_the_reset():
    blind, blind_obs = _reset(5, robot_visible=False)
    share, share_obs = _reset(5, robot_visible=0.5)
    everyone, _ = _reset(5, robot_visible=True)
    for key in blind_obs:
        np.testing.assert_array_equal(share_obs[key], blind_obs[key])
    n = blind.sim.num_humans
    for sim in (share.sim, everyone.sim):  # the same slots, who stands, the same dwells and first jobs
        np.testing.assert_array_equal(sim.pickers.slot, blind.sim.pickers.slot)
        np.testing.assert_array_equal(sim.pickers.dwell, blind.sim.pickers.dwell)
    # a bool draws nothing; a share draws one uniform per picker, last
    assert everyone.np_random.bit_generator.state == blind.np_random.bit_generator.state
    blind.np_random.random(n)
    assert share.np_random.bit_generator.state == blind.np_random.bit_generator.state


def test_pickers_who_see_the_robot_change_the_episode():
    def pickers(visible) -> np.ndarray:
        env = gym.make(ENV, robot_visible=visible)
        env.reset(seed=3)
        out = []
        for _ in range(30):
            obs, _, terminated, truncated, _ = env.step(0)
            out.append(obs["humans"])
            if terminated or truncated:
                break
        return np.concatenate(out)

    assert not np.array_equal(pickers(True), pickers(False))


@pytest.mark.parametrize("bad", [1.5, -0.1, float("nan")])
def test_a_share_outside_zero_one_is_refused_at_construction(bad):
    with pytest.raises(ValueError, match="robot_visible"):
        gym.make(ENV, robot_visible=bad)


@pytest.mark.parametrize("bad", ["0.8", None, [0.8]])
def test_a_share_of_another_type_is_refused_at_construction(bad):
    with pytest.raises(TypeError, match="robot_visible"):
        gym.make(ENV, robot_visible=bad)


@pytest.mark.skipif(not HAS_JUPEDSIM, reason="needs JuPedSim")
def test_social_force_pickers_take_a_bool_and_default_to_seeing_the_robot():
    with pytest.raises(ValueError, match="robot_visible must be True or False with crowd='social_force'"):
        gym.make(ENV, crowd="social_force", robot_visible=0.5)
    assert gym.make(ENV, crowd="social_force").unwrapped.scene.robot_visible is True


@pytest.mark.parametrize("kwargs", [{}, {"robot_visible": 0.3}])
def test_both_checkers_pass_without_warnings(kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(ENV, **kwargs)
        gym_check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)
    assert not caught, [str(w.message) for w in caught]


def test_same_seed_same_episode_with_a_share():
    def episode() -> list[bytes]:
        env = gym.make(ENV, num_humans=8)
        rng = np.random.default_rng(4)
        obs, _ = env.reset(seed=11)
        out = [obs["humans"].tobytes(), env.unwrapped.sim.pickers.sees_robot.tobytes()]
        for _ in range(60):
            obs, reward, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
            out += [obs["humans"].tobytes(), obs["robot"].tobytes(), np.float64(reward).tobytes()]
            if terminated or truncated:
                obs, _ = env.reset()
                out.append(env.unwrapped.sim.pickers.sees_robot.tobytes())
        return out

    assert episode() == episode()
