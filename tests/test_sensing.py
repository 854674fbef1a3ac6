"""The people sensor: occlusion by racks, range, noise, latency; history from what was seen; the truth untouched."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.observation import Human
from sb3_crowdnav.sim.sensing import PeopleSensor
from sb3_crowdnav.sim.warehouse.config import FULL_SIGHT, PEOPLE_SENSOR_RANGE
from sb3_crowdnav.sim.warehouse.layout import layout_from_sizes
from sb3_crowdnav.sim.warehouse.sight import RackSight

T = 5


def _row(*people: tuple[float, float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A newest history row of 10 slots with ``people`` (x, y, vx, vy) of radius 0.3 in the first ones."""
    row, present = np.zeros((10, 5)), np.zeros(10, dtype=bool)
    for i, (x, y, vx, vy) in enumerate(people):
        row[i] = x, y, vx, vy, 0.3
        present[i] = True
    return row, present


def test_a_picker_behind_a_rack_is_masked_and_appears_when_the_robot_rounds_the_rack_end():
    layout = layout_from_sizes(1, 1, 8.0, 1.0, 2.0, 2.0)  # one 8 x 1 m rack, 2 m aisles around it
    _, y0, x1, y1 = layout.boxes[0]
    scene = SceneConfig(people_sensor_range=None, people_sensor_latency=0)
    sensor = PeopleSensor(scene, RackSight(layout))
    picker = (0.0, y0 - 0.5, 0.0, 0.0)  # standing at the rack's south face, in the middle
    row, present = _row(picker)
    north = y1 + 0.8  # the robot drives east along the north aisle, then turns south round the east end
    path = [(x, north) for x in np.arange(0.0, x1 + 0.9, 0.25)] + [(x1 + 0.9, y) for y in np.arange(north, y0 - 1, -0.25)]
    sensor.reset(np.random.default_rng(0), *path[0], row, present)
    seen = [bool(sensor.mask[0])]
    for x, y in path[1:]:
        sensor.step(x, y, row, present)
        seen.append(bool(sensor.mask[0]))
        if sensor.mask[0]:
            np.testing.assert_array_equal(sensor.history[:, 0], np.repeat(row[None, 0], T, axis=0))  # a new history
        else:
            assert not sensor.history[:, 0].any()  # padded over the whole window
    first = seen.index(True)
    assert not any(seen[:first]) and all(seen[first:])  # hidden all along the north side, seen from the rounding on
    assert path[first][0] > x1 - 0.5  # only near the rack's east end


def test_rack_sight_is_the_same_with_the_box_kernel_and_with_shapely():
    layout = layout_from_sizes(3, 2, 4.0, 1.0, 1.6, 1.6)
    boxes, polygons = RackSight(layout), RackSight(layout)
    polygons._boxes = None  # the general racks' rule (shapely), as for racks that are not boxes
    from shapely import Polygon, union_all

    polygons._racks = union_all([Polygon(p) for p in layout.rack_vertices]).buffer(-1e-9, join_style="mitre")
    rng = np.random.default_rng(1)
    w, h = layout.width / 2, layout.height / 2
    for _ in range(50):
        x, y = rng.uniform(-w, w), rng.uniform(-h, h)
        positions = rng.uniform((-w, -h), (w, h), (20, 2))
        radii = np.full(20, 0.3)
        np.testing.assert_array_equal(boxes.in_sight(x, y, positions, radii), polygons.in_sight(x, y, positions, radii))
        row = np.concatenate([positions, rng.normal(size=(20, 2)), radii[:, None]], axis=1)
        present = rng.random(20) < 0.8
        for sensor_range in (None, 3.0):  # the compiled frame (boxes) and the general one agree
            (s1, m1), (s2, m2) = boxes.frame(x, y, row, present, sensor_range), polygons.frame(x, y, row, present,
                                                                                               sensor_range)
            np.testing.assert_array_equal(m1, m2)
            np.testing.assert_array_equal(s1, s2)
            assert not (m1 & ~present).any() and not s1[~m1].any()


