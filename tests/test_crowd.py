"""The crowd-model seam (``crowd=``, ``crowd_kwargs=``) and the population (``human_speed``, ``stop_probability``,
``stop_duration``, ``robot_visible`` as a share, ``num_humans=0``) of the open floor."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.envs.crowd_nav import CrowdNavEnv
from sb3_crowdnav.sim import CROWD_MODELS, OrcaPolicy, SceneConfig
from sb3_crowdnav.sim.config import MEASURED_SPEED
from sb3_crowdnav.sim.crowd import RobotAgent, make_crowd
from sb3_crowdnav.sim.crowd_settings import CROWD_SETTINGS, OrcaCrowdSettings
from sb3_crowdnav.sim.observation import Human
from sb3_crowdnav.sim.population import People

NEW_OPTIONS = [
    {"crowd": "linear"},
    {"crowd_kwargs": {"safety_space": 0.2}},
    {"human_speed": "measured"},
    {"stop_probability": 0.7, "stop_duration": (1.0, 3.0)},
    {"robot_visible": 0.5},
]


def _episodes(env: gym.Env, seed: int, steps: int = 120) -> list[bytes]:
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    out = [obs["humans"].tobytes()]
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(int(rng.integers(80)))
        out.append(obs["humans"].tobytes() + obs["robot"].tobytes() + repr((reward, info["outcome"])).encode())
        if terminated or truncated:
            obs, _ = env.reset()
    return out


@pytest.mark.parametrize("kwargs", NEW_OPTIONS, ids=lambda k: ",".join(k))
def test_same_seed_same_episodes_and_another_seed_others(kwargs):
    first = _episodes(gym.make("CrowdNav-v0", **kwargs), 3)
    assert first == _episodes(gym.make("CrowdNav-v0", **kwargs), 3)
    assert first != _episodes(gym.make("CrowdNav-v0", **kwargs), 4)


def test_every_crowd_model_has_its_settings_under_its_name():
    assert set(CROWD_MODELS) == set(CROWD_SETTINGS)
    for name in CROWD_MODELS:
        if name == "replay":  # needs a recording: tests/test_replay.py
            continue
        assert type(SceneConfig(crowd=name).crowd_kwargs) is CROWD_SETTINGS[name]


BAD = [  # (kwargs, exception, the name the message gives)
    ({"crowd": "social_forces"}, ValueError, "crowd"),
    ({"crowd": 3}, ValueError, "crowd"),  # not one of the choices, whatever its type
    ({"crowd_kwargs": [("safety_space", 0.1)]}, TypeError, "crowd_kwargs"),
    ({"crowd_kwargs": {"neighbour_dist": 3.0}}, ValueError, "crowd_kwargs"),
    ({"crowd_kwargs": {"safety_space": "0.1"}}, TypeError, "safety_space"),
    ({"crowd_kwargs": {"safety_space": -0.1}}, ValueError, "safety_space"),
    ({"crowd_kwargs": {"safety_space": 3.0}}, ValueError, "safety_space"),
    ({"crowd": "linear", "crowd_kwargs": {"safety_space": 0.1}}, ValueError, "crowd_kwargs"),
    ({"crowd": "linear", "human_policy": "linear"}, ValueError, "human_policy"),
    ({"crowd": "orca", "human_policy": "linear"}, ValueError, "human_policy"),
    ({"human_policy": "social_force"}, ValueError, "human_policy"),
    ({"human_speed": "fast"}, ValueError, "human_speed"),
    ({"human_speed": "measured", "human_v_pref": 1.2}, ValueError, "human_v_pref"),
    ({"stop_probability": "0.5"}, TypeError, "stop_probability"),
    ({"stop_probability": 1.5}, ValueError, "stop_probability"),
    ({"stop_probability": math.nan}, ValueError, "stop_probability"),
    ({"stop_probability": 0.5, "stop_duration": "long"}, TypeError, "stop_duration"),
    ({"stop_probability": 0.5, "stop_duration": (3.0, 1.0)}, ValueError, "stop_duration"),
    ({"stop_probability": 0.5, "stop_duration": (1.0,)}, ValueError, "stop_duration"),
    ({"stop_probability": 0.5, "stop_duration": (-1.0, 2.0)}, ValueError, "stop_duration"),
    ({"stop_probability": 0.5, "stop_duration": (1.0, "2")}, TypeError, "stop_duration"),
    ({"stop_duration": (1.0, 2.0)}, ValueError, "stop_duration"),  # no one stops: it would have no effect
    ({"robot_visible": 1}, TypeError, "robot_visible"),  # an int is a slip, not a share
    ({"robot_visible": "half"}, TypeError, "robot_visible"),
    ({"robot_visible": 1.5}, ValueError, "robot_visible"),
    ({"robot_visible": -0.1}, ValueError, "robot_visible"),
    ({"robot_visible": 0.5, "crowd": "linear"}, ValueError, "robot_visible"),
]


@pytest.mark.parametrize(("kwargs", "exception", "name"), BAD, ids=lambda x: str(x))
def test_bad_values_are_refused_at_construction_by_name(kwargs, exception, name):
    with pytest.raises(exception, match=name) as caught:
        gym.make("CrowdNav-v0", **kwargs)
    if exception is ValueError:
        assert not isinstance(caught.value, TypeError)


def test_the_warehouse_refuses_the_open_floors_crowd_settings():
    for kwargs in ({"crowd": "linear"}, {"stop_probability": 0.5}, {"stop_duration": (1.0, 2.0)}):
        with pytest.raises(ValueError, match=next(iter(kwargs))):
            gym.make("CrowdNavWarehouse-v0", **kwargs)
    # a share of pickers seeing the robot is the warehouse's too now (tests/test_warehouse_visibility.py), and so are
    # measured walking speeds (tests/test_picker_speeds.py)
    assert gym.make("CrowdNavWarehouse-v0", robot_visible=0.5).unwrapped.scene.robot_visible == 0.5
    assert gym.make("CrowdNavWarehouse-v0", human_speed="measured").unwrapped.scene.human_speed == "measured"


def test_human_policy_is_the_old_name_of_crowd():
    old, new = SceneConfig(human_policy="linear"), SceneConfig(crowd="linear")
    assert old == new and old.crowd == "linear" and old.human_policy is None
    assert _episodes(gym.make("CrowdNav-v0", human_policy="linear"), 0) == _episodes(
        gym.make("CrowdNav-v0", crowd="linear"), 0)


def test_shares_of_none_and_all_are_the_bools():
    assert SceneConfig(robot_visible=0.0).robot_visible is False
    assert SceneConfig(robot_visible=np.float32(1.0)).robot_visible is True
    assert _episodes(gym.make("CrowdNav-v0", robot_visible=1.0), 0) == _episodes(
        gym.make("CrowdNav-v0", robot_visible=True), 0)


# ---------------------------------------------------------------------- the population
def _people(env: CrowdNavEnv, resets: int) -> list[People]:
    out = []
    env.reset(seed=0)
    for _ in range(resets):
        out.append(env.sim.people)
        env.reset()
    return out


def test_fixed_speeds_are_the_papers_and_measured_ones_follow_their_distribution():
    assert all((p.v_prefs == 1.0).all() for p in _people(CrowdNavEnv(), 5))
    speeds = np.concatenate([p.v_prefs for p in _people(CrowdNavEnv(human_speed="measured"), 300)])
    mean, sd, low, high = MEASURED_SPEED
    assert speeds.min() >= low and speeds.max() <= high
    assert abs(speeds.mean() - mean) < 0.03 and abs(speeds.std() - sd) < 0.03
    inside = speeds[(speeds > low) & (speeds < high)]
    assert len(np.unique(inside)) == len(inside) > 0.98 * len(speeds)  # drawn per person; a few clipped


def test_measured_speeds_are_walked():
    """Linear walkers far from their goals walk at exactly their drawn speeds."""
    env = CrowdNavEnv(crowd="linear", human_speed="measured")
    env.reset(seed=1)
    env.step(0)
    n = env.sim.num_humans
    speed = np.linalg.norm(env.sim.history[-1, :n, Human.VEL], axis=-1)
    np.testing.assert_allclose(speed, env.sim.people.v_prefs, rtol=1e-12)


def test_a_share_of_people_see_the_robot():
    seeing = np.concatenate([p.sees_robot for p in _people(CrowdNavEnv(robot_visible=0.5), 300)])
    assert len(seeing) == 1800 and 0.45 < seeing.mean() < 0.55
    assert all(p.sees_robot.all() for p in _people(CrowdNavEnv(robot_visible=True), 3))
    assert not any(p.sees_robot.any() for p in _people(CrowdNavEnv(), 3))


def test_people_stop_when_drawn_and_stand_for_their_duration():
    env = CrowdNavEnv(crowd="linear", stop_probability=0.5, stop_duration=(1.0, 3.0), time_limit=30.0)
    stopping = standing_steps = 0
    for people in _people(env, 40):
        stops = np.isfinite(people.stop_start)
        stopping += stops.sum()
        duration = people.stop_end[stops] - people.stop_start[stops]
        assert ((duration >= 1.0) & (duration <= 3.0)).all()
        walk = np.linalg.norm(people.goals - people.starts, axis=-1) / people.v_prefs
        assert (people.stop_start[stops] <= walk[stops]).all()
    assert 0.35 < stopping / (40 * 6) < 0.65
    env.reset(seed=5)
    people, dt = env.sim.people, env.scene.time_step
    for step in range(60):
        t = step * dt  # the preferred velocity of step k is the one at its start
        env.step(0)
        velocity = env.sim.history[-1, : people.n, Human.VEL]
        standing = (people.stop_start <= t) & (t < people.stop_end)
        assert (velocity[standing] == 0.0).all()
        standing_steps += standing.sum()
    assert standing_steps > 0


def test_orca_people_who_stop_stand():
    env = CrowdNavEnv(stop_probability=1.0, stop_duration=(4.0, 4.0))
    env.reset(seed=2)
    people, dt = env.sim.people, env.scene.time_step
    slow = []
    for step in range(40):
        t = step * dt
        env.step(0)
        speed = np.linalg.norm(env.sim.history[-1, : people.n, Human.VEL], axis=-1)
        standing = (people.stop_start + 1.0 <= t) & (t < people.stop_end)  # a second after stopping
        slow += speed[standing].tolist()
    assert len(slow) > 20 and np.median(slow) < 0.05  # ORCA people stand (stepping aside now and then)


# ---------------------------------------------------------------------- who sees the robot
def _scripted(sees: list[bool], steps: int = 40) -> np.ndarray:
    """Two people walking down, 6 m apart, beyond each other's 2 m ORCA neighbourhood; the robot walks up at 1 m/s
    through both (close to A at about 2 s, to B at about 5 s). The people's positions (steps, 2, 2)."""
    scene = SceneConfig(num_humans=2, orca_neighbor_dist=2.0, robot_visible=True)
    people = People(starts=np.array([[0.2, 0.0], [-0.2, 6.0]]), goals=np.array([[0.2, -20.0], [-0.2, -14.0]]),
                    radii=np.full(2, 0.3), v_prefs=np.ones(2), sees_robot=np.array(sees),
                    stop_start=np.full(2, math.inf), stop_end=np.full(2, math.inf))
    crowd = make_crowd(scene)
    robot = RobotAgent((0.0, -4.0), (0.0, 0.0), 0.3)
    crowd.reset(np.random.default_rng(0), people, robot)
    positions, out = people.starts, []
    for k in range(steps):
        preferred = [(0.0, -1.0)] * 2
        positions, _ = crowd.step(preferred, robot)
        robot = RobotAgent((0.0, -4.0 + (k + 1) * 0.25), (0.0, 1.0), 0.3)
        out.append(positions.copy())
    assert np.linalg.norm(np.diff(np.array(out), axis=1), axis=-1).min() > 2.0  # A and B never see each other
    return np.array(out)


