"""The 80-action table, the robot kinematics and the nearest-action mapping."""

import math

import numpy as np
import pytest

from sb3_crowdnav.sim import N_ACTIONS, action_table, apply_action, nearest_action, wrap_angle
from sb3_crowdnav.sim.actions import N_DIRECTIONS, move

DT = 0.25


def test_table_has_80_actions_with_five_speeds_and_sixteen_directions():
    speeds, directions = action_table(v_pref=1.5)
    assert speeds.shape == directions.shape == (N_ACTIONS,) == (80,)
    np.testing.assert_allclose(np.unique(speeds), 1.5 * np.array([0.2, 0.4, 0.6, 0.8, 1.0]))
    uniq = np.unique(directions)
    assert len(uniq) == 16
    assert np.all(uniq > -math.pi) and np.all(uniq <= math.pi)
    np.testing.assert_allclose(np.diff(uniq), 2 * math.pi / 16)
    # action a = speed index * 16 + direction index; direction index 0 is "straight on"
    np.testing.assert_allclose(speeds[4 * 16], 1.5)
    assert directions[4 * 16] == 0.0
    np.testing.assert_allclose(speeds[:16], 0.3)
    np.testing.assert_allclose(directions[4], math.pi / 2)


def test_rotation_range_restricts_directions():
    _, directions = action_table(rotation_range=math.pi / 2)
    assert directions.min() == pytest.approx(-math.pi / 4)
    assert directions.max() == pytest.approx(math.pi / 4)
    assert len(np.unique(directions)) == 16
    with pytest.raises(ValueError, match="rotation_range"):
        action_table(rotation_range=0.0)
    with pytest.raises(ValueError, match="rotation_range"):
        action_table(rotation_range=7.0)
    with pytest.raises(ValueError, match="v_pref"):
        action_table(v_pref=0.0)


@pytest.mark.parametrize("heading", [0.0, 0.3, -2.5, math.pi])
def test_full_speed_straight_on_moves_v_pref_dt_along_heading(heading):
    speeds, directions = action_table(v_pref=1.2)
    a = 4 * N_DIRECTIONS  # (v_pref, Δθ = 0)
    pos = np.array([0.5, -1.0])
    new_pos, new_heading, vel = apply_action(pos, np.float64(heading), np.array([3.0, 3.0]), speeds[a], directions[a],
                                             "unicycle", DT)
    np.testing.assert_allclose(new_pos, pos + 1.2 * DT * np.array([math.cos(heading), math.sin(heading)]), atol=1e-12)
    np.testing.assert_allclose(vel, 1.2 * np.array([math.cos(heading), math.sin(heading)]), atol=1e-12)
    assert float(wrap_angle(new_heading - heading)) == pytest.approx(0.0, abs=1e-12)


def test_holonomic_straight_on_moves_towards_the_goal_whatever_the_heading():
    speeds, directions = action_table()
    pos, goal = np.array([1.0, 1.0]), np.array([4.0, 5.0])  # 3-4-5 triangle
    new_pos, new_heading, _ = apply_action(pos, np.float64(-2.0), goal, speeds[64], directions[64], "holonomic", DT)
    np.testing.assert_allclose(new_pos, pos + DT * np.array([0.6, 0.8]), atol=1e-12)
    assert float(new_heading) == pytest.approx(math.atan2(4, 3))


def test_unicycle_turn_is_relative_and_wrapped():
    speeds, directions = action_table()
    # direction index 8 is a reversal (π), speed index 0 (0.2 v_pref)
    new_pos, new_heading, _ = apply_action(np.zeros(2), np.float64(math.pi / 2), np.ones(2), speeds[8], directions[8],
                                           "unicycle", DT)
    assert float(new_heading) == pytest.approx(-math.pi / 2)
    np.testing.assert_allclose(new_pos, [0.0, -0.2 * DT], atol=1e-12)


