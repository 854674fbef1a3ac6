"""Property: whatever the constructor is given, the env refuses it by name at once, or serves every reset and step."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sb3_crowdnav.envs.crowd_nav import REWARD_KEYS, SCENE_KEYS, CrowdNavEnv

PARAMETERS = (*SCENE_KEYS, *REWARD_KEYS, "reward", "scenario")


def _number(lo: float, hi: float, wide: float):
    """Mostly values inside a parameter's range [lo, hi] (Python floats or NumPy scalars), sometimes up to ``wide``,
    a nan or a negative."""
    inside = st.floats(lo, hi, allow_nan=False, allow_infinity=False)
    outside = st.floats(0.0, wide, allow_nan=False, allow_infinity=False)
    return st.one_of(inside, inside, inside, inside.map(np.float32), outside, st.just(float("nan")), st.just(-1.0))


KWARGS = st.fixed_dictionaries({}, optional={
    "num_humans": st.one_of(st.integers(0, 10), st.integers(-2, 40), st.integers(0, 10).map(np.int64),
                            st.tuples(st.integers(0, 10), st.integers(0, 10))),
    "max_humans": st.one_of(st.integers(10, 20), st.integers(-1, 150)),
    "time_step": _number(0.05, 1.0, 5.0),
    "time_limit": _number(1.0, 60.0, 1e5),
    "robot_radius": _number(0.1, 0.6, 60.0),
    "human_radius": _number(0.1, 0.6, 10.0),
    "robot_v_pref": _number(0.2, 3.0, 20.0),
    "human_v_pref": _number(0.2, 3.0, 20.0),
    "circle_radius": _number(2.0, 30.0, 300.0),
    "square_width": _number(4.0, 60.0, 500.0),
    "start_noise": _number(0.0, 1.0, 50.0),
    "scenario": st.sampled_from(["circle_crossing", "circle_crossing", "square_crossing", "warehouse", "ring"]),
    "kinematics": st.sampled_from(["unicycle", "holonomic"]),
    "rotation_range": _number(0.5, 6.28, 7.0),
    "robot_visible": st.one_of(st.booleans(), st.booleans().map(np.bool_), st.just(1), _number(0.0, 1.0, 2.0)),
    "history_length": st.one_of(st.integers(1, 8), st.integers(0, 60)),
    "human_policy": st.sampled_from(["orca", "linear"]),
    "crowd": st.sampled_from(["orca", "orca", "linear", "social_force"]),
    "crowd_kwargs": st.one_of(st.none(), st.fixed_dictionaries({"safety_space": _number(0.0, 0.5, 5.0)}),
                              st.just({"radius": 1.0})),
    "human_speed": st.sampled_from(["fixed", "measured", "measured", "fast"]),
    "stop_probability": _number(0.0, 1.0, 3.0),
    "stop_duration": st.tuples(_number(0.0, 5.0, 1e4), _number(0.0, 10.0, 1e4)),
    "reward": st.sampled_from(["crowdnav", "comfort", "comfort_angular"]),
    "comfort_side": _number(0.1, 3.0, 2000.0),
    "comfort_person": _number(0.1, 3.0, 2000.0),
    "discomfort_factor": _number(0.0, 5.0, 1e6),
    "success_reward": _number(-5.0, 5.0, 1e4),
})


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kwargs=KWARGS, seed=st.integers(0, 2**16))
def test_refused_by_name_at_construction_or_200_good_steps(kwargs, seed):
    try:
        env = CrowdNavEnv(**kwargs)
    except (ValueError, TypeError) as exc:
        message = str(exc)
        assert any(name in message for name in PARAMETERS), message  # names the parameter that is wrong
        return
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    for _ in range(200):
        assert env.observation_space.contains(obs), {k: v for k, v in obs.items() if not np.isfinite(v).all()}
        obs, reward, terminated, truncated, _ = env.step(int(rng.integers(80)))
        assert np.isfinite(reward)
        if terminated or truncated:
            obs, _ = env.reset()
    assert env.observation_space.contains(obs)


def test_unknown_reset_options_are_refused():
    env = CrowdNavEnv()
    with pytest.raises(ValueError, match=r"reset options \['num_humans'\] are not supported"):
        env.reset(seed=0, options={"num_humans": 3})


def test_numpy_scalars_are_accepted_and_stored_as_python_values():
    env = CrowdNavEnv(time_step=np.float32(0.25), num_humans=np.int64(4), robot_visible=np.bool_(True))
    assert type(env.scene.time_step) is float and type(env.scene.num_humans) is int
    assert env.scene.robot_visible is True


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"human_radius": 3.0}, "human_radius must be <= 2.0 m"),
    ({"human_radius": 1.5}, "num_humans: 6 pedestrians of radius 1.5 m cannot be placed"),
    ({"robot_radius": 50.0}, "robot_radius must be <= 2.0 m"),
    ({"circle_radius": 0.3}, "cannot be placed reliably on the 0.3 m circle"),
    ({"square_width": 1, "scenario": "square_crossing"}, "cannot be placed reliably on the 1 m square"),
    ({"comfort_side": 720.0, "reward": "comfort"}, "comfort_side must be <= 10.0 m"),
    ({"max_humans": 10**12}, "max_humans must be <= 100"),
    ({"time_step": 1e-9}, "steps per episode"),
    ({"time_limit": 1e12}, "time_limit must be <= 3600.0 s"),
    ({"num_humans": (2, 40), "max_humans": 40}, "num_humans: 40 pedestrians"),
])
def test_values_that_failed_later_are_refused_at_construction(kwargs, message):
    with pytest.raises(ValueError, match=message):
        CrowdNavEnv(**kwargs)