def test_people_who_do_not_see_the_robot_walk_as_in_a_crowd_that_does_not():
    """In a crowd where A sees the robot and B does not, A walks as in a crowd that all sees it and B as in one that
    does not; both dodge when they see it (so the test fails if the split went the other way or nowhere)."""
    mixed, seeing, blind = _scripted([True, False]), _scripted([True, True]), _scripted([False, False])
    np.testing.assert_array_equal(mixed[:, 0], seeing[:, 0])
    np.testing.assert_array_equal(mixed[:, 1], blind[:, 1])
    assert np.abs(seeing[:, 0] - blind[:, 0]).max() > 0.1  # A dodges the robot it sees
    assert np.abs(seeing[:, 1] - blind[:, 1]).max() > 0.1  # so would B


def test_a_share_of_people_seeing_the_robot_changes_the_episodes_between_none_and_all():
    runs = {share: _episodes(gym.make("CrowdNav-v0", robot_visible=share), 7, 80) for share in (False, 0.5, True)}
    assert runs[0.5] != runs[False] and runs[0.5] != runs[True]


def test_crowd_kwargs_are_stored_as_the_models_frozen_settings():
    assert SceneConfig(crowd_kwargs={"safety_space": 0.1}).crowd_kwargs == OrcaCrowdSettings(0.1)