@pytest.mark.parametrize("kinematics", ["unicycle", "holonomic"])
def test_one_robot_equals_its_row_of_a_batch(kinematics):
    """apply_action of one robot and of the 80 actions at once agree for every action."""
    speeds, directions = action_table(v_pref=0.9, rotation_range=math.pi)
    rng = np.random.default_rng(0)
    pos, goal, heading = rng.normal(size=2), rng.normal(size=2), rng.uniform(-math.pi, math.pi)
    b_pos, b_head, b_vel = apply_action(pos[None], np.full(80, heading), goal[None], speeds, directions, kinematics, DT)
    for a in range(N_ACTIONS):
        s_pos, s_head, s_vel = apply_action(pos, np.float64(heading), goal, speeds[a], directions[a], kinematics, DT)
        np.testing.assert_allclose(s_pos, b_pos[a], rtol=0, atol=1e-12)
        np.testing.assert_allclose(s_vel, b_vel[a], rtol=0, atol=1e-12)
        assert float(s_head) == pytest.approx(float(b_head[a]), abs=1e-12)


@pytest.mark.parametrize("kinematics", ["unicycle", "holonomic"])
def test_the_compiled_kinematics_is_the_numpy_form(kinematics):
    """move (the env's one robot) and apply_action (batches) against a NumPy form of the module docstring's rules."""
    rng = np.random.default_rng(4)
    pos, goal = rng.normal(size=(500, 2)) * 3, rng.normal(size=(500, 2)) * 3
    heading, speed, direction = rng.uniform(-4, 4, 500), rng.uniform(0, 1, 500), rng.uniform(-math.pi, math.pi, 500)
    base = np.arctan2(*(goal - pos).T[::-1]) if kinematics == "holonomic" else heading
    expected_heading = np.mod(base + direction + np.pi, 2 * np.pi) - np.pi
    velocity = speed[:, None] * np.stack([np.cos(expected_heading), np.sin(expected_heading)], axis=1)
    new_pos, new_heading, vel = apply_action(pos, heading, goal, speed, direction, kinematics, DT)
    np.testing.assert_allclose(new_heading, expected_heading, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(vel, velocity, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(new_pos, pos + velocity * DT, rtol=1e-12, atol=1e-15)
    assert ((-math.pi < new_heading) & (new_heading <= math.pi)).all()
    one = [move(*p, h, 0.0, 0.0, *g, s, d, kinematics == "holonomic", DT, math.inf, math.inf) for p, h, g, s, d in
           zip(pos.tolist(), heading.tolist(), goal.tolist(), speed.tolist(), direction.tolist(), strict=True)]
    np.testing.assert_array_equal(np.array(one), np.concatenate([new_pos, new_heading[:, None], vel], axis=1))


def test_apply_action_rejects_unknown_kinematics():
    with pytest.raises(ValueError, match="kinematics"):
        apply_action(np.zeros(2), np.float64(0.0), np.ones(2), 1.0, 0.0, "bicycle", DT)
    with pytest.raises(ValueError, match="kinematics"):
        apply_action(np.zeros((3, 2)), np.zeros(3), np.ones((3, 2)), np.ones(3), np.zeros(3), "bicycle", DT)


def test_wrap_angle():
    np.testing.assert_allclose(wrap_angle(np.array([0.0, math.pi, -math.pi, 3 * math.pi, 2 * math.pi + 0.1])),
                               [0.0, math.pi, math.pi, math.pi, 0.1], atol=1e-12)


def test_nearest_action_hand_made_velocities():
    speeds, directions = action_table()
    # unicycle, heading 0: (1, 0) is full speed straight on; (0, 0.6) is 0.6 m/s turned by +π/2
    assert nearest_action(np.array([1.0, 0.0]), 0.0, 1.0, speeds, directions, "unicycle") == 64
    assert nearest_action(np.array([0.0, 0.6]), 0.0, 1.0, speeds, directions, "unicycle") == 2 * 16 + 4
    # the heading rotates the frame: heading π/2 makes (0, 1) straight on
    assert nearest_action(np.array([0.0, 1.0]), math.pi / 2, 0.0, speeds, directions, "unicycle") == 64
    # holonomic: directions are relative to the goal direction (here π/2), not to the heading
    assert nearest_action(np.array([0.0, 1.0]), 0.0, math.pi / 2, speeds, directions, "holonomic") == 64
    assert nearest_action(np.array([-0.4, 0.0]), 0.0, math.pi / 2, speeds, directions, "holonomic") == 16 + 4
    # a wish to stop becomes the slowest speed
    assert nearest_action(np.array([0.0, 0.0]), 0.0, 0.0, speeds, directions, "unicycle") < 16
    allowed = np.zeros(80, dtype=bool)
    allowed[70] = True
    assert nearest_action(np.array([1.0, 0.0]), 0.0, 0.0, speeds, directions, "unicycle", allowed) == 70
