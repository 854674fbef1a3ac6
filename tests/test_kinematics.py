"""The robot's kinematics: the stop action, the acceleration and turn-rate limits, one rule for env, lookahead and ORCA."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import OrcaPolicy
from sb3_crowdnav.apg_value.propagation import PropagationModel
from sb3_crowdnav.sim.actions import N_ACTIONS, STOP_ACTION, action_table, apply_action, wrap_angle
from sb3_crowdnav.sim.observation import Robot

DT = 0.25
LIMITS = {"unicycle": {"max_acceleration": 1.0, "max_turn_rate": 1.5}, "holonomic": {"max_acceleration": 1.0}}
SMALL = {"num_humans": 1, "time_limit": 5.0}  # 20-step episodes with one person: many short transitions


def _speed(robot: np.ndarray) -> float:
    return float(np.hypot(*robot[Robot.VEL]))


def _step_changes(before: np.ndarray, after: np.ndarray) -> tuple[float, float, float]:
    """(speed change [m/s], heading change [rad], velocity change [m/s]) of one step, float64 from float32 states."""
    before, after = before.astype(np.float64), after.astype(np.float64)
    turn = abs(float(wrap_angle(after[Robot.HEADING] - before[Robot.HEADING])))
    return abs(_speed(after) - _speed(before)), turn, float(np.hypot(*(after[Robot.VEL] - before[Robot.VEL])))


@pytest.mark.parametrize("kinematics", ["unicycle", "holonomic"])
def test_the_robot_never_exceeds_its_limits_over_200_random_action_episodes(kinematics):
    env = gym.make("CrowdNav-v0", kinematics=kinematics, actions="with_stop", **LIMITS[kinematics], **SMALL)
    rng = np.random.default_rng(0)
    most = np.zeros(3)
    for episode in range(200):
        obs, _ = env.reset(seed=episode)
        done = False
        while not done:
            before = obs["robot"]
            obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
            most = np.maximum(most, _step_changes(before, obs["robot"]))
            assert _speed(obs["robot"]) <= 1.0 + 1e-6  # never beyond v_pref
            done = terminated or truncated
    speed_change, turn, velocity_change = most
    a_dt = LIMITS[kinematics]["max_acceleration"] * DT
    if kinematics == "unicycle":
        w_dt = LIMITS[kinematics]["max_turn_rate"] * DT
        assert speed_change <= a_dt + 1e-6 and turn <= w_dt + 1e-6
        assert speed_change > 0.99 * a_dt and turn > 0.99 * w_dt  # the limits bind (random commands ask for more)
    else:
        assert velocity_change <= a_dt + 1e-6
        assert velocity_change > 0.99 * a_dt


def test_without_limits_the_paper_robot_turns_and_brakes_at_once():
    """The default robot (the paper's) is unlimited: random actions change speed and heading beyond any AMR's."""
    env = gym.make("CrowdNav-v0", **SMALL)
    rng = np.random.default_rng(1)
    obs, _ = env.reset(seed=0)
    most = np.zeros(3)
    for _ in range(20):
        before = obs["robot"]
        obs, *_ = env.step(int(rng.integers(N_ACTIONS)))
        most = np.maximum(most, _step_changes(before, obs["robot"]))
    assert env.action_space.n == N_ACTIONS and most[0] > 0.5 and most[1] > 2.0


@pytest.mark.parametrize("kinematics", ["unicycle", "holonomic"])
@pytest.mark.parametrize("limited", [False, True])
def test_the_stop_holds_the_robot_still(kinematics, limited):
    """From rest the stop keeps the robot where it is; moving, it brakes (by at most a_max·Δt per step with limits)
    to a standstill, and from then on the position does not change by a bit."""
    limits = LIMITS[kinematics] if limited else {}
    env = gym.make("CrowdNav-v0", kinematics=kinematics, actions="with_stop", num_humans=0, **limits)
    assert env.action_space.n == STOP_ACTION + 1
    speeds, directions = action_table(1.0, actions="with_stop")
    assert (speeds[STOP_ACTION], directions[STOP_ACTION]) == (0.0, 0.0) and speeds[:STOP_ACTION].min() > 0
    obs, _ = env.reset(seed=3)
    start = obs["robot"].copy()
    obs, *_ = env.step(STOP_ACTION)
    np.testing.assert_array_equal(obs["robot"][Robot.POS], start[Robot.POS])
    np.testing.assert_array_equal(obs["robot"][Robot.VEL], 0.0)
    for _ in range(6):  # full speed straight on (action 64), as far as the limits let it
        obs, *_ = env.step(64)
    speed = _speed(obs["robot"])
    assert speed > 0.5
    braking = []
    for _ in range(8):
        obs, *_ = env.step(STOP_ACTION)
        braking.append(_speed(obs["robot"]))
    if limited:  # 1 m/s² over 0.25 s steps: 0.25 m/s less per step
        np.testing.assert_allclose(braking[:3], [max(speed - 0.25 * k, 0.0) for k in (1, 2, 3)], atol=1e-6)
    else:
        assert braking[0] == 0.0
    assert braking[-1] == 0.0
    still = obs["robot"].copy()
    for _ in range(3):
        obs, *_ = env.step(STOP_ACTION)
    np.testing.assert_array_equal(obs["robot"][Robot.POS], still[Robot.POS])
    np.testing.assert_allclose(obs["robot"][Robot.HEADING], still[Robot.HEADING], atol=1e-6)


@pytest.mark.parametrize(("env_id", "kwargs"), [
    ("CrowdNav-v0", {"kinematics": "unicycle", "crowd": "linear", **LIMITS["unicycle"]}),
    ("CrowdNav-v0", {"kinematics": "holonomic", "crowd": "linear", **LIMITS["holonomic"]}),
    ("CrowdNavWarehouse-v0", {}),  # its defaults: the stop, both limits, occlusion by racks and an 8 m range
])
def test_env_and_lookahead_agree_on_random_transitions_with_limits_and_occlusion(env_id, kwargs):
    """The lookahead propagates the robot by the env's rule (the same compiled move()): on random states and actions
    its next robot state is the env's (to float32), and on the open floor with constant-velocity people so is R. In
    the warehouse the racks hide pickers: the lookahead reads the observation only, so it predicts from those seen."""
    env = gym.make(env_id, actions="with_stop", num_humans=3, **kwargs)
    world = env.unwrapped.world
    assert world.max_acceleration == 1.0
    model = PropagationModel(world, env.unwrapped.scene.history_length, 0.9)
    rng = np.random.default_rng(5)
    obs, _ = env.reset(seed=11)
    checked = hidden = 0
    for _ in range(150):
        prop = model(obs["robot"][None], obs["humans"][None], obs["humans_mask"][None],
                     {k: obs[k][None] for k in ("obstacles", "obstacles_mask", "waypoints") if k in obs})
        assert prop.reward.shape == (1, world.n_actions)
        action = int(rng.integers(world.n_actions))
        nxt, reward, terminated, truncated, _ = env.step(action)
        diff = prop.robot[0, action] - nxt["robot"]
        diff[Robot.HEADING] = wrap_angle(diff[Robot.HEADING])
        np.testing.assert_allclose(diff, 0.0, atol=2e-5)
        if env_id == "CrowdNav-v0":
            assert prop.reward[0, action] == pytest.approx(reward, abs=1e-4)
            assert bool(prop.terminal[0, action]) == terminated
        checked += 1
        hidden += int(env.unwrapped.sim.mask.sum() - nxt["humans_mask"].sum())
        obs = env.reset()[0] if terminated or truncated else nxt
    assert checked == 150
    assert (hidden > 0) == (env_id == "CrowdNavWarehouse-v0")  # occlusion was at work in the warehouse


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"max_acceleration": 0.0}, "max_acceleration must be > 0"),
    ({"max_acceleration": -1.0}, "max_acceleration must be > 0"),
    ({"max_turn_rate": 0.0}, "max_turn_rate must be > 0"),
    ({"max_turn_rate": -1.5}, "max_turn_rate must be > 0"),
    ({"max_acceleration": math.inf}, "max_acceleration must be finite"),
    ({"max_turn_rate": 1.5, "kinematics": "holonomic"}, "max_turn_rate must be None with kinematics='holonomic'"),
    ({"actions": "stop"}, "actions must be one of"),
])
@pytest.mark.parametrize("env_id", ["CrowdNav-v0", "CrowdNavWarehouse-v0"])
def test_infeasible_kinematics_are_refused_at_construction(env_id, kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(env_id, **kwargs)
    with pytest.raises(TypeError, match="max_acceleration must be a real number"):
        gym.make(env_id, max_acceleration="1.0")


def test_the_warehouse_robot_is_a_warehouse_amr_and_the_paper_robot_on_request():
    world = gym.make("CrowdNavWarehouse-v0").unwrapped.world
    assert (world.actions, world.max_acceleration, world.max_turn_rate) == ("with_stop", 1.0, 1.5)
    holonomic = gym.make("CrowdNavWarehouse-v0", kinematics="holonomic").unwrapped.world
    assert (holonomic.max_acceleration, holonomic.max_turn_rate) == (1.0, None)
    paper = gym.make("CrowdNavWarehouse-v0", actions="paper", max_acceleration=None, max_turn_rate=None)
    assert paper.action_space.n == N_ACTIONS and paper.unwrapped.world.max_turn_rate is None
    assert gym.make("CrowdNav-v0").unwrapped.world.actions == "paper"


@pytest.mark.parametrize(("env_id", "kwargs"), [
    ("CrowdNav-v0", {"actions": "with_stop", **LIMITS["unicycle"]}),
    ("CrowdNav-v0", {"kinematics": "holonomic", **LIMITS["holonomic"]}),
    ("CrowdNavWarehouse-v0", {}),
])
def test_the_new_options_pass_the_checkers_without_warnings(env_id, kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(env_id, **kwargs)
        gym_check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)
    assert not caught, [str(w.message) for w in caught]


@pytest.mark.parametrize(("env_id", "kwargs"), [
    ("CrowdNav-v0", {"actions": "with_stop", **LIMITS["unicycle"]}),
    ("CrowdNavWarehouse-v0", {}),
])
def test_same_seed_same_episode_with_limits(env_id, kwargs):
    def episode() -> list[bytes]:
        env = gym.make(env_id, **kwargs)
        rng = np.random.default_rng(2)
        obs, _ = env.reset(seed=8)
        out = [obs["robot"].tobytes()]
        for _ in range(60):
            obs, reward, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
            out.append(obs["robot"].tobytes() + obs["humans"].tobytes() + repr(reward).encode())
            if terminated or truncated:
                break
        return out

    assert episode() == episode()


@pytest.mark.parametrize("mapping", ["nearest", "constrained"])
def test_the_orca_robot_picks_among_the_velocities_its_step_reaches(mapping):
    """With limits the ORCA robot's candidate velocities are the env's next velocities (one rule), so its chosen
    velocity passes through the limits; on an empty floor it still drives home and, at the goal's edge, can stop."""
    env = gym.make("CrowdNav-v0", actions="with_stop", num_humans=0, **LIMITS["unicycle"])
    policy = OrcaPolicy.from_env(env, mapping=mapping)
    obs, _ = env.reset(seed=0)
    outcome = "running"
    for _ in range(env.unwrapped.max_steps):
        robot = obs["robot"].astype(np.float64)
        goal_direction = math.atan2(*(robot[Robot.GOAL] - robot[Robot.POS])[::-1])
        vx, vy = policy._velocities(robot, goal_direction)
        reached = apply_action(robot[Robot.POS], np.float64(robot[Robot.HEADING]), robot[Robot.GOAL], policy.speeds,
                               policy.directions, "unicycle", DT, robot[Robot.VEL], 1.0, 1.5).velocity
        np.testing.assert_array_equal(np.stack([vx, vy], axis=1), reached)
        action = int(policy.predict(obs)[0])
        obs, _, terminated, truncated, info = env.step(action)
        np.testing.assert_allclose(obs["robot"][Robot.VEL], reached[action], atol=1e-6)
        if terminated or truncated:
            outcome = info["outcome"]
            break
    assert outcome == "success"
