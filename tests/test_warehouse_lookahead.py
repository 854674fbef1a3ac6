"""The lookahead knows the walls: propagation and env agree on obstacle collisions, rewards and waypoints; and on the
progress shaping, on the route's waypoints and on the open floor's goal."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.apg_value.propagation import PropagationModel
from sb3_crowdnav.sim.observation import OBSTACLE_KEYS, WAYPOINT_KEY, Robot
from sb3_crowdnav.sim.warehouse.config import PAPER_ROBOT

WAREHOUSE, OPEN_FLOOR = "CrowdNavWarehouse-v0", "CrowdNav-v0"


def _model(env) -> PropagationModel:
    return PropagationModel(env.unwrapped.world, env.unwrapped.scene.history_length, 0.9)


def _towards_goal(obs: dict[str, np.ndarray]) -> int:
    """The full-speed unicycle action nearest the direction of the goal."""
    robot = obs["robot"].astype(np.float64)
    angle = math.atan2(robot[Robot.GOAL][1] - robot[1], robot[Robot.GOAL][0] - robot[0]) - robot[Robot.HEADING]
    return 64 + round(angle / (2 * math.pi / 16)) % 16


@pytest.mark.parametrize("env_id, seed, progress_reward", [(WAREHOUSE, s, 0.0) for s in range(4)] +
                         [(WAREHOUSE, s, 0.1) for s in range(4, 6)] + [(OPEN_FLOOR, s, 0.1) for s in range(6, 8)])
def test_env_and_propagation_agree_on_random_transitions(env_id, seed, progress_reward):
    # the robot and the static world alone (the open floor: the robot alone); with the progress shaping in two seeds
    env = gym.make(env_id, num_humans=0, progress_reward=progress_reward)
    model = _model(env)
    warehouse = env_id == WAREHOUSE
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    checked = ends = 0
    for _ in range(400):
        # on the open floor every other step heads for the goal: the episodes end in successes, not timeouts alone
        action = int(rng.integers(80)) if warehouse or rng.random() < 0.5 else _towards_goal(obs)
        batch = {k: v[None] for k, v in obs.items()}
        prop = model(batch["robot"], batch["humans"], batch["humans_mask"],
                     {k: batch[k] for k in (*OBSTACLE_KEYS, WAYPOINT_KEY) if k in batch})
        replans = env.unwrapped.sim.replans if warehouse else 0
        obs, reward, terminated, truncated, info = env.step(action)
        # the observation is float32: the shaping sees positions rounded to ~1e-6 m
        assert prop.reward[0, action] == pytest.approx(reward, abs=1e-6 if progress_reward else 1e-9)
        assert bool(prop.terminal[0, action]) == terminated
        ends += info.get("collision_with") == "obstacle" if warehouse else info["is_success"]
        if warehouse and not (terminated or truncated) and env.unwrapped.sim.replans == replans:
            # the current waypoint is the env's; a route point beyond the K observed ones it cannot know
            predicted, actual = prop.static["waypoints"][0, action].reshape(-1, 2), obs["waypoints"].reshape(-1, 2)
            passed = not np.allclose(predicted, batch["waypoints"][0].reshape(-1, 2))
            n = 1 if passed else len(predicted)  # all of them while no waypoint is passed
            np.testing.assert_allclose(predicted[:n], actual[:n], atol=1e-5)
        checked += 1
        if terminated or truncated:
            obs, _ = env.reset()
    assert checked == 400 and ends > 0  # obstacle collisions (successes on the open floor) happened and were foreseen


def test_open_floor_models_have_no_static_world():
    """CrowdNav-v0's world, and so the shipped open-floor models', has no static-world rules."""
    from sb3_crowdnav import pretrained

    world = gym.make("CrowdNav-v0").unwrapped.world
    assert not world.has_static_world and world.obstacle_collision_penalty is None and world.progress_reward == 0
    assert pretrained("apg_rl").policy.world == world


def test_apg_value_acts_in_the_warehouse_with_the_walls_in_its_lookahead():
    from sb3_crowdnav import APGValue

    model = APGValue("ApgPolicy", "CrowdNavWarehouse-v0", imitation_episodes=0, seed=0)
    world = model.policy.world
    assert (world.obstacle_collision_penalty, world.waypoint_radius, world.progress_reward) == (-0.25, 0.6, 0.0)
    env = gym.make("CrowdNavWarehouse-v0", num_humans=0)
    obs, _ = env.reset(seed=3)
    values = model.policy.action_values(obs)[0]
    batch = {k: v[None] for k, v in obs.items()}
    prop = model.policy.propagation(batch["robot"], batch["humans"], batch["humans_mask"],
                                    {k: batch[k] for k in (*OBSTACLE_KEYS, WAYPOINT_KEY)})
    hit = prop.terminal[0] & (prop.reward[0] == -0.25)
    np.testing.assert_allclose(values[hit], -0.25)  # a collision's value is its penalty, nothing after it


@pytest.mark.parametrize("env_id", [WAREHOUSE, OPEN_FLOOR])
def test_progress_shaping_is_the_metres_gained_on_the_current_waypoint_or_the_goal(env_id):
    """``progress_reward`` k: each step earns k x (distance to the current waypoint (the warehouse) or to the goal
    (the open floor) before - after), zero on terminal steps; with k = 0 (the default, the paper's reward) the term
    is 0 (the warehouse's ``info``) or absent (the open floor's ``info``, the paper env's)."""
    k = 0.1
    # the paper's robot: unlimited random actions go both ways along the route from the first steps
    robot = PAPER_ROBOT if env_id == WAREHOUSE else {}
    shaped = gym.make(env_id, num_humans=0, progress_reward=k, **robot)
    plain = gym.make(env_id, num_humans=0, **robot)
    rng = np.random.default_rng(3)
    for seed in range(3):
        obs, _ = shaped.reset(seed=seed)
        plain.reset(seed=seed)
        gains = []
        for _ in range(300):
            action = int(rng.integers(80))
            target = obs["waypoints"][:2] if env_id == WAREHOUSE else obs["robot"][Robot.GOAL]
            waypoint, pos0 = target.astype(float), obs["robot"][:2].astype(float)
            obs, reward, terminated, truncated, info = shaped.step(action)
            _, plain_reward, *_, plain_info = plain.step(action)
            assert plain_info["reward_progress"] == 0.0 if env_id == WAREHOUSE else "reward_progress" not in plain_info
            if terminated:
                assert info["reward_progress"] == 0.0 and reward == plain_reward
                break
            gained = np.linalg.norm(pos0 - waypoint) - np.linalg.norm(obs["robot"][:2] - waypoint)
            assert info["reward_progress"] == pytest.approx(k * gained, abs=1e-5)
            assert reward == pytest.approx(plain_reward + info["reward_progress"], abs=1e-12)
            gains.append(info["reward_progress"])
            if truncated:
                break
        assert any(g > 0 for g in gains) and any(g < 0 for g in gains)  # random actions go both ways


@pytest.mark.parametrize("env_id", [WAREHOUSE, OPEN_FLOOR, "CrowdNavWorlds-v0"])
def test_progress_reward_is_checked_at_construction(env_id):
    bad_values = ((-0.1, ValueError), (11.0, ValueError), (float("nan"), ValueError), (math.inf, ValueError),
                  ("0.1", TypeError), (True, TypeError), (None, TypeError))
    for bad, error in bad_values:
        with pytest.raises(error, match="progress_reward"):
            gym.make(env_id, progress_reward=bad)


@pytest.mark.parametrize("env_id, k", [(WAREHOUSE, 0.1), (WAREHOUSE, 1.0), (OPEN_FLOOR, 0.1), (OPEN_FLOOR, 1.0)])
def test_value_ceiling_bounds_every_return_and_caps_the_lookahead(env_id, k):
    """No discounted return of the shaped warehouse or open floor exceeds ``value_ceiling`` (measured on random
    episodes, each state's return to the episode's end); the lookahead caps V(s') there, so an overestimating V
    cannot outbid a success action."""
    from sb3_crowdnav.apg_value import APGValue

    env = gym.make(env_id, num_humans=2, progress_reward=k)
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0)
    policy = model.policy
    gamma, dt = policy.gamma, policy.world.time_step
    ceiling = float(policy.value_ceiling(np.array([1.0]))[0])
    assert ceiling == pytest.approx(max(1.0, k * dt / (1 - gamma**dt)))
    rng = np.random.default_rng(0)
    best = -np.inf
    for seed in range(6):
        obs, _ = env.reset(seed=seed)
        rewards, done = [], False
        while not done:  # a forward-driving random robot: gains on its waypoints or goal, sometimes reaches the goal
            action = int(rng.choice([64, 65, 79, 48])) if rng.random() < 0.8 else int(rng.integers(80))
            obs, reward, terminated, truncated, _ = env.step(action)
            rewards.append(reward)
            done = terminated or truncated
        ret = 0.0
        for r in reversed(rewards):
            ret = r + gamma**dt * ret
            best = max(best, ret)
    assert best <= ceiling + 1e-9
    # an overestimating V (its output bias raised by 20): the lookahead still values no action above R + γ'·ceiling
    with th.no_grad():
        list(policy.value_net.parameters())[-1].add_(20.0)
    obs, _ = env.reset(seed=0)
    q, prop = policy.lookahead({key: value[None] for key, value in obs.items()})
    discount = gamma ** (dt * obs["robot"][Robot.V_PREF])
    assert np.all(q <= prop.reward + discount * ceiling + 1e-6)
    assert np.any(q > prop.reward + discount * (ceiling - 1e-3))  # capped, not zeroed


def test_open_floor_policies_have_no_value_ceiling_but_with_progress_shaping():
    from sb3_crowdnav import APGValue, pretrained

    assert pretrained("apg_rl").policy.value_ceiling(np.array([1.0])) is None
    shaped = APGValue("ApgPolicy", gym.make(OPEN_FLOOR, progress_reward=0.1), imitation_episodes=0, seed=0)
    assert shaped.policy.value_ceiling(np.array([1.0]))[0] == 1.0  # max(S, k·Δt / (1 - γ^Δt)) = max(1, 0.96)


def test_cautious_pedestrian_model_charges_the_worse_of_moving_on_and_standing_still(tmp_path):
    """``pedestrian_model="cautious"``: R(s, a) is the lower of the constant-velocity reward and the reward with every
    picker standing still (the same observation with the latest velocities zeroed), on real warehouse states."""
    from sb3_crowdnav import APGValue
    from sb3_crowdnav.sim.observation import Human, ObservationSchema

    # the world this test was written in (the paper's robot among blind pickers): under the warehouse's new defaults no
    # action met a stopping picker in these 300 steps, so the comparison would check nothing
    env = gym.make("CrowdNavWarehouse-v0", num_humans=8, actions="paper", max_acceleration=None, max_turn_rate=None,
                   robot_visible=False)
    cv, cautious = _model(env), _model(env)
    cautious.pedestrian_model = "cautious"
    schema = ObservationSchema.from_space(env.observation_space)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=11)
    stricter = 0
    for _ in range(300):
        batch = {k: v[None] for k, v in obs.items()}
        static = {k: batch[k] for k in (*OBSTACLE_KEYS, WAYPOINT_KEY)}
        still = schema.humans_view(batch["humans"].copy())
        still[:, -1, :, Human.VEL] = 0.0
        still = still.reshape(1, -1)
        a = cv(batch["robot"], batch["humans"], batch["humans_mask"], static)
        b = cv(batch["robot"], still, batch["humans_mask"], static)
        c = cautious(batch["robot"], batch["humans"], batch["humans_mask"], static)
        np.testing.assert_array_equal(c.reward, np.minimum(a.reward, b.reward))
        worse = b.reward < a.reward
        np.testing.assert_array_equal(c.terminal, np.where(worse, b.terminal, a.terminal))
        np.testing.assert_array_equal(c.robot, a.robot)  # V sees the constant-velocity state either way
        np.testing.assert_array_equal(c.humans, a.humans)
        stricter += int((c.terminal & ~a.terminal).sum())
        obs, _, terminated, truncated, _ = env.step(int(rng.integers(80)))
        if terminated or truncated:
            obs, _ = env.reset()
    assert stricter > 0  # some actions collide only with a picker who stops

    model = APGValue("ApgPolicy", "CrowdNavWarehouse-v0", imitation_episodes=0, seed=0)
    assert model.policy.pedestrian_model == "constant_velocity"
    model.policy.set_pedestrian_model("cautious")
    model.save(tmp_path / "m.zip")
    assert APGValue.load(tmp_path / "m.zip").policy.pedestrian_model == "cautious"
    with pytest.raises(ValueError, match="pedestrian_model must be one of"):
        model.policy.set_pedestrian_model("psychic")
    with pytest.raises(ValueError, match="pedestrian_model must be one of"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, policy_kwargs={"pedestrian_model": "still"})


