"""Reward terms (paper Eq. 9-14, SPEC §2.3) against hand-computed values, and the geometry helpers."""

import math

import numpy as np
import pytest

from sb3_crowdnav.sim import RewardConfig, closest_approach, compute_reward, walking_direction

DT = 0.25
R = 0.3  # robot and pedestrian radius
FAR_GOAL = np.array([0.0, 50.0])
COMFORT, CROWDNAV, ANGULAR = RewardConfig("comfort"), RewardConfig("crowdnav"), RewardConfig("comfort_angular")


def reward(cfg, robot0, robot1, humans0, humans1=None, dirs=None, heading0=0.0, heading1=0.0, goal=FAR_GOAL,
           mask=None):
    """One transition; pedestrians static unless ``humans1`` is given, walking along +x unless ``dirs`` is given."""
    humans0 = np.atleast_2d(np.asarray(humans0, dtype=float))
    humans1 = humans0 if humans1 is None else np.atleast_2d(np.asarray(humans1, dtype=float))
    n = len(humans0)
    dirs = np.tile([1.0, 0.0], (n, 1)) if dirs is None else np.atleast_2d(np.asarray(dirs, dtype=float))
    mask = np.ones(n, dtype=bool) if mask is None else np.asarray(mask)
    return compute_reward(cfg, DT, np.asarray(robot0, float), np.asarray(robot1, float), np.float64(heading0),
                          np.float64(heading1), np.asarray(goal, float), np.float64(R), humans0, humans1, dirs,
                          np.full(n, R), mask)


def social(w):
    """Eq. 11 with the corrected w: -r_p (exp(-(w - d_side)) - 1)."""
    return -0.02 * (math.exp(-(w - 0.7)) - 1.0)


# ---------------------------------------------------------------------- comfort ellipse, Eq. 9-11
def test_comfort_in_front_measured_between_surfaces():
    # pedestrian at the origin walking +x, robot centre 1.5 m ahead: surface offset x0 = 1.5 - 0.6 = 0.9, y0 = 0
    # w = sqrt(x0² d_side²/d_person²) = 0.9 * 0.7 / 1.2 = 0.525 <= 0.7: inside. (Between centres, w = 0.875: outside.)
    t = reward(COMFORT, [1.5, 0.0], [1.5, 0.0], [0.0, 0.0])
    assert float(t.social_term) == pytest.approx(social(0.9 * 0.7 / 1.2), rel=1e-12)
    assert float(t.social_term) == pytest.approx(-0.02 * (math.exp(0.175) - 1.0))
    assert float(t.reward) == pytest.approx(float(t.social_term))
    assert bool(t.in_comfort_zone)
    assert float(t.discomfort_term) == 0.0  # "comfort" has no discomfort term


def test_comfort_off_axis_and_rotated_frame():
    # pedestrian walking +y; robot centre at (-0.8, 1.0) relative to it
    centre = np.array([-0.8, 1.0])
    surf = centre * (np.linalg.norm(centre) - 0.6) / np.linalg.norm(centre)
    x0, y0 = surf[1], -surf[0]  # frame: x along +y, y along -x (rotated by +90°)
    w = math.sqrt(x0**2 * (0.7 / 1.2) ** 2 + y0**2)
    assert w < 0.7 and x0 > 0
    t = reward(COMFORT, centre, centre, [0.0, 0.0], dirs=[0.0, 1.0])
    assert float(t.social_term) == pytest.approx(social(w), rel=1e-12)


def test_comfort_behind_and_outside_give_zero():
    behind = reward(COMFORT, [-1.5, 0.0], [-1.5, 0.0], [0.0, 0.0])  # x0 = -0.9 < 0
    assert float(behind.social_term) == 0.0 and not bool(behind.in_comfort_zone)
    outside = reward(COMFORT, [2.0, 0.0], [2.0, 0.0], [0.0, 0.0])  # x0 = 1.4, w = 0.817 > 0.7
    assert float(outside.social_term) == 0.0 and not bool(outside.in_comfort_zone)
    side = reward(COMFORT, [0.2, 1.4], [0.2, 1.4], [0.0, 0.0])  # mostly to the side, |y0| > 0.7
    assert float(side.social_term) == 0.0


