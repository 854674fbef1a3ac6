"""examples/foresight_bound.py: the replayed future is the real one, the probe refuses a crowd where it is not, and
its charges reach the lookahead only inside their block."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from example_scripts import load_example

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.apg_value import propagation
from sb3_crowdnav.sim.observation import Human, ObservationSchema

probe = load_example("foresight_bound")


@pytest.mark.parametrize("robot_visible", [0.8, 1.0])
def test_the_replayed_next_step_is_the_real_one(robot_visible):
    """Whatever the robot does in a step, the pickers' next rows are those the replay foresaw (ORCA pickers read the
    robot's state at the start of the step), every picker seeing the robot included."""
    env, twin = (gym.make("CrowdNavWarehouse-v0", robot_visible=robot_visible) for _ in range(2))
    env.reset(seed=5)
    future = probe.Foresight(twin, 5)
    rng = np.random.default_rng(0)
    for _ in range(25):
        expected = future.ahead(1, 0)[0]
        action = int(rng.integers(env.action_space.n))
        future.actions.append(action)
        _, _, terminated, truncated, _ = env.step(action)
        sim = env.unwrapped.sim
        np.testing.assert_array_equal(sim.history[-1, : sim.num_humans], expected)
        if terminated or truncated:
            break
    assert len(future.actions) > 3  # (the episode did not end at once)


def test_a_crowd_that_feels_the_robots_move_is_refused():
    """Social-force pickers integrate the robot's move through the step: the probe stops with an error rather than
    tell the lookahead a future that is not the real one."""
    env, twin = (gym.make("CrowdNavWarehouse-v0", crowd="social_force") for _ in range(2))

    class Straight:
        def predict(self, obs, deterministic=True):
            return np.array([64]), None

    with pytest.raises(RuntimeError, match="depends on the robot's action"):
        probe.play(Straight(), env, twin, [2_000_000, 2_000_001, 2_000_002], "next", 6, {"paths": None})


def test_next_velocities_replace_the_observed_newest_only():
    env = gym.make("CrowdNavWarehouse-v0")
    obs, _ = env.reset(seed=3)
    mask = obs["humans_mask"]
    n = env.unwrapped.sim.num_humans
    rows = np.random.default_rng(1).normal(size=(n, 5))
    told = probe.with_next_velocities(obs, rows)
    schema = ObservationSchema(env.unwrapped.sim.scene.history_length, mask.size)
    before, after = (schema.humans_view(o["humans"][None])[0] for o in (obs, told))
    seen = np.flatnonzero(mask[:n] > 0.5)
    assert 0 < seen.size < n  # (seed 3: one picker observed, the others hidden or out of range)
    np.testing.assert_allclose(after[-1, seen][:, Human.VEL], rows[seen][:, Human.VEL], rtol=1e-6)
    changed = np.zeros(after.shape, dtype=bool)
    changed[-1, seen, Human.VEL] = True
    np.testing.assert_array_equal(after[~changed], before[~changed])
    assert told["humans"] is not obs["humans"]  # the observation itself is untouched


def test_braking_charges_only_inside_the_block_and_once():
    """A person standing on the robot's braking path is charged from the real path inside the block, for the first
    call only; standing contact only with charge_standing; the check is the package's again after the block."""
    check = propagation.braking_hits
    path = np.zeros((3, 1, 2, 2))  # two actions: the first brakes along x from 0 to 0.2 m, the second stands at 5 m
    path[:, 0, 0, 0] = [0.0, 0.15, 0.2]
    path[:, 0, 1] = 5.0
    args = (np.array([0.3]), [np.full((1, 1, 2), 50.0)], [np.zeros((1, 1, 2))], np.array([[0.3]]),
            np.array([[True]]), 0.25)
    assert not check(path, *args).any()  # the observed person is far away
    near_first = np.zeros((4, 1, 2))
    near_first[:, 0] = [0.4, 0.0]  # within 0.6 m of the first action's path
    at_second = np.full((4, 1, 2), 5.2)  # beside the second action's robot, which stands
    at_second[:, 0, 1] = 5.0
    for paths, standing, charged in ((near_first, False, [True, False]), (at_second, False, [False, False]),
                                     (at_second, True, [False, True])):
        pending = {"paths": paths}
        with probe.braking_foresight(pending, standing):
            assert propagation.braking_hits is not check
            np.testing.assert_array_equal(propagation.braking_hits(path, *args)[0], charged)
            assert pending["paths"] is None
            assert not propagation.braking_hits(path, *args).any()  # used once
        assert propagation.braking_hits is check


