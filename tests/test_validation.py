"""One rule for bad input across the package: a wrong type is a ``TypeError``, a wrong value a ``ValueError``,
and both name the parameter. Checked here over a sample of every floor's public constructors."""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import pytest

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import APGValue, CrowdNavEnv, OrcaPolicy
from sb3_crowdnav.evaluation.policy_spec import PolicySpec
from sb3_crowdnav.evaluation.runner import RandomPolicy
from sb3_crowdnav.imitation import DQfD
from sb3_crowdnav.nn import ApgExtractor, LmExtractor, SfExtractor
from sb3_crowdnav.sim import RewardConfig, SceneConfig
from sb3_crowdnav.sim.simulator import CrowdSimulator
from sb3_crowdnav.sim.validation import (
    check_bool,
    check_choice,
    check_int,
    check_number,
    check_positive,
    check_probability,
    check_range,
)
from sb3_crowdnav.sim.warehouse.config import WarehouseConfig
from sb3_crowdnav.sim.warehouse.layout import LayoutRanges, WarehouseLayout
from sb3_crowdnav.training import ScheduleConfig


def _space() -> gym.spaces.Dict:
    return gym.make("CrowdNav-v0").observation_space


def _apg_value(**kwargs: Any) -> APGValue:
    return APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, **kwargs)


# (constructor, parameter, a value of a wrong type, a value of the right type but wrong)
CASES: list[tuple[str, Callable[..., Any], str, Any, Any]] = [
    ("SceneConfig", SceneConfig, "time_step", "0.25", -0.25),
    ("SceneConfig", SceneConfig, "max_humans", 10.0, 0),
    ("SceneConfig", SceneConfig, "history_length", True, 0),
    ("RewardConfig", RewardConfig, "success_reward", "1", float("nan")),
    ("RewardConfig", RewardConfig, "comfort_side", None, 0.0),
    ("WarehouseConfig", WarehouseConfig, "max_obstacles", 1.5, 0),
    ("WarehouseConfig", WarehouseConfig, "progress_reward", "0.1", 11.0),
    ("WarehouseConfig", WarehouseConfig, "dwell_time", "2-8", (8.0, 2.0)),
    ("LayoutRanges", LayoutRanges, "rows", "23", (3, 2)),
    ("WarehouseLayout", lambda **kw: WarehouseLayout(**{"width": 10.0, "height": 8.0, **kw}), "width", "10", -1.0),
    ("CrowdNavEnv", CrowdNavEnv, "gamma", "0.9", 1.5),
    ("CrowdNavEnv", CrowdNavEnv, "num_humans", 2.5, -1),
    ("CrowdNavEnv", CrowdNavEnv, "progress_reward", "0.1", -0.1),
    ("CrowdSimulator", lambda **kw: CrowdSimulator(SceneConfig(), RewardConfig(), **kw), "progress_reward", "0.1", 11.0),
    ("OrcaPolicy", OrcaPolicy, "safety_space", "0", -0.1),
    ("RandomPolicy", RandomPolicy, "seed", 1.5, -1),
    ("ApgExtractor", lambda **kw: ApgExtractor(_space(), **kw), "lstm_hidden_size", 50.0, 0),
    ("ApgExtractor", lambda **kw: ApgExtractor(_space(), **kw), "r_max", "3", 0.0),
    ("SfExtractor", lambda **kw: SfExtractor(_space(), **kw), "force_range", [0.3], -0.3),
    ("LmExtractor", lambda **kw: LmExtractor(_space(), **kw), "cell_size", "1", 0.0),
    ("ScheduleConfig", ScheduleConfig, "n_envs", 2.0, 0),
    ("ScheduleConfig", ScheduleConfig, "exploration_initial_eps", "0.5", 1.5),
    ("APGValue", _apg_value, "batch_size", 32.0, 0),
    ("APGValue", _apg_value, "gamma", "0.9", 0.0),
    ("DQfD", lambda **kw: DQfD("MultiInputPolicy", "CrowdNav-v0", **kw), "demo_batch_size", "64", 0),
]


@pytest.mark.parametrize(("constructor", "parameter", "wrong_type", "wrong_value"),
                         [case[1:] for case in CASES], ids=[f"{case[0]}-{case[2]}" for case in CASES])
def test_wrong_type_is_a_type_error_and_wrong_value_a_value_error(constructor, parameter, wrong_type, wrong_value):
    name = re.escape(parameter)
    with pytest.raises(TypeError, match=name):
        constructor(**{parameter: wrong_type})
    with pytest.raises(ValueError, match=name) as caught:
        constructor(**{parameter: wrong_value})
    assert not isinstance(caught.value, TypeError)  # a plain ValueError, not the dual observation-space error


def test_bool_options_refuse_look_alikes():
    """A bool option takes a bool: ``1`` or ``"yes"`` is a slip to report, not a truthy value to accept."""
    for value in (1, "yes", None):
        with pytest.raises(TypeError, match="robot_visible must be a bool"):
            SceneConfig(robot_visible=value)
        with pytest.raises(TypeError, match="bootstrap_timeouts must be a bool"):
            ScheduleConfig(bootstrap_timeouts=value)


def test_policy_spec_follows_the_rule():
    with pytest.raises(TypeError, match="policy"):
        PolicySpec.parse(3)
    with pytest.raises(ValueError, match="policy"):
        PolicySpec.parse("random:x")


@pytest.mark.parametrize(("check", "args", "good", "wrong_type", "wrong_value"), [
    (check_int, (1,), 3, 3.0, 0),
    (check_number, (), 0.5, "0.5", -0.5),
    (check_positive, (), 1e-9, True, 0.0),
    (check_range, (0, 1), 1.0, "1", 1.01),
    (check_probability, (), 0.0, None, -1e-9),
    (check_choice, (("a", "b"),), "a", None, "c"),
    (check_bool, (), False, 0, None),
])
def test_each_validator(check, args, good, wrong_type, wrong_value):
    check("x", good, *args)
    if check is check_choice:  # a value of another type is also just not one of the choices
        with pytest.raises(ValueError, match="x must be one of"):
            check("x", wrong_type, *args)
    else:
        with pytest.raises(TypeError, match=r"^x must be"):
            check("x", wrong_type, *args)
    if wrong_value is not None:
        with pytest.raises(ValueError, match=r"^x must be"):
            check("x", wrong_value, *args)


def test_numpy_scalars_are_accepted_like_python_ones():
    import numpy as np

    check_int("n", np.int64(3), 1)
    check_number("x", np.float32(0.5))
    check_bool("flag", np.bool_(True))
    check_range("open interval", 0.5, 0, 1, low_open=True, high_open=True)
    with pytest.raises(ValueError, match=r"must be in \(0, 1\)"):
        check_range("open interval", 1.0, 0, 1, low_open=True, high_open=True)