def test_comfort_is_summed_over_pedestrians():
    # one pedestrian behind the robot walking +x, one ahead at (3, 0) walking -x: both see it 0.9 m ahead
    t = reward(COMFORT, [1.5, 0.0], [1.5, 0.0], [[0.0, 0.0], [3.0, 0.0]], dirs=[[1.0, 0.0], [-1.0, 0.0]])
    assert float(t.social_term) == pytest.approx(2 * social(0.525), rel=1e-12)
    # a masked pedestrian does not count
    t = reward(COMFORT, [1.5, 0.0], [1.5, 0.0], [[0.0, 0.0], [3.0, 0.0]], dirs=[[1.0, 0.0], [-1.0, 0.0]],
               mask=[True, False])
    assert float(t.social_term) == pytest.approx(social(0.525), rel=1e-12)


def test_comfort_uses_end_of_step_positions():
    # robot walks into the zone during the step
    t = reward(COMFORT, [3.0, 0.0], [1.5, 0.0], [0.0, 0.0])
    assert float(t.social_term) == pytest.approx(social(0.525))


def test_crowdnav_reports_comfort_zone_without_penalising_it():
    t = reward(CROWDNAV, [1.5, 0.0], [1.5, 0.0], [0.0, 0.0])
    assert bool(t.in_comfort_zone)
    assert float(t.social_term) == 0.0 and float(t.reward) == 0.0


# ---------------------------------------------------------------------- angular penalty, Eq. 13
@pytest.mark.parametrize(
    ("heading0", "heading1", "expected"),
    [
        (0.0, math.pi / 2, -0.02),  # at the threshold (π/2)
        (0.0, -math.pi / 2, -0.02),
        (0.0, math.pi, -0.02),
        (0.0, math.pi / 2 - 0.01, 0.0),  # below
        (3.0, -3.0, 0.0),  # wraps: the change is 0.28 rad, not 6 rad
        (0.5, 0.5, 0.0),
    ],
)
def test_angular_penalty(heading0, heading1, expected):
    t = reward(ANGULAR, [0.0, 0.0], [0.0, 0.1], [10.0, 10.0], heading0=heading0, heading1=heading1)
    assert float(t.angular_term) == pytest.approx(expected)
    assert float(t.reward) == pytest.approx(expected)
    comfort_only = reward(COMFORT, [0.0, 0.0], [0.0, 0.1], [10.0, 10.0], heading0=heading0, heading1=heading1)
    assert float(comfort_only.angular_term) == 0.0


def test_angular_threshold_is_a_parameter():
    cfg = RewardConfig("comfort_angular", angular_penalty_threshold=math.pi, angular_penalty=0.05)
    assert float(reward(cfg, [0, 0], [0, 0.1], [10, 10], heading1=math.pi / 2).angular_term) == 0.0
    assert float(reward(cfg, [0, 0], [0, 0.1], [10, 10], heading1=math.pi).angular_term) == pytest.approx(-0.05)


# ---------------------------------------------------------------------- discomfort, collision, success
def test_discomfort_is_linear_in_surface_distance():
    # surface distance 0.7 - 0.6 = 0.1 m < 0.2 m: (0.1 - 0.2) * 0.5 * 0.25 = -0.0125
    t = reward(CROWDNAV, [0.7, 0.0], [0.7, 0.0], [0.0, 0.0])
    assert float(t.min_distance) == pytest.approx(0.1)
    assert float(t.discomfort_term) == pytest.approx(-0.0125)
    assert float(t.reward) == pytest.approx(-0.0125)
    assert float(reward(CROWDNAV, [0.85, 0.0], [0.85, 0.0], [0.0, 0.0]).discomfort_term) == 0.0
    # the minimum over the step counts: passing 0.05 m from the surface mid-step
    t = reward(CROWDNAV, [-1.0, 0.65], [1.0, 0.65], [0.0, 0.0])
    assert float(t.min_distance) == pytest.approx(0.05)
    assert float(t.discomfort_term) == pytest.approx((0.05 - 0.2) * 0.5 * DT)