def test_the_range_keeps_people_whose_disc_is_within_it():
    sensor = PeopleSensor(SceneConfig(people_sensor_range=3.0))
    row, present = _row((3.2, 0.0, 0, 0), (3.4, 0.0, 0, 0), (0.0, -2.0, 0, 0), (9.0, 9.0, 0, 0))
    present[2] = False  # a padded slot is never seen
    sensor.reset(np.random.default_rng(0), 0.0, 0.0, row, present)
    assert sensor.mask[:4].tolist() == [True, False, False, False]  # 3.2 - 0.3 <= 3; 3.4 - 0.3 > 3


def _episode(env_id: str, steps: int = 40, seed: int = 4, **kwargs) -> list[tuple]:
    """(obs, reward, terminated, truncated, info) of ``steps`` steps of the same action sequence."""
    env = gym.make(env_id, **kwargs)
    rng = np.random.default_rng(9)
    obs, _ = env.reset(seed=seed)
    out = [(obs, 0.0, False, False, {})]
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
        out.append((obs, reward, terminated, truncated, {k: v for k, v in info.items() if k != "episode_stats"}))
        if terminated or truncated:
            obs, _ = env.reset()
            out.append((obs, 0.0, False, False, {}))
    return out


@pytest.mark.parametrize(("env_id", "sensing"), [
    ("CrowdNavWarehouse-v0", {}),  # its defaults: occlusion and an 8 m range
    ("CrowdNav-v0", {"people_sensor_range": 2.5, "people_sensor_noise": 0.1, "people_sensor_latency": 2}),
])
def test_sensing_changes_only_what_the_robot_sees_collisions_count_with_everyone(env_id, sensing):
    """The same seed and actions with and without the sensor: the same rewards, ends and infos (collisions, rewards
    and separations come from the true state); only the people in the observation differ."""
    blind_spots = FULL_SIGHT if env_id == "CrowdNavWarehouse-v0" else {}
    truth = _episode(env_id, **blind_spots)
    seen = _episode(env_id, **sensing)
    assert len(truth) == len(seen)
    hidden = 0
    for (o1, r1, te1, tr1, i1), (o2, r2, te2, tr2, i2) in zip(truth, seen, strict=True):
        assert (r1, te1, tr1, i1) == (r2, te2, tr2, i2)
        np.testing.assert_array_equal(o1["robot"], o2["robot"])  # the robot's own state is never late or noisy
        assert (o2["humans_mask"] <= o1["humans_mask"]).all()  # only those present can be seen
        hidden += int(o1["humans_mask"].sum() - o2["humans_mask"].sum())
    assert hidden > 0


def test_the_warehouse_observes_exactly_the_pickers_in_sight_and_range():
    env = gym.make("CrowdNavWarehouse-v0", num_humans=8)
    obs, _ = env.reset(seed=2)
    sim = env.unwrapped.sim
    rng = np.random.default_rng(0)
    counts = []
    for _ in range(120):
        n, (x, y) = sim.num_humans, sim.robot[:2]
        truth = sim.history[-1, :n]
        expected = RackSight(sim.layout).in_sight(x, y, truth[:, :2].copy(), truth[:, 4].copy())
        expected &= np.hypot(truth[:, 0] - x, truth[:, 1] - y) - truth[:, 4] <= PEOPLE_SENSOR_RANGE
        mask = obs["humans_mask"][:n].astype(bool)
        np.testing.assert_array_equal(mask, expected)
        humans = env.unwrapped.schema.humans_view(obs["humans"])
        np.testing.assert_allclose(humans[-1, :n][mask], truth[mask].astype(np.float32))  # seen: exact (no noise)
        assert not humans[:, :n][:, ~mask].any()  # unseen: zeros over the window
        counts.append((mask.sum(), n))
        obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        if terminated or truncated:
            obs, _ = env.reset()
    seen = sum(c for c, _ in counts) / sum(n for _, n in counts)
    assert 0.05 < seen < 0.95  # some pickers hidden, some seen


def test_latency_shows_the_people_as_they_were_and_a_history_of_what_was_seen():
    lag = 3
    now = _episode("CrowdNav-v0", steps=20, people_sensor_range=100.0)
    late = _episode("CrowdNav-v0", steps=20, people_sensor_latency=lag)
    view = gym.make("CrowdNav-v0").unwrapped.schema.humans_view
    for t in range(len(now)):
        expected = view(now[max(t - lag, 0)][0]["humans"])[-1]
        np.testing.assert_array_equal(view(late[t][0]["humans"])[-1], expected)
        if t >= lag + T:
            np.testing.assert_array_equal(view(late[t][0]["humans"]), view(now[t - lag][0]["humans"]))