def test_the_lookahead_evaluates_each_distinct_state_once_under_the_robots_limits():
    from test_pretrained_actions import observations

    from sb3_crowdnav.apg_value import APGValue

    policy = APGValue("ApgPolicy", WAREHOUSE, imitation_episodes=0, seed=0).policy
    n_actions = policy.world.n_actions
    batch = observations(WAREHOUSE, 24, seed=3)
    q, prop = policy.lookahead(batch)
    tensors, inverse = policy.lookahead_inputs(prop)
    every, none = policy.lookahead_inputs(prop, distinct=False)
    assert none is None and len(every["robot"]) == 24 * n_actions
    # 1 m/s², 1.5 rad/s: the 81 commands reach far fewer states, and every row of the full set is among them
    assert len(tensors["robot"]) < 24 * n_actions / 3
    for key, rows in every.items():
        th.testing.assert_close(tensors[key][th.as_tensor(inverse)], rows, rtol=0, atol=0)
    # no row is shared between two observations, and the values are those of every row
    owner = np.repeat(np.arange(24), n_actions)
    assert all(len(set(owner[inverse == r])) == 1 for r in range(len(tensors["robot"])))
    with th.inference_mode():
        v_every = policy.value_net(every).reshape(24, n_actions).numpy()
    q_every = prop.reward + prop.discount[:, None] * np.where(prop.terminal, 0.0, v_every)
    np.testing.assert_allclose(q, q_every, rtol=0, atol=1e-5)
    # one observation at a time, the same values
    np.testing.assert_allclose(policy.lookahead({k: v[5:6] for k, v in batch.items()})[0], q[5:6], rtol=0, atol=1e-5)