def test_collision_and_success():
    t = reward(CROWDNAV, [0.5, 0.0], [0.55, 0.0], [0.0, 0.0])
    assert bool(t.collision) and not bool(t.success)
    assert float(t.reward) == pytest.approx(-0.25) and float(t.collision_term) == pytest.approx(-0.25)
    t = reward(CROWDNAV, [0.0, 3.5], [0.0, 3.8], [5.0, 5.0], goal=[0.0, 4.0])  # 0.2 m from the goal < radius
    assert bool(t.success) and not bool(t.collision)
    assert float(t.reward) == pytest.approx(1.0) and float(t.success_term) == pytest.approx(1.0)
    t = reward(CROWDNAV, [0.0, 3.5], [0.0, 3.65], [5.0, 5.0], goal=[0.0, 4.0])  # 0.35 m: not yet
    assert not bool(t.success) and float(t.reward) == 0.0
    custom = RewardConfig("crowdnav", success_reward=2.0, collision_penalty=-1.0)
    assert float(reward(custom, [0.0, 3.5], [0.0, 3.8], [5.0, 5.0], goal=[0.0, 4.0]).reward) == pytest.approx(2.0)
    assert float(reward(custom, [0.5, 0.0], [0.55, 0.0], [0.0, 0.0]).reward) == pytest.approx(-1.0)


def test_collision_beats_success():
    # the robot reaches its goal but sweeps through a pedestrian on the way
    t = reward(CROWDNAV, [0.0, -1.0], [0.0, 1.0], [0.0, 0.0], goal=[0.0, 1.0])
    assert bool(t.collision) and not bool(t.success)
    assert float(t.reward) == pytest.approx(-0.25) and float(t.success_term) == 0.0


def test_terminal_steps_have_no_shaping_terms():
    # success while a pedestrian's comfort zone holds the goal, with a sharp turn, 0.1 m from a surface
    kwargs = dict(robot0=[0.0, 3.6], robot1=[0.0, 3.9], humans0=[0.0, 4.6], dirs=[0.0, -1.0], heading0=0.0,
                  heading1=math.pi / 2)
    for cfg in (CROWDNAV, COMFORT, ANGULAR):
        running = reward(cfg, **kwargs)  # the same step without reaching the goal is shaped
        assert float(running.min_distance) == pytest.approx(0.1)
        assert float(running.reward) < 0
        t = reward(cfg, **kwargs, goal=[0.0, 4.0])
        assert bool(t.success)
        assert float(t.social_term) == float(t.angular_term) == float(t.discomfort_term) == 0.0
        assert float(t.reward) == pytest.approx(1.0)
    # collision with a turn inside a comfort zone
    t = reward(ANGULAR, [0.5, 0.0], [0.55, 0.0], [0.0, 0.0], heading1=math.pi)
    assert float(t.reward) == pytest.approx(-0.25) and float(t.angular_term) == 0.0 and float(t.social_term) == 0.0


def test_no_pedestrians():
    t = compute_reward(ANGULAR, DT, np.zeros(2), np.array([0.0, 0.25]), np.float64(0.0), np.float64(0.0), FAR_GOAL,
                       np.float64(R), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool))
    assert float(t.reward) == 0.0 and float(t.min_distance) == math.inf and not bool(t.collision)


# ---------------------------------------------------------------------- one implementation, any leading dims
def random_transitions(rng, shape, n):
    robot0 = rng.uniform(-2, 2, (*shape, 2))
    robot1 = robot0 + rng.uniform(-0.3, 0.3, (*shape, 2))
    humans0 = rng.uniform(-2.5, 2.5, (*shape, n, 2))
    humans1 = humans0 + rng.uniform(-0.3, 0.3, (*shape, n, 2))
    angle = rng.uniform(-math.pi, math.pi, (*shape, n))
    dirs = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    goal = robot1 + rng.uniform(-0.5, 0.5, (*shape, 2))
    return dict(
        robot_pos0=robot0, robot_pos1=robot1, heading0=rng.uniform(-math.pi, math.pi, shape),
        heading1=rng.uniform(-math.pi, math.pi, shape), goal=goal, robot_radius=rng.uniform(0.2, 0.4, shape),
        human_pos0=humans0, human_pos1=humans1, human_dir=dirs, human_radius=rng.uniform(0.2, 0.4, (*shape, n)),
        mask=rng.random((*shape, n)) < 0.8,
    )


