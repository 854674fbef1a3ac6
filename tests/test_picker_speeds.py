"""``human_speed="measured"`` in ``CrowdNavWarehouse-v0``: each picker walks at its own preferred speed, drawn per
episode from the open floor's measured distribution after every other draw of the reset."""

from __future__ import annotations

import importlib.util
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.sim.config import MEASURED_SPEED
from sb3_crowdnav.sim.observation import Human

CROWDS = ["orca", pytest.param("social_force", marks=pytest.mark.skipif(
    importlib.util.find_spec("jupedsim") is None, reason="social force needs jupedsim"))]
STOP = 80  # the robot stands: the pickers walk their jobs around it
_, _, LOW, HIGH = MEASURED_SPEED


def _pickers(env):
    return env.unwrapped.sim.pickers


def _true_speeds(env) -> np.ndarray:
    """The pickers' actual speeds (n,) [m/s] (the simulator's state, not what the sensor shows)."""
    sim = env.unwrapped.sim
    return np.linalg.norm(sim.history[-1, : sim.num_humans, Human.VEL], axis=-1)


def test_measured_picker_speeds_are_drawn_per_picker_and_walked():
    """ORCA pickers never walk faster than their own speed, and some reach it in the aisles (most are slowed near
    the racks and each other): the speeds reached differ between pickers and lie in the measured range (with "fixed",
    everyone at human_v_pref)."""
    env = gym.make("CrowdNavWarehouse-v0", human_speed="measured", num_humans=8, robot_visible=False)
    reached, drawn = [], []
    for seed in range(3):
        env.reset(seed=seed)
        v_prefs = _pickers(env).v_prefs
        top = np.zeros(len(v_prefs))
        for _ in range(60):
            env.step(STOP)
            speeds = _true_speeds(env)
            assert (speeds <= v_prefs * (1 + 1e-6)).all()  # ORCA's maximum speed is each picker's own
            top = np.maximum(top, speeds)
        reached.extend(top[np.isclose(top, v_prefs, rtol=0.01)])
        drawn.append(v_prefs)
    reached, drawn = np.array(reached), np.concatenate(drawn)
    assert len(reached) >= 3 and LOW <= reached.min() and reached.max() <= HIGH and np.ptp(reached) > 0.3
    assert len(np.unique(drawn)) == len(drawn)  # per picker and per episode
    fixed = gym.make("CrowdNavWarehouse-v0", num_humans=8, human_v_pref=0.8)
    fixed.reset(seed=0)
    assert (_pickers(fixed).v_prefs == 0.8).all()


def test_the_speeds_are_the_resets_last_draw():
    """Same seed: the layout, the robot, the pickers' slots, jobs, dwells and who sees the robot are those of "fixed"."""
    fixed = gym.make("CrowdNavWarehouse-v0", robot_visible=0.5, num_humans=8)
    measured = gym.make("CrowdNavWarehouse-v0", robot_visible=0.5, num_humans=8, human_speed="measured")
    for seed in range(4):
        a, _ = fixed.reset(seed=seed)
        b, _ = measured.reset(seed=seed)
        assert fixed.unwrapped.layout.to_dict() == measured.unwrapped.layout.to_dict()
        np.testing.assert_array_equal(a["robot"], b["robot"])
        np.testing.assert_array_equal(a["humans"], b["humans"])
        p, q = _pickers(fixed), _pickers(measured)
        for name in ("slot", "dwell", "waypoint", "sees_robot"):
            np.testing.assert_array_equal(getattr(p, name), getattr(q, name))
        assert p.routes == q.routes
        assert not np.array_equal(p.v_prefs, q.v_prefs)


@pytest.mark.parametrize("crowd", CROWDS)
def test_each_picker_heads_for_its_waypoint_at_its_own_speed(crowd):
    """A walking picker's preferred velocity has the length of its speed (shorter only slowing into its slot); with
    social force a faster picker's drive holds it closer to a rack, so it must come closer to a waypoint."""
    env = gym.make("CrowdNavWarehouse-v0", human_speed="measured", crowd=crowd, num_humans=8)
    env.reset(seed=3)
    pickers = _pickers(env)
    mid_route = 0
    for _ in range(20):
        positions = env.unwrapped.sim.history[-1, : pickers.n, Human.POS]
        lengths = np.linalg.norm(pickers.preferred_velocities(positions), axis=-1)
        assert (lengths <= pickers.v_prefs * (1 + 1e-12)).all()
        walking = ~pickers.standing & (pickers.waypoint < pickers._route_lengths - 1)
        np.testing.assert_allclose(lengths[walking], pickers.v_prefs[walking], rtol=1e-12)
        mid_route += int(walking.sum())
        env.step(STOP)
    assert mid_route > 0
    order = np.argsort(pickers.v_prefs)
    if crowd == "orca":  # no push: every picker reaches a waypoint within the same distance
        assert np.ptp(pickers.waypoint_arrival) == 0 and np.ptp(pickers.slot_arrival) == 0
    else:
        assert (np.diff(pickers.waypoint_arrival[order]) <= 0).all() and np.ptp(pickers.waypoint_arrival) > 0


@pytest.mark.parametrize("crowd", CROWDS)
def test_same_seed_same_episode_with_measured_speeds(crowd):
    env = gym.make("CrowdNavWarehouse-v0", human_speed="measured", crowd=crowd)

    def run(seed):
        rng = np.random.default_rng(seed)
        frames = [env.reset(seed=seed)[0]]
        speeds = _pickers(env).v_prefs.copy()
        for _ in range(40):
            obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
            frames.append(obs)
            if terminated or truncated:
                break
        return speeds, frames

    (speeds_a, a), (speeds_b, b), (speeds_c, _) = run(7), run(7), run(8)
    np.testing.assert_array_equal(speeds_a, speeds_b)
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        for key in x:
            np.testing.assert_array_equal(x[key], y[key])
    assert not np.array_equal(speeds_a, speeds_c)


@pytest.mark.parametrize("crowd", CROWDS)
def test_the_checkers_pass_without_warnings_and_the_bounds_hold(crowd):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make("CrowdNavWarehouse-v0", human_speed="measured", crowd=crowd)
        gym_check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)
        sb3_check_env(gym.make("CrowdNavWarehouse-v0", human_speed="measured", crowd=crowd), warn=True)
    assert not [str(w.message) for w in caught]
    velocity_bound = env.observation_space["humans"].high.reshape(-1, 5)[0, Human.VEL]
    assert (velocity_bound >= HIGH).all()  # the fastest picker fits
    env.reset(seed=0)
    for _ in range(60):
        obs, _, terminated, truncated, _ = env.step(STOP)
        assert env.observation_space.contains(obs)
        if terminated or truncated:
            env.reset()


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"human_speed": "measured", "human_v_pref": 1.2}, "human_v_pref"),
    ({"human_speed": "measured", "stop_probability": 0.2}, "stop_probability"),
    ({"human_speed": "walking"}, "human_speed"),
])
def test_what_the_pickers_never_read_is_refused_by_name(kwargs, name):
    with pytest.raises(ValueError, match=name):
        gym.make("CrowdNavWarehouse-v0", **kwargs)