def test_the_open_floor_lookahead_evaluates_every_action():
    # the paper's robot has no limits: every command reaches its own state, and no row is merged
    from test_pretrained_actions import observations

    from sb3_crowdnav import pretrained

    policy = pretrained("apg_rl").policy
    batch = observations(OPEN_FLOOR, 4, seed=1)
    prop = policy.propagation(batch["robot"], batch["humans"], batch["humans_mask"])
    tensors, inverse = policy.lookahead_inputs(prop)
    assert inverse is None and len(tensors["robot"]) == 4 * 80
    distinct, _ = policy.lookahead_inputs(prop, distinct=True)
    assert len(distinct["robot"]) == 4 * 80
    with pytest.raises(TypeError, match="distinct"):
        policy.lookahead_inputs(prop, distinct=1)


def _near_the_goal(env: gym.Env, policy) -> dict[str, np.ndarray]:
    """An observation of ``env`` (empty floor) from which some action reaches the goal: the ORCA robot drives there."""
    from sb3_crowdnav.sim.orca import OrcaPolicy

    robot = OrcaPolicy.from_env(env, mapping="constrained")
    obs, _ = env.reset(seed=3)
    for _ in range(200):
        batch = {key: value[None] for key, value in obs.items()}
        _, prop = policy.lookahead(batch)
        if (prop.terminal & (prop.reward > 0.5)).any():
            return batch
        obs, *_ = env.step(int(robot.predict(obs, deterministic=True)[0]))
    raise AssertionError("the ORCA robot never came within a step of its goal")