@pytest.mark.parametrize("argv", [["--steps", "6"], ["--charge-standing", "--foresight", "next"], ["--episodes", "0"],
                                  ["--foresight", "far"], ["--foresight", "plans", "--charge-standing"]])
def test_bad_input_exits_2_with_one_line(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        probe.main(argv)
    assert exc.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_a_policy_without_a_lookahead_is_refused(capsys):
    with pytest.raises(SystemExit) as exc:
        probe.main(["--policy", "orca", "--episodes", "1"])
    assert exc.value.code == 2
    assert "no lookahead" in capsys.readouterr().err


def _open_floor_obs(env):
    """A warehouse observation with no rack or wall segment observed (the planner's rack test has nothing to meet)."""
    obs, _ = env.reset(seed=3)
    return {**obs, "obstacles_mask": np.zeros_like(obs["obstacles_mask"])}


def test_a_planner_with_people_all_around_is_doomed_and_with_nobody_near_is_not():
    env = gym.make("CrowdNavWarehouse-v0")
    obs = _open_floor_obs(env)
    world, n, steps = env.unwrapped.world, env.unwrapped.sim.num_humans, 4
    centre = obs["robot"][:2].astype(np.float64)
    mask = np.zeros_like(obs["humans_mask"])
    mask[:n] = 1.0
    obs = {**obs, "humans_mask": mask}
    ring = centre + 0.5 * np.stack([np.cos(np.arange(n) * 2 * np.pi / n), np.sin(np.arange(n) * 2 * np.pi / n)], 1)
    radii = np.full(n, 0.3)
    standing = np.broadcast_to(ring, (steps + 1, n, 2))
    assert probe.doomed_actions(world, obs, standing, radii, steps).all()
    far = np.broadcast_to(centre + 50.0, (steps + 1, n, 2))
    assert not probe.doomed_actions(world, obs, far, radii, steps).any()
    hidden = {**obs, "humans_mask": np.zeros_like(mask)}  # people the robot does not observe are not foreseen
    assert not probe.doomed_actions(world, hidden, standing, radii, steps).any()


def test_the_planners_charge_replaces_the_check_at_the_first_step_only():
    check = propagation.braking_hits
    path = np.zeros((3, 1, 2, 2))
    args = (np.array([0.3]), [np.full((1, 1, 2), 50.0)], [np.zeros((1, 1, 2))], np.array([[0.3]]),
            np.array([[True]]), 0.25)
    pending = {"paths": None, "doomed": np.array([True, False])}
    with probe.braking_foresight(pending, False):
        np.testing.assert_array_equal(propagation.braking_hits(path, *args)[0], [True, False])
        np.testing.assert_array_equal(propagation.braking_hits(path, *args), check(path, *args))  # used once
    assert propagation.braking_hits is check


def test_plans_play_an_episode():
    env, twin = gym.make("CrowdNavWarehouse-v0"), gym.make("CrowdNavWarehouse-v0")
    from sb3_crowdnav.evaluation.runner import make_policy

    policy = make_policy("pretrained:apg_warehouse", env.unwrapped)
    pending = {"paths": None}
    with probe.braking_foresight(pending, False):
        outcomes = probe.play(policy, env, twin, [2_000_001], "plans", 4, pending)
    assert sum(outcomes.values()) == 1