def numpy_reward(cfg, dt, robot_pos0, robot_pos1, heading0, heading1, goal, robot_radius, human_pos0, human_pos1,
                 human_dir, human_radius, mask):
    """A readable NumPy form of the reward (Eq. 9-14 with the module docstring's conventions), broadcast over (...)."""
    radius_sum = human_radius + robot_radius[..., None]
    d0 = robot_pos0[..., None, :] - human_pos0
    dv = (robot_pos1 - robot_pos0)[..., None, :] - (human_pos1 - human_pos0)
    dv2 = np.sum(dv * dv, axis=-1)
    t = np.where(dv2 > 1e-12, np.clip(-np.sum(d0 * dv, axis=-1) / np.where(dv2 > 1e-12, dv2, 1.0), 0.0, 1.0), 0.0)
    surface = np.where(mask, np.linalg.norm(d0 + t[..., None] * dv, axis=-1) - radius_sum, np.inf)
    min_distance = surface.min(axis=-1)
    collision = min_distance < 0
    success = ~collision & (np.linalg.norm(robot_pos1 - goal, axis=-1) < robot_radius)
    shaping = ~(collision | success)
    rel = robot_pos1[..., None, :] - human_pos1
    dist = np.linalg.norm(rel, axis=-1)
    surf = rel * (np.maximum(dist - radius_sum, 0.0) / np.maximum(dist, 1e-9))[..., None]
    x0 = np.sum(surf * human_dir, axis=-1)
    y0 = surf[..., 1] * human_dir[..., 0] - surf[..., 0] * human_dir[..., 1]
    w = np.sqrt(x0**2 * (cfg.comfort_side / cfg.comfort_person) ** 2 + y0**2)
    inside = (w <= cfg.comfort_side) & (x0 >= 0) & mask
    social = np.where(inside, -cfg.social_penalty * (np.exp(-(w - cfg.comfort_side)) - 1.0), 0.0).sum(axis=-1)
    turn = np.abs(np.mod(heading1 - heading0 + np.pi, 2 * np.pi) - np.pi)
    terms = dict(
        success_term=np.where(success, cfg.success_reward, 0.0),
        collision_term=np.where(collision, cfg.collision_penalty, 0.0),
        discomfort_term=np.where(shaping & (min_distance < cfg.discomfort_dist) & cfg.uses_discomfort,
                                 (min_distance - cfg.discomfort_dist) * cfg.discomfort_factor * dt, 0.0),
        social_term=np.where(shaping & cfg.uses_social, social, 0.0),
        angular_term=np.where(shaping & cfg.uses_angular & (turn >= cfg.angular_penalty_threshold - 1e-9),
                              -cfg.angular_penalty, 0.0),
    )
    return dict(terms, reward=sum(terms.values()), success=success, collision=collision, min_distance=min_distance,
                in_comfort_zone=inside.any(axis=-1))


@pytest.mark.parametrize("name", ["crowdnav", "comfort", "comfort_angular"])
def test_the_compiled_reward_is_the_numpy_form(name):
    cfg = RewardConfig(name)
    batch = random_transitions(np.random.default_rng(3), (2000,), 6)
    terms, expected = compute_reward(cfg, DT, **batch), numpy_reward(cfg, DT, **batch)
    for field, value in expected.items():
        np.testing.assert_allclose(getattr(terms, field), value, rtol=1e-12, atol=1e-15, err_msg=field)
    assert terms.collision.any() and terms.success.any() and (terms.angular_term < 0).any() == cfg.uses_angular


@pytest.mark.parametrize("name", ["crowdnav", "comfort", "comfort_angular"])
def test_one_transition_equals_its_row_of_a_batch(name):
    cfg = RewardConfig(name)
    rng = np.random.default_rng(1)
    batch = random_transitions(rng, (400,), 6)
    terms = compute_reward(cfg, DT, **batch)
    assert terms.collision.any() and terms.success.any() and terms.in_comfort_zone.any()
    assert (terms.social_term < 0).any() == cfg.uses_social
    for i in range(400):
        single = compute_reward(cfg, DT, **{k: v[i] for k, v in batch.items()})
        for field in terms._fields:
            assert float(getattr(single, field)) == pytest.approx(float(getattr(terms, field)[i]), rel=1e-12, abs=1e-15), field


def test_batched_over_lookahead_shape():
    """The lookahead evaluates (B, 80) transitions at once."""
    batch = random_transitions(np.random.default_rng(2), (3, 80), 10)
    terms = compute_reward(ANGULAR, DT, **batch)
    for field in terms._fields:
        assert getattr(terms, field).shape == (3, 80), field
    single = compute_reward(ANGULAR, DT, **{k: v[2, 17] for k, v in batch.items()})
    assert float(single.reward) == pytest.approx(float(terms.reward[2, 17]), abs=1e-15)