def test_noise_perturbs_positions_by_sigma_only_and_repeats_with_the_seed():
    sigma = 0.2
    truth = _episode("CrowdNav-v0", steps=60, num_humans=8, max_humans=8)
    noisy = _episode("CrowdNav-v0", steps=60, num_humans=8, max_humans=8, people_sensor_noise=sigma)
    again = _episode("CrowdNav-v0", steps=60, num_humans=8, max_humans=8, people_sensor_noise=sigma)
    view = gym.make("CrowdNav-v0", num_humans=8, max_humans=8).unwrapped.schema.humans_view
    errors = []
    for (o1, *_), (o2, *_), (o3, *_) in zip(truth, noisy, again, strict=True):
        np.testing.assert_array_equal(o2["humans"], o3["humans"])
        a, b = view(o1["humans"])[-1], view(o2["humans"])[-1]
        np.testing.assert_array_equal(a[:, Human.VEL], b[:, Human.VEL])
        errors.append(b[:, Human.POS] - a[:, Human.POS])
    errors = np.concatenate(errors).ravel()
    assert abs(errors.std() - sigma) < 0.03 and abs(errors.mean()) < 0.03


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    ({"people_sensor_range": 0.0}, ValueError, "people_sensor_range must be > 0"),
    ({"people_sensor_range": -2.0}, ValueError, "people_sensor_range must be > 0"),
    ({"people_sensor_range": 5000.0}, ValueError, "people_sensor_range must be <= 1000"),
    ({"people_sensor_range": "8"}, TypeError, "people_sensor_range must be a real number"),
    ({"people_sensor_noise": -0.1}, ValueError, "people_sensor_noise must be >= 0"),
    ({"people_sensor_noise": float("nan")}, ValueError, "people_sensor_noise must be finite"),
    ({"people_sensor_latency": -1}, ValueError, "people_sensor_latency must be >= 0"),
    ({"people_sensor_latency": 1.5}, TypeError, "people_sensor_latency must be an int"),
    ({"people_sensor_latency": 21}, ValueError, "people_sensor_latency must be <= 20"),
])
@pytest.mark.parametrize("env_id", ["CrowdNav-v0", "CrowdNavWarehouse-v0"])
def test_infeasible_sensing_is_refused_at_construction(env_id, kwargs, error, match):
    with pytest.raises(error, match=match):
        gym.make(env_id, **kwargs)


def test_occlusion_is_the_warehouse_s_and_a_bool():
    with pytest.raises(TypeError, match="occlusion must be a bool"):
        gym.make("CrowdNavWarehouse-v0", occlusion=1)
    with pytest.raises(TypeError, match=r"unknown keyword argument.*occlusion"):
        gym.make("CrowdNav-v0", occlusion=True)  # nothing on the open floor hides anyone
    env = gym.make("CrowdNavWarehouse-v0").unwrapped
    assert env.warehouse.occlusion and env.scene.people_sensor_range == PEOPLE_SENSOR_RANGE
    assert gym.make("CrowdNav-v0").unwrapped.sim.sensor is None  # CrowdNav-v0 unchanged: no sensor at all


@pytest.mark.parametrize(("env_id", "kwargs"), [
    ("CrowdNavWarehouse-v0", {}),
    ("CrowdNav-v0", {"people_sensor_range": 3.0, "people_sensor_noise": 0.05, "people_sensor_latency": 1}),
])
def test_sensing_passes_the_checkers_without_warnings_and_repeats_with_the_seed(env_id, kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(env_id, **kwargs)
        gym_check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)
    assert not caught, [str(w.message) for w in caught]
    first, second = _episode(env_id, **kwargs), _episode(env_id, **kwargs)
    for (o1, *rest1), (o2, *rest2) in zip(first, second, strict=True):
        assert all(np.array_equal(o1[k], o2[k]) for k in o1) and rest1 == rest2
