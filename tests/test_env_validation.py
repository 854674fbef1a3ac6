"""Every constructor argument is checked; the exception names the argument."""

import math

import gymnasium as gym
import pytest

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import CrowdNavEnv
from sb3_crowdnav.sim import RewardConfig, SceneConfig

BAD_ENV_KWARGS = [
    # (kwargs, exception, the argument named in the message)
    (dict(num_humans=-1), ValueError, "num_humans"),
    (dict(num_humans=11), ValueError, "num_humans"),  # > max_humans (10)
    (dict(num_humans=4, max_humans=3), ValueError, "num_humans"),
    (dict(num_humans=(5, 2)), ValueError, "num_humans"),
    (dict(num_humans=(1, 2, 3)), ValueError, "num_humans"),
    (dict(num_humans=(1, 11)), ValueError, "num_humans"),
    (dict(num_humans=(-1, 3)), ValueError, "num_humans"),
    (dict(num_humans=2.5), TypeError, "num_humans"),
    (dict(num_humans=True), TypeError, "num_humans"),
    (dict(max_humans=0), ValueError, "max_humans"),
    (dict(time_step=0.0), ValueError, "time_step"),
    (dict(time_step=-0.25), ValueError, "time_step"),
    (dict(time_step="0.25"), TypeError, "time_step"),
    (dict(time_step=math.nan), ValueError, "time_step"),
    (dict(time_step=30.0), ValueError, "time_step"),  # longer than the time limit
    (dict(time_step=5e-324), ValueError, "time_step"),  # a few ulps: 25 s / time_step overflows to inf
    (dict(time_limit=0.0), ValueError, "time_limit"),
    (dict(time_limit=math.inf), ValueError, "time_limit"),
    (dict(robot_radius=0.0), ValueError, "robot_radius"),
    (dict(human_radius=-0.3), ValueError, "human_radius"),
    (dict(robot_v_pref=0.0), ValueError, "robot_v_pref"),
    (dict(human_v_pref=-1.0), ValueError, "human_v_pref"),
    (dict(circle_radius=0.0), ValueError, "circle_radius"),
    (dict(square_width=-1.0), ValueError, "square_width"),
    (dict(start_noise=-0.1), ValueError, "start_noise"),
    (dict(rotation_range=0.0), ValueError, "rotation_range"),
    (dict(rotation_range=7.0), ValueError, "rotation_range"),
    (dict(history_length=0), ValueError, "history_length"),
    (dict(orca_neighbor_dist=0.0), ValueError, "orca_neighbor_dist"),
    (dict(orca_max_neighbors=0), ValueError, "orca_max_neighbors"),
    (dict(orca_time_horizon=-5.0), ValueError, "orca_time_horizon"),
    (dict(orca_time_horizon_obst=0.0), ValueError, "orca_time_horizon_obst"),
    (dict(robot_visible="yes"), TypeError, "robot_visible"),
    (dict(kinematics="differential"), ValueError, "kinematics"),
    (dict(scenario="warehouse_party"), ValueError, "scenario"),
    (dict(human_policy="social_force"), ValueError, "human_policy"),
    (dict(reward="sparse"), ValueError, "reward"),
    (dict(success_reward=math.nan), ValueError, "success_reward"),
    (dict(collision_penalty=0.5), ValueError, "collision_penalty"),
    (dict(discomfort_dist=-0.2), ValueError, "discomfort_dist"),
    (dict(discomfort_factor=-1.0), ValueError, "discomfort_factor"),
    (dict(comfort_person=0.0), ValueError, "comfort_person"),
    (dict(comfort_person=1e-276), ValueError, "comfort_person"),  # (d_side / d_person)² overflowed in the reward
    (dict(comfort_side=0.005), ValueError, "comfort_side"),
    (dict(comfort_side=-0.7), ValueError, "comfort_side"),
    (dict(social_penalty=-0.02), ValueError, "social_penalty"),
    (dict(angular_penalty=-0.02), ValueError, "angular_penalty"),
    (dict(angular_penalty_threshold=0.0), ValueError, "angular_penalty_threshold"),
    (dict(gamma=0.0), ValueError, "gamma"),
    (dict(gamma=1.5), ValueError, "gamma"),
    (dict(gamma="0.9"), TypeError, "gamma"),
    (dict(render_mode="ascii"), ValueError, "render_mode"),
    (dict(num_pedestrians=6), TypeError, "num_pedestrians"),  # unknown keyword
    (dict(name="comfort"), TypeError, "name"),  # RewardConfig's field is spelled reward= on the env
]


@pytest.mark.parametrize(("kwargs", "exception", "argument"), BAD_ENV_KWARGS, ids=lambda x: str(x))
def test_bad_env_arguments_raise_and_name_the_argument(kwargs, exception, argument):
    with pytest.raises(exception, match=argument):
        CrowdNavEnv(**kwargs)


def test_gym_make_passes_the_errors_through():
    with pytest.raises(ValueError, match="kinematics"):
        gym.make("CrowdNav-v0", kinematics="teleport")
    with pytest.raises(TypeError, match="speed_limit"):
        gym.make("CrowdNav-v0", speed_limit=2)


def test_configs_validate_by_themselves():
    with pytest.raises(ValueError, match="num_humans"):
        SceneConfig(num_humans=20)
    with pytest.raises(ValueError, match="reward"):
        RewardConfig(name="dense")
    with pytest.raises(TypeError):
        SceneConfig(unknown=1)


def test_good_arguments_are_accepted():
    env = CrowdNavEnv(num_humans=(0, 10), kinematics="holonomic", rotation_range=math.pi / 2, robot_visible=True,
                      reward="comfort_angular", angular_penalty_threshold=math.pi, success_reward=2.0, gamma=1.0,
                      start_noise=0.0, time_step=0.1, time_limit=10.0)
    assert env.scene.max_steps == 100
    assert env.reward_config.success_reward == 2.0
    env.reset(seed=0)
    env.step(0)