# ---------------------------------------------------------------------- an empty floor
@pytest.mark.parametrize("num_humans", [0, (0, 2)])
def test_an_empty_floor_passes_the_checkers_without_warnings(num_humans):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make("CrowdNav-v0", num_humans=num_humans)
        gym_check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)
        sb3_check_env(gym.make("CrowdNav-v0", num_humans=num_humans), warn=True)
    assert not [str(w.message) for w in caught]


def test_an_empty_floor_gives_a_sensible_observation_finite_info_and_orca_reaches_the_goal():
    env = gym.make("CrowdNav-v0", num_humans=0)
    policy = OrcaPolicy.from_env(env, mapping="constrained")
    obs, info = env.reset(seed=0)
    assert info["num_humans"] == 0 and not obs["humans_mask"].any() and not obs["humans"].any()
    far = env.unwrapped.no_one_distance
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(int(policy.predict(obs)[0]))
        done = terminated or truncated
        assert info["min_distance"] == far and math.isfinite(reward)
        assert not obs["humans_mask"].any() and env.observation_space.contains(obs)
    stats = info["episode_stats"]
    assert info["outcome"] == "success" and stats["min_separation"] == far
    # means over no steps (nan by contract): the separations in discomfort and comfort zones, the speed near people
    documented_nan = {"discomfort_separation", "comfort_zone_separation", "speed_near_people"}
    assert all(math.isfinite(v) for k, v in stats.items() if isinstance(v, float) and k not in documented_nan)
    assert far > 2 * env.unwrapped.schema.bounds(1, 1, 1, 1)["robot"][1][0]  # farther than any two positions