def test_cap_values_caps_an_overestimating_v_on_the_open_floor_so_the_goal_wins(tmp_path):
    """On the paper's open floor V is not capped by default (the shipped models act as trained): a V that
    overestimates next to the goal outbids the success action, and the robot circles there. ``cap_values=True`` caps
    it at the success reward, at one step and in a two-step beam; the setting is saved with the model."""
    from sb3_crowdnav.apg_value import APGValue

    env = gym.make(OPEN_FLOOR, num_humans=0)
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0)
    policy = model.policy
    assert policy.cap_values is None and not policy.caps_values and policy.value_ceiling(np.ones(1)) is None
    with th.no_grad():
        list(policy.value_net.parameters())[-1].add_(20.0)  # V about 20 everywhere: far above any return
    obs = _near_the_goal(env, policy)
    for depth, width in ((1, None), (2, 8)):
        policy.set_planning(depth, width)
        policy.set_cap_values(None)
        q, prop = policy.lookahead(obs)
        goal = prop.terminal[0] & (prop.reward[0] > 0.5)
        assert not goal[int(q[0].argmax())], depth  # uncapped: an action that does not arrive looks better
        policy.set_cap_values(True)
        q, prop = policy.lookahead(obs)
        assert goal[int(q[0].argmax())], depth  # capped: the goal
        discount = policy.gamma ** (policy.world.time_step * obs["robot"][0, Robot.V_PREF])
        assert np.all(q[0] <= prop.reward[0] + discount * 1.0 + 1e-6)
    model.save(tmp_path / "capped.zip")
    assert APGValue.load(tmp_path / "capped.zip").policy.cap_values is True
    policy.set_cap_values(None)
    model.save(tmp_path / "rule.zip")
    assert APGValue.load(tmp_path / "rule.zip").policy.cap_values is None
    # False turns the warehouse's cap off; anything but None or a bool is refused
    warehouse = APGValue("ApgPolicy", gym.make(WAREHOUSE, num_humans=1), imitation_episodes=0, seed=0).policy
    assert warehouse.caps_values and warehouse.value_ceiling(np.ones(1)) is not None
    warehouse.set_cap_values(False)
    assert warehouse.value_ceiling(np.ones(1)) is None
    for bad in ("yes", 1):
        with pytest.raises(TypeError, match="cap_values"):
            policy.set_cap_values(bad)


