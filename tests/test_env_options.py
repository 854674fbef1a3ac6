"""Every keyword argument of every registered env changes its episodes, or is refused at construction by name."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from sb3_crowdnav import ENV_IDS, WAREHOUSE_ENV_IDS
from sb3_crowdnav.sim.actions import STOP_ACTION
from sb3_crowdnav.sim.observation import Robot
from sb3_crowdnav.sim.warehouse.config import PEOPLE_SENSOR_RANGE, PICKERS_SEE_ROBOT, ROBOT_DEFAULTS

ALL_IDS = [*ENV_IDS, *WAREHOUSE_ENV_IDS]
LAYOUT_FILE = Path(__file__).resolve().parent.parent / "examples" / "warehouse_layout.yaml"
STEPS: dict[str, int] = {}  # steps of a trace per env id (episodes end and restart within it); 300 by default
WAIT = 24  # steps every other episode of a trace begins with on the spot (see _act)

# one value other than the default for every keyword (a tuple: the first one the registered id does not set)
NON_DEFAULT = {
    # SceneConfig
    "num_humans": 3, "max_humans": 8, "time_step": 0.2, "time_limit": 5.0, "history_length": 3,
    "kinematics": "holonomic", "rotation_range": math.pi, "robot_radius": 0.4, "robot_v_pref": 0.8,
    "human_radius": 0.35, "human_v_pref": 0.8, "robot_visible": True, "scenario": ("square_crossing", "circle_crossing"),
    "circle_radius": 5.0, "start_noise": 0.2, "human_policy": "linear", "square_width": 8.0,
    "orca_neighbor_dist": 2.0, "orca_max_neighbors": 1, "orca_time_horizon": 1.0, "orca_time_horizon_obst": 0.5,
    "crowd": "linear", "crowd_kwargs": {"safety_space": 0.2}, "human_speed": "measured", "stop_probability": 0.5,
    "stop_duration": (0.5, 1.0), "actions": ("with_stop", "paper"), "max_acceleration": 0.5, "max_turn_rate": 0.8,
    "people_sensor_range": 3.0, "people_sensor_noise": 0.1, "people_sensor_latency": 1, "observed": "nearest",
    # RewardConfig and the env's own
    "reward": ("comfort", "crowdnav"), "gamma": 0.5, "render_mode": "rgb_array",
    "success_reward": 2.0, "collision_penalty": -1.0, "discomfort_dist": 0.5, "discomfort_factor": 2.0,
    "comfort_person": 2.0, "comfort_side": 1.2, "social_penalty": 0.1, "angular_penalty": 0.1,
    "angular_penalty_threshold": 0.3,
    # WarehouseConfig
    "layout": str(LAYOUT_FILE), "layout_ranges": {"rows": (1, 2)}, "max_obstacles": 8, "sensor_range": 2.0,
    "num_waypoints": 2, "waypoint_radius": 0.3, "replan_distance": 0.2, "dwell_time": (0.5, 1.0),
    "min_route_distance": 4.0, "obstacle_collision_penalty": -1.0, "time_limit_factor": 1.0, "time_limit_slack": 5.0,
    "progress_reward": 0.1, "occlusion": False,
}
# the keywords each env refuses because its setting never reads them (with the non-default value above)
OPEN_FLOOR_REFUSED = {"orca_time_horizon_obst", "stop_duration"}  # stop_duration: no one stops by default
REFUSED = {
    "CrowdNav-v0": OPEN_FLOOR_REFUSED | {"square_width", "social_penalty", "angular_penalty"},
    "CrowdNavSquare-v0": OPEN_FLOOR_REFUSED | {"circle_radius", "start_noise", "social_penalty", "angular_penalty"},
    "CrowdNavComfort-v0": OPEN_FLOOR_REFUSED | {"square_width", "discomfort_factor", "angular_penalty"},
    "CrowdNavComfortAngular-v0": OPEN_FLOOR_REFUSED | {"square_width", "discomfort_factor"},
    "CrowdNavWarehouse-v0": {"circle_radius", "square_width", "start_noise", "human_policy", "scenario",
                             "social_penalty", "angular_penalty", "crowd", "observed",
                             "stop_probability", "stop_duration"},
}


# defaults an env sets itself beyond its registered kwargs
ENV_DEFAULTS = {"CrowdNavWarehouse-v0": {**ROBOT_DEFAULTS, "robot_visible": PICKERS_SEE_ROBOT,
                                         "people_sensor_range": PEOPLE_SENSOR_RANGE}}


def _options(env_id: str) -> list[str]:
    return sorted(_env_class(env_id).option_names())


def _env_class(env_id: str) -> type:
    module, name = gym.spec(env_id).entry_point.split(":")
    return getattr(__import__(module, fromlist=[name]), name)


def _value(env_id: str, keyword: str):
    value = NON_DEFAULT[keyword]  # a KeyError here: a new keyword needs its non-default value in the table
    if isinstance(value, tuple) and isinstance(value[0], str):
        registered = gym.spec(env_id).kwargs.get(keyword, ENV_DEFAULTS.get(env_id, {}).get(keyword))
        value = value[0] if value[0] != registered else value[1]
    return value


def _act(obs: dict[str, np.ndarray], rng: np.random.Generator, wait: int, n_actions: int) -> int:
    """Under unicycle kinematics: for ``wait`` steps on the spot (the stop, else back and forth at the slowest speed,
    turning by π), then at full speed towards the current waypoint (the goal on the open floor), a random action one
    step in five. Waiting lets the crossing crowd pass (successes), not waiting runs into it (collisions)."""
    noise = int(rng.integers(80))
    if wait > 0:
        return STOP_ACTION if n_actions > STOP_ACTION else 8
    if rng.random() < 0.2:
        return noise
    robot = obs["robot"].astype(np.float64)
    target = obs["waypoints"][:2] if "waypoints" in obs else robot[Robot.GOAL]
    angle = math.atan2(target[1] - robot[1], target[0] - robot[0]) - robot[Robot.HEADING]
    return 64 + round(angle / (2 * math.pi / 16)) % 16


def _plain(value) -> str:
    """An exact text of an observation or info value (arrays by their bytes, floats by repr, nan equal to nan)."""
    if isinstance(value, dict):
        return "{" + ",".join(f"{k}:{_plain(value[k])}" for k in sorted(value)) + "}"
    if isinstance(value, np.ndarray):
        return f"{value.dtype}{value.shape}{value.tobytes().hex()}"
    return repr(value)


def trace(env: gym.Env, steps: int) -> list[str]:
    """Every reset and step of ``steps`` steps from ``reset(seed=0)`` (episodes go on from the env's generator), and
    the last frame when the env renders."""
    rng = np.random.default_rng(0)
    obs, info = env.reset(seed=0)
    out = [_plain(obs) + _plain(info)]
    episode, wait = 0, WAIT
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(_act(obs, rng, wait, env.action_space.n))
        wait -= 1
        out.append(_plain(obs) + repr((reward, terminated, truncated)) + _plain(info))
        if terminated or truncated:
            obs, info = env.reset()
            out.append(_plain(obs) + _plain(info))
            episode += 1
            wait = WAIT if episode % 2 == 0 else 0
    if env.unwrapped.render_mode is not None:
        out.append(_plain(env.render()))
    env.close()
    return out


@functools.cache
def default_trace(env_id: str) -> tuple[str, ...]:
    return tuple(trace(gym.make(env_id), STEPS.get(env_id, 300)))


# each env class in the default run; the registered variants of CrowdNavEnv (same class, other defaults) in `make slow`
CLASS_IDS = ("CrowdNav-v0", "CrowdNavWarehouse-v0")


@pytest.mark.parametrize(("env_id", "keyword"), [
    pytest.param(i, k, marks=() if i in CLASS_IDS else pytest.mark.slow) for i in ALL_IDS for k in _options(i)])
def test_every_option_changes_the_episodes_or_is_refused_by_name(env_id, keyword):
    value = _value(env_id, keyword)
    if keyword in REFUSED[env_id]:
        with pytest.raises(ValueError, match=keyword):
            gym.make(env_id, **{keyword: value})
        return
    env = gym.make(env_id, **{keyword: value})
    same = tuple(trace(env, STEPS.get(env_id, 300))) == default_trace(env_id)
    assert not same, f"{env_id} with {keyword}={value!r} plays the default's episodes"


def test_the_traces_see_every_outcome():
    """The traces can show a change of the success reward and of the collision penalties: they hold successes and
    collisions with pedestrians (and, in the warehouse, with racks or walls)."""
    for env_id in ALL_IDS:
        text = "".join(default_trace(env_id))
        assert "outcome:'success'" in text and "collision_with:'human'" in text, env_id
    assert "collision_with:'obstacle'" in "".join(default_trace("CrowdNavWarehouse-v0"))


def test_the_table_of_refusals_names_options_of_each_env():
    for env_id in ALL_IDS:
        assert REFUSED[env_id] <= set(_options(env_id)), env_id