# ---------------------------------------------------------------------- geometry helpers
def test_closest_approach_catches_agents_passing_through_each_other():
    # swap places within one step: end points 2 m apart, but they meet in the middle
    d = closest_approach(np.array([-1.0, 0.0]), np.array([1.0, 0.0]), np.array([1.0, 0.0]), np.array([-1.0, 0.0]))
    assert float(d) == pytest.approx(0.0, abs=1e-12)
    t = reward(CROWDNAV, [-1.0, 0.0], [1.0, 0.0], [1.0, 0.0], humans1=[-1.0, 0.0])
    assert bool(t.collision)
    # crossing paths at different times: no collision
    d = closest_approach(np.array([-1.0, 0.0]), np.array([0.0, 0.0]), np.array([1.0, 1.0]), np.array([1.0, 0.0]))
    assert float(d) > 0.6


def test_closest_approach_parallel_and_static():
    d = closest_approach(np.array([0.0, 0.0]), np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([1.0, 1.0]))
    assert float(d) == pytest.approx(1.0)
    assert not bool(reward(CROWDNAV, [0.0, 0.0], [1.0, 0.0], [0.0, 1.0], humans1=[1.0, 1.0]).collision)
    d = closest_approach(np.zeros(2), np.zeros(2), np.array([3.0, 4.0]), np.array([3.0, 4.0]))
    assert float(d) == pytest.approx(5.0)
    # batched: (B, N)
    d = closest_approach(np.zeros((4, 1, 2)), np.ones((4, 1, 2)), np.zeros((4, 3, 2)), np.zeros((4, 3, 2)))
    assert d.shape == (4, 3)


def test_walking_direction_keeps_last_walking_direction():
    vel = np.zeros((5, 2, 2))  # (T, N, 2), oldest first
    vel[0, 0] = [2.0, 0.0]
    vel[1, 0] = [0.0, 0.5]  # pedestrian 0 last walked +y, then stood still for 3 steps
    vel[:, 1] = [0.0, 0.0]  # pedestrian 1 never moved: faces the robot
    dirs = walking_direction(vel, np.array([[0.0, 0.0], [1.0, 1.0]]), np.array([4.0, 5.0]))
    np.testing.assert_allclose(dirs, [[0.0, 1.0], [0.6, 0.8]], atol=1e-12)
    # the newest moving velocity wins
    vel[4, 0] = [-3.0, 0.0]
    np.testing.assert_allclose(walking_direction(vel, np.zeros((2, 2)), np.array([4.0, 5.0]))[0], [-1.0, 0.0])


def test_walking_direction_batched():
    rng = np.random.default_rng(3)
    vel = rng.normal(size=(7, 5, 4, 2)) * (rng.random((7, 5, 4, 1)) < 0.5)
    pos, robot = rng.normal(size=(7, 4, 2)), rng.normal(size=(7, 2))
    dirs = walking_direction(vel, pos, robot)
    assert dirs.shape == (7, 4, 2)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0)
    for b in range(7):
        np.testing.assert_allclose(walking_direction(vel[b], pos[b], robot[b]), dirs[b])


def test_batched_reward_without_directions_skips_only_the_comfort_zone():
    from sb3_crowdnav.sim.config import RewardConfig
    from sb3_crowdnav.sim.rewards import compute_reward

    rng = np.random.default_rng(5)
    b, n = 64, 6
    args = dict(
        robot_pos0=rng.uniform(-1, 1, (b, 2)), robot_pos1=rng.uniform(-1, 1, (b, 2)), heading0=rng.uniform(-3, 3, b),
        heading1=rng.uniform(-3, 3, b), goal=rng.uniform(-1, 1, (b, 2)), robot_radius=np.full(b, 0.3),
        human_pos0=rng.uniform(-1.5, 1.5, (b, n, 2)), human_pos1=rng.uniform(-1.5, 1.5, (b, n, 2)),
        human_radius=np.full((b, n), 0.3), mask=rng.random((b, n)) < 0.8,
    )
    dirs = rng.normal(size=(b, n, 2))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    cfg = RewardConfig(name="crowdnav")
    full = compute_reward(cfg, 0.25, human_dir=dirs, **args)
    lean = compute_reward(cfg, 0.25, human_dir=None, **args)
    np.testing.assert_array_equal(full.reward, lean.reward)
    np.testing.assert_array_equal(full.min_distance, lean.min_distance)
    assert full.in_comfort_zone.any() and not lean.in_comfort_zone.any()
    with pytest.raises(ValueError, match="human_dir"):
        compute_reward(RewardConfig(name="comfort"), 0.25, human_dir=None, **args)