def test_a_finished_run_gets_the_schedules_cap(tmp_path):
    """``ScheduleConfig.cap_values`` reaches the finished run's files through ``finish_depth`` (with the search), and
    is checked at construction."""
    import json

    from sb3_crowdnav.apg_value import APGValue
    from sb3_crowdnav.training.callbacks import finish_depth
    from sb3_crowdnav.training.schedule import ScheduleConfig

    APGValue("ApgPolicy", gym.make(OPEN_FLOOR), imitation_episodes=0, seed=0).save(tmp_path / "best.zip")
    (tmp_path / "best.json").write_text(json.dumps({"episodes": 1}))
    finish_depth(tmp_path, 2, lambda _: None, 8, cap_values=True)
    policy = APGValue.load(tmp_path / "best.zip").policy
    assert (policy.planning_depth, policy.planning_width, policy.cap_values) == (2, 8, True)
    assert json.loads((tmp_path / "best.json").read_text())["cap_values"] is True
    finish_depth(tmp_path, 2, lambda _: None, 8)  # None keeps the file's cap
    assert APGValue.load(tmp_path / "best.zip").policy.cap_values is True
    assert ScheduleConfig(variant="apg_robust", cap_values=True).cap_values is True
    with pytest.raises(TypeError, match="cap_values"):
        ScheduleConfig(variant="apg_robust", cap_values="on")
