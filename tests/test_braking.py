"""The lookahead's stopping-distance check (``stopping_check``): an action is charged a collision when the robot,
braking from its new velocity at its acceleration limit, would hit a rack or a person; off by default."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.apg_value.propagation import PropagationModel, braking_path
from sb3_crowdnav.sim.actions import STOP_ACTION, apply_action
from sb3_crowdnav.sim.observation import Human
from sb3_crowdnav.sim.world import World

FULL, FOUR_FIFTHS = 64, 48  # straight on at v_pref and at 0.8 v_pref (speed index x 16 + direction 0)
T, M = 2, 1  # history length, people


def _world(**kwargs) -> World:
    return World(actions="with_stop", max_acceleration=1.0, max_turn_rate=1.5, obstacle_collision_penalty=-0.25,
                 waypoint_radius=0.5, **kwargs)


def _observation(person: tuple[float, float, float, float] | None = None, wall_x: float | None = None):
    """The robot at the origin heading east at 1 m/s (v_pref 1, radius 0.3, goal 10 m ahead), one person (x, y, vx,
    vy) of radius 0.3 or nobody, and a wall x = ``wall_x`` or none."""
    robot = np.array([[0.0, 0.0, 1.0, 0.0, 0.3, 10.0, 0.0, 1.0, 0.0]])
    humans = np.zeros((1, T, M, 5))
    mask = np.zeros((1, M))
    if person is not None:
        humans[0, :, 0, :4], humans[0, :, 0, Human.RADIUS], mask[0, 0] = person, 0.3, 1.0
    obstacles, obstacles_mask = np.zeros((1, 4)), np.zeros((1, 1))
    if wall_x is not None:
        obstacles[0], obstacles_mask[0, 0] = (wall_x, -5.0, wall_x, 5.0), 1.0
    static = {"obstacles": obstacles, "obstacles_mask": obstacles_mask, "waypoints": np.array([[10.0, 0.0]])}
    return robot, humans.reshape(1, -1), mask, static


def _collides(world: World, obs, stopping_check: bool, pedestrian_model: str = "constant_velocity") -> np.ndarray:
    prop = PropagationModel(world, T, 0.9, pedestrian_model, stopping_check)(*obs)
    return prop.terminal[0] & (prop.reward[0] < 0)


def test_the_braking_path_is_the_envs_stop_command_repeated():
    world = _world()
    velocity = np.array([[0.6, 0.8], [0.0, 0.0]])  # 1 m/s north-east, and a robot that stands
    heading = np.arctan2(velocity[:, 1], velocity[:, 0])
    path = braking_path(world, np.zeros((2, 2)), heading, velocity, np.full((2, 2), 10.0))
    assert path.shape == (5, 2, 2)  # 1 m/s at a_max·Δt = 0.25 m/s a step: four steps to a stand
    position, h, v = np.zeros(2), heading[0], velocity[0]
    for k in range(1, 5):  # the env's own step under the stop command
        position, h, v = apply_action(position, h, np.full(2, 10.0), 0.0, 0.0, "unicycle", 0.25, v, 1.0, 1.5)
        np.testing.assert_allclose(path[k, 0], position)
    np.testing.assert_allclose(np.linalg.norm(path[-1, 0]), 0.25 * (0.75 + 0.5 + 0.25))  # straight, 0.375 m
    np.testing.assert_array_equal(path[:, 1], 0.0)  # the standing robot stays put


def test_an_action_whose_braking_path_hits_a_rack_is_charged_and_one_that_stops_short_is_not():
    # full speed: 0.25 m in the step, then 0.375 m braking: the disc's front reaches 0.925 m; at 0.8 v_pref 0.725 m
    world, obs = _world(), _observation(wall_x=0.8)
    without, checked = _collides(world, obs, False), _collides(world, obs, True)
    assert not without[[FULL, FOUR_FIFTHS, STOP_ACTION]].any()  # no action touches the wall within the step
    assert checked[FULL] and not checked[FOUR_FIFTHS] and not checked[STOP_ACTION]
    prop = PropagationModel(world, T, 0.9, stopping_check=True)(*obs)
    assert prop.reward[0, FULL] == world.obstacle_collision_penalty  # the rack's penalty, terminal
    np.testing.assert_array_equal(checked, without | checked)  # the check only adds collisions
    assert not _collides(world, _observation(wall_x=0.95), True)[FULL]  # a wall beyond the stop: nothing charged


def test_where_no_action_can_brake_in_time_the_lookahead_chooses_as_without_the_check():
    # a wall 0.6 m ahead: even the stop action (0.1875 m in the step, 0.1875 m braking) brings the disc's front to
    # 0.675 m, and no reachable turn (at most 0.375 rad a step) escapes it: every action is charged, so none is
    world, obs = _world(), _observation(wall_x=0.6)
    checked = PropagationModel(world, T, 0.9, stopping_check=True)(*obs)
    unchecked = PropagationModel(world, T, 0.9)(*obs)
    assert not unchecked.terminal[0, STOP_ACTION]
    np.testing.assert_array_equal(checked.reward, unchecked.reward)
    np.testing.assert_array_equal(checked.terminal, unchecked.terminal)


@pytest.mark.parametrize("pedestrian_model", ["constant_velocity", "cautious"])
def test_an_action_whose_braking_path_meets_a_person_is_charged(pedestrian_model):
    # a person standing 1.2 m ahead: full speed stops at 0.625 m, 0.575 m from their centre (< 0.6, the radii sum)
    world, obs = _world(), _observation(person=(1.2, 0.0, 0.0, 0.0))
    assert not _collides(world, obs, False, pedestrian_model)[FULL]
    checked = _collides(world, obs, True, pedestrian_model)
    assert checked[FULL] and not checked[FOUR_FIFTHS] and not checked[STOP_ACTION]
    prop = PropagationModel(world, T, 0.9, pedestrian_model, True)(*obs)
    assert prop.reward[0, FULL] == world.reward.collision_penalty
    hidden = list(obs)
    hidden[2] = np.zeros((1, M))  # the same person unobserved: the lookahead knows only what is seen
    assert not _collides(world, hidden, True, pedestrian_model)[FULL]


def test_the_cautious_model_also_brakes_for_a_person_who_stops():
    # walking away at 1 m/s the person stays ahead of the braking robot; standing where they are, they do not
    world, obs = _world(), _observation(person=(1.2, 0.0, 1.0, 0.0))
    assert not _collides(world, obs, True, "constant_velocity")[FULL]
    assert _collides(world, obs, True, "cautious")[FULL]


def test_off_by_default_and_refused_where_it_cannot_act():
    world, obs = _world(), _observation(wall_x=0.8)
    default = PropagationModel(world, T, 0.9)
    assert default.stopping_check is False
    np.testing.assert_array_equal(default(*obs).reward, PropagationModel(world, T, 0.9, stopping_check=False)(*obs).reward)
    with pytest.raises(ValueError, match="stopping_check=True needs a world with max_acceleration"):
        PropagationModel(World(), T, 0.9, stopping_check=True)  # the paper's robot stops at once
    with pytest.raises(TypeError, match="stopping_check must be a bool"):
        PropagationModel(world, T, 0.9, stopping_check="yes")
    from sb3_crowdnav import APGValue
    with pytest.raises(ValueError, match="stopping_check=True needs a world with max_acceleration"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, policy_kwargs={"stopping_check": True})


def test_stopping_check_round_trips_through_save_and_load_and_into_the_graph_decision(tmp_path):
    from sb3_crowdnav import APGValue
    from sb3_crowdnav.deploy.graph import LookaheadDecision

    env = gym.make("CrowdNavWarehouse-v0", num_humans=2)
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0, policy_kwargs={"pedestrian_model": "cautious"})
    assert model.policy.stopping_check is False
    model.policy.set_stopping_check(True)
    assert model.policy.pedestrian_model == "cautious"  # switching one keeps the other
    model.policy.set_pedestrian_model("constant_velocity")
    assert model.policy.stopping_check is True
    model.save(tmp_path / "m.zip")
    loaded = APGValue.load(tmp_path / "m.zip")
    assert loaded.policy.stopping_check is True and loaded.policy.pedestrian_model == "constant_velocity"
    obs, _ = env.reset(seed=3)
    np.testing.assert_array_equal(loaded.policy.action_values(obs), model.policy.action_values(obs))
    assert LookaheadDecision(loaded.policy).propagation.braking_steps == 5  # 1 m/s at 1 m/s² in 0.25 s steps, + 1
    loaded.policy.set_stopping_check(False)
    loaded.save(tmp_path / "off.zip")
    assert APGValue.load(tmp_path / "off.zip").policy.stopping_check is False


def test_a_sub_step_that_moves_the_robot_by_a_rounding_residue_is_standing():
    """Braking from a whole number of a_max·Δt leaves a speed of ~1e-16 m/s at the last sub-step: whether that moves
    the position by an ulp depends on the last bit of the arithmetic, so it counts as standing (STANDING_STEP), in the
    numpy lookahead and in an exported graph alike; a slow but real motion is still charged."""
    from sb3_crowdnav.apg_value.propagation import braking_hits
    from sb3_crowdnav.sim.rewards import STANDING_STEP

    def hit(last_step: float) -> bool:
        # the robot stands at (0.5, 0) after 0.25 s, then moves by last_step; a person walks into that spot
        path = np.array([[0.0, 0.0], [0.5, 0.0], [0.5 + last_step, 0.0]])[:, None, None, :]  # (n + 1, B, A, 2)
        person, velocity = np.array([[[1.8, 0.0]]]), np.array([[[-2.0, 0.0]]])  # 0.8 m away at 0.25 s, 0.3 m at 0.5 s
        return bool(braking_hits(path, np.array([0.3]), [person], [velocity], np.array([[0.3]]), np.ones((1, 1)),
                                 0.25)[0, 0])

    assert not hit(0.0) and not hit(1e-16) and not hit(STANDING_STEP / 2)
    assert hit(1e-6) and hit(0.01)