def test_the_lookahead_acts_on_an_empty_floor():
    from sb3_crowdnav.apg_value import APGValue

    env = gym.make("CrowdNav-v0", num_humans=0)
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0)
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        action, _ = model.predict(obs, deterministic=True)
        assert env.action_space.contains(int(action))
        obs, *_ = env.step(int(action))


@pytest.mark.parametrize("crowd", ["linear", "social_force", "measured"])
def test_the_policy_cannot_tell_which_crowd_runs(crowd):
    """The lookahead stays honest: the world contract a model is checked and propagated with, the observation's keys
    and shapes, and the shipped model's decision on the same observation are the same whatever moves the people."""
    from sb3_crowdnav.models import pretrained
    from sb3_crowdnav.serialization import same_layout
    from sb3_crowdnav.sim.world import compare_worlds

    kwargs = {"human_speed": "measured"} if crowd == "measured" else {"crowd": crowd}
    paper, other = gym.make("CrowdNav-v0"), gym.make("CrowdNav-v0", **kwargs)
    assert other.unwrapped.world == paper.unwrapped.world
    assert compare_worlds(paper.unwrapped.world, other.unwrapped.world) is None
    assert same_layout(paper.observation_space, other.observation_space)
    obs, _ = other.reset(seed=1)
    for _ in range(3):
        obs, *_ = other.step(0)
    a = pretrained("apg_rl", env=paper).predict(obs, deterministic=True)[0]
    b = pretrained("apg_rl", env=other).predict(obs, deterministic=True)[0]
    assert a == b
