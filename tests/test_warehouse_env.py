"""CrowdNavWarehouse-v0: registration, checkers, seeding, obstacles that hold, pickers outside racks, refusals."""

from __future__ import annotations

import itertools
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from shapely.geometry import Point, Polygon

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.sim.geometry import segment_distance, swept_clearance
from sb3_crowdnav.sim.observation import ObservationSchema, Robot
from sb3_crowdnav.sim.warehouse.config import FULL_SIGHT
from sb3_crowdnav.sim.warehouse.simulator import next_waypoints

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "warehouse_layout.yaml"


def _episode(env, seed, policy=None):
    obs, _ = env.reset(seed=seed)
    frames = [obs]
    while True:
        action = env.action_space.sample() if policy is None else policy(obs)
        obs, _, terminated, truncated, info = env.step(action)
        frames.append(obs)
        if terminated or truncated:
            return frames, info


def test_make_without_prior_import():
    code = "import gymnasium as gym; env = gym.make('sb3_crowdnav:CrowdNavWarehouse-v0'); print(env.reset(seed=0)[1])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "route_length" in out


def test_both_checkers_pass_without_warnings():
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check(gym.make("CrowdNavWarehouse-v0").unwrapped)
        sb3_check(gym.make("CrowdNavWarehouse-v0").unwrapped)
    assert [str(w.message) for w in caught] == []


def test_observation_schema_and_bounds():
    env = gym.make("CrowdNavWarehouse-v0")
    env.action_space.seed(0)
    schema = ObservationSchema.from_space(env.observation_space)
    assert (schema.max_obstacles, schema.num_waypoints) == (16, 3)
    for seed in range(3):
        frames, _ = _episode(env, seed)
        for obs in frames:
            assert env.observation_space.contains(obs)
            segments = obs["obstacles"].reshape(16, 4)[obs["obstacles_mask"] > 0.5]
            pos = obs["robot"][Robot.POS]
            distances = segment_distance(pos, pos, segments[:, :2], segments[:, 2:])
            assert np.all(distances <= 4.0 + 1e-5) and np.all(np.diff(distances) >= -1e-5)  # in range, nearest first
            waypoints, goal = obs["waypoints"].reshape(3, 2), obs["robot"][Robot.GOAL]
            at_goal = np.all(np.isclose(waypoints, goal), axis=1)
            assert np.all(at_goal[np.argmax(at_goal):]) or not at_goal.any()  # after the goal, only the goal


def test_same_seed_same_episode_other_seeds_differ():
    env = gym.make("CrowdNavWarehouse-v0")
    env.action_space.seed(0)
    a, _ = _episode(env, 5, policy=lambda obs: 0)
    layout_a = env.unwrapped.layout.to_dict()
    b, _ = _episode(env, 5, policy=lambda obs: 0)
    assert layout_a == env.unwrapped.layout.to_dict()
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        for key in x:
            np.testing.assert_array_equal(x[key], y[key])
    starts = {env.reset(seed=s)[0]["robot"].tobytes() for s in range(8)}
    assert len(starts) == 8


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_no_picker_ever_inside_a_rack_or_wall():
    """200 random-action episodes: every picker keeps its body out of the layout's polygons (1 cm tolerance)."""
    env = gym.make("CrowdNavWarehouse-v0", num_humans=8)
    env.action_space.seed(1)
    worst = -np.inf
    for seed in range(200):
        frames, _ = _episode(env, seed)
        obstacles = [Polygon(p) for p in env.unwrapped.layout.polygons]
        for obs in frames[::2]:
            humans = obs["humans"].reshape(5, -1, 5)[-1][obs["humans_mask"] > 0.5]
            for x, y, _, _, r in humans:
                depth = max(r - o.exterior.distance(Point(x, y)) if not o.contains(Point(x, y)) else
                            r + o.exterior.distance(Point(x, y)) for o in obstacles)
                worst = max(worst, depth)
    assert worst <= 0.01, f"a picker reached {worst:.3f} m into an obstacle"


@pytest.mark.parametrize("seed", range(10))
def test_driving_straight_at_full_speed_ends_on_the_obstacle(seed):
    env = gym.make("CrowdNavWarehouse-v0", num_humans=0)
    env.reset(seed=seed)
    sim = env.unwrapped.sim
    pos = sim.robot[Robot.POS]
    target = min((rack.mean(axis=0) for rack in sim.layout.racks), key=lambda c: np.linalg.norm(c - pos))
    sim.robot[Robot.HEADING] = np.arctan2(*(target - pos)[::-1])  # face the nearest rack
    full_straight = 4 * 16  # the fastest speed, direction 0 (keep the heading)
    path = [pos.copy()]
    while True:
        _, reward, terminated, truncated, info = env.step(full_straight)
        path.append(env.unwrapped.sim.robot[Robot.POS].copy())
        if terminated or truncated:
            break
    assert info["outcome"] == "collision" and info["collision_with"] == "obstacle"
    assert reward == pytest.approx(-0.25)
    segments = env.unwrapped.sim.segments
    for p0, p1 in itertools.pairwise(path[:-1]):  # every step before the last kept clear
        assert swept_clearance(p0, p1, segments, np.ones(len(segments))) >= 0.3
    hall = env.unwrapped.layout.hall
    assert all(hall.contains(Point(p)) for p in path)  # never through a wall


def test_next_waypoints_drops_reached_ones_and_keeps_the_goal():
    wps = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    np.testing.assert_array_equal(next_waypoints(wps, np.array([0.0, 0.0]), 0.5), wps)
    np.testing.assert_array_equal(next_waypoints(wps, np.array([1.2, 0.0]), 0.5), [[2, 0], [3, 0], [3, 0]])
    np.testing.assert_array_equal(next_waypoints(wps, np.array([3.0, 0.0]), 5.0), [[3, 0], [3, 0], [3, 0]])
    batch = next_waypoints(np.stack([wps, wps]), np.array([[1.2, 0.0], [0.0, 0.0]]), 0.5)
    np.testing.assert_array_equal(batch[0], [[2, 0], [3, 0], [3, 0]])
    np.testing.assert_array_equal(batch[1], wps)


def test_the_example_layout_file_drives():
    env = gym.make("CrowdNavWarehouse-v0", layout=str(EXAMPLE))
    _, info = _episode(env, 0)
    assert env.unwrapped.layout.width == 16.0 and "route_length" in info["episode_stats"]


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"num_humans": 100, "max_humans": 100}, "num_humans: at most"),
    ({"num_humans": 200, "max_humans": 200}, "max_humans must be <= 100"),
    ({"layout_ranges": {"aisle_width": (0.5, 0.6)}}, "narrower than the robot's diameter"),
    ({"layout": {"width": 8, "height": 8, "racks": [{"rect": [-4, -0.5, 4, 0.5]}]}}, "split into 2 parts"),
    ({"min_route_distance": 100.0}, "min_route_distance: 100.0 m does not fit"),
    ({"dwell_time": (5.0, 1.0)}, "dwell_time must satisfy min <= max"),
    ({"max_obstacles": 0}, "max_obstacles must be >= 1"),
    ({"layout": "missing.yaml"}, "no file"),
    ({"shelves": 3}, "unknown keyword argument"),
])
def test_infeasible_settings_are_refused_at_construction(kwargs, message):
    with pytest.raises((ValueError, TypeError), match=message):
        gym.make("CrowdNavWarehouse-v0", **kwargs)


def test_rendering_draws_the_layout():
    env = gym.make("CrowdNavWarehouse-v0", render_mode="rgb_array")
    env.reset(seed=0)
    env.step(0)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3
    grey = np.all(np.abs(frame.astype(int) - 140) < 6, axis=2).mean()  # the racks' and walls' fill
    assert grey > 0.02
    env.close()


def test_pickers_move_continuously_from_where_the_observation_shows_them():
    """Each picker's first step starts where the reset observation put it (no jump of more than v_pref·Δt); seen
    through racks (occlusion zeroes a hidden picker's slot)."""
    env = gym.make("CrowdNavWarehouse-v0", num_humans=8, **FULL_SIGHT)
    for seed in range(10):
        obs, _ = env.reset(seed=seed)
        before = obs["humans"].reshape(5, -1, 5)[-1, :, :2]
        for _ in range(3):
            obs, *_ = env.step(0)
            after = obs["humans"].reshape(5, -1, 5)[-1, :, :2]
            assert np.linalg.norm(after - before, axis=1).max() <= 1.0 * 0.25 + 1e-6
            before = after


def test_evaluation_separates_human_and_obstacle_collisions(tmp_path):
    from sb3_crowdnav.cli import main
    from sb3_crowdnav.evaluation import results_table, run_episodes, summarize

    records = run_episodes("random:3", 20, env_id="CrowdNavWarehouse-v0")
    kinds = {r.collision_with for r in records if r.outcome == "collision"}
    assert kinds <= {"human", "obstacle"} and "obstacle" in kinds
    assert all(r.collision_with == "" for r in records if r.outcome != "collision")
    assert all(np.isfinite(r.route_length) and r.route_length >= 6.0 for r in records)
    s = summarize(records)
    assert s.has_obstacles
    assert s.human_collision_rate + s.obstacle_collision_rate == pytest.approx(s.collision_rate)
    markdown = results_table({"random": s}).to_markdown()
    assert "obstacle collision" in markdown and "path / route" in markdown
    open_floor = summarize(run_episodes("random:3", 5))
    assert not open_floor.has_obstacles and "obstacle collision" not in results_table({"r": open_floor}).to_markdown()
    # the command line takes the warehouse like any registered env, and draws the layout under the trajectories
    out = tmp_path / "bench"
    assert main(["benchmark", "--env", "CrowdNavWarehouse-v0", "--policy", "orca-constrained", "--policy", "random",
                 "--episodes", "4", "--out", str(out), "--no-gif", "--no-progress"]) == 0
    assert "obstacle_collision" in (out / "results.csv").read_text().splitlines()[0]
    assert (out / "trajectories.png").stat().st_size > 10_000


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_cli_renders_a_warehouse_episode(tmp_path):
    from sb3_crowdnav.cli import main

    out = tmp_path / "episode.gif"
    assert main(["render", "--env", "CrowdNavWarehouse-v0", "--policy", "orca-constrained", "--seed", "1000003",
                 "--out", str(out)]) == 0
    import imageio.v2 as imageio

    frames = imageio.mimread(out)
    assert len(frames) > 10
    grey = np.all(np.abs(frames[-1][..., :3].astype(int) - 140) < 6, axis=2).mean()  # racks and walls are drawn
    assert grey > 0.02


def test_a_picker_pressed_into_a_rack_is_pushed_out_to_its_radius():
    """The guard behind ORCA: a centre inside a rack, or closer to it than the radius, goes back to the surface."""
    from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
    from sb3_crowdnav.sim.warehouse.config import WarehouseConfig
    from sb3_crowdnav.sim.warehouse.simulator import WarehouseSimulator

    sim = WarehouseSimulator(SceneConfig(num_humans=4, scenario="warehouse"), RewardConfig(), WarehouseConfig())
    sim.reset(np.random.default_rng(0))
    rack = Polygon(sim.layout.racks[0])
    for inside in (np.asarray(rack.centroid.coords[0]), np.asarray(rack.exterior.coords[0]) + 0.05):
        out = sim.pickers._outside(inside)
        assert not rack.contains(Point(out))
        assert rack.exterior.distance(Point(out)) == pytest.approx(0.3 + 1e-3, abs=1e-6)
    assert sim.pickers._outside(np.array(sim.pickers.slots[0])) is None  # a pick slot is clear of every rack


def test_a_picker_pressed_during_a_step_is_moved_out_and_the_dwells_still_count_down():
    """A step whose ORCA result puts a picker inside a rack: the picker ends the step outside it (at its radius from
    the surface, in the simulator and in RVO2), and the other pickers' dwells count down as in any step."""
    env = gym.make("CrowdNavWarehouse-v0", num_humans=6)
    env.reset(seed=5)
    sim = env.unwrapped.sim
    pickers, rack = sim.pickers, Polygon(sim.layout.racks[0])
    inside = np.asarray(rack.exterior.coords[0]) + 0.05
    orca = pickers.crowd.crowds[0]
    advance = orca.step

    def pressed_step(*args):
        positions, velocities = advance(*args)
        positions[0] = inside
        return positions, velocities

    orca.step = pressed_step
    dwell = pickers.dwell.copy()
    env.step(0)
    position = sim.history[-1, 0, :2]
    assert not rack.contains(Point(position))
    assert rack.exterior.distance(Point(position)) == pytest.approx(0.3 + 1e-3, abs=1e-6)
    np.testing.assert_allclose(orca.sim.get_agent_position(0).to_tuple(), position, atol=1e-6)  # (RVO2: float)
    standing = dwell > 0
    assert standing.any()
    np.testing.assert_array_equal(pickers.dwell[standing], np.maximum(0.0, dwell[standing] - 0.25))


def test_the_fast_geometric_tests_of_a_step_agree_with_shapely_and_numpy():
    """The robot's line of sight, the pickers' overlap guard and the swept-disc hit test, in floats or on boxes,
    give what the shapely predicates and :func:`segment_distance` give."""
    from shapely.geometry import LineString

    from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
    from sb3_crowdnav.sim.warehouse.config import WarehouseConfig
    from sb3_crowdnav.sim.warehouse.simulator import WarehouseSimulator

    sim = WarehouseSimulator(SceneConfig(num_humans=4, scenario="warehouse"), RewardConfig(), WarehouseConfig())
    rng = np.random.default_rng(0)
    for _ in range(3):
        sim.reset(rng)
        layout, r = sim.layout, sim.scene.robot_radius
        sight = layout.free_space(r).buffer(1e-6)
        room = layout.free_space(sim.scene.human_radius - 1e-6)
        w, h = layout.width / 2, layout.height / 2
        points = rng.uniform((-w, -h), (w, h), (400, 2))
        starts = points[[sight.contains(Point(p)) for p in points]]
        for a, b in zip(starts[:-1], points[1 : len(starts)], strict=True):
            assert sim._in_sight(a, b) == sight.covers(LineString([a, b]))
        for group in points.reshape(-1, 4, 2):
            np.testing.assert_array_equal(sim.pickers._pressed(group), [not room.contains(Point(p)) for p in group])
        for p0, p1, seg in zip(points[:-1:2], points[1::2], sim.segments[rng.integers(len(sim.segments), size=200)],
                               strict=False):
            expected = LineString([p0, p1]).distance(LineString([seg[:2], seg[2:]]))
            assert float(segment_distance(p0, p1, seg[:2], seg[2:])) == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_a_fixed_layout_keeps_its_maps_and_gives_the_episodes_of_a_fresh_env():
    """A fixed layout's pick slots, roadmaps and routes between slots serve every episode: an env that ran other
    episodes first gives the same episode as a fresh one."""
    kwargs = {"layout": str(EXAMPLE), "num_humans": 8}
    used = gym.make("CrowdNavWarehouse-v0", **kwargs)
    for seed in range(3):
        _episode(used, 100 + seed, policy=lambda obs: 0)
    sim = used.unwrapped.sim
    maps = sim._fixed
    for seed in (7, 8):
        a, info_a = _episode(used, seed, policy=lambda obs: 17)
        b, info_b = _episode(gym.make("CrowdNavWarehouse-v0", **kwargs), seed, policy=lambda obs: 17)
        assert len(a) == len(b) and info_a["outcome"] == info_b["outcome"]
        for x, y in zip(a, b, strict=True):
            for key in x:
                np.testing.assert_array_equal(x[key], y[key])
    assert sim._fixed is maps
    assert len(maps[1]._routes) > 8  # routes between slots remembered across episodes


def test_a_picker_walks_from_its_slot_to_the_next_along_the_slots_route():
    env = gym.make("CrowdNavWarehouse-v0", num_humans=6)
    env.reset(seed=3)
    pickers = env.unwrapped.sim.pickers
    for _ in range(40):
        env.step(0)
        for i in range(pickers.n):
            if pickers.dwell[i] == 0:  # walking: the route of the slot it left to the slot it walks to ends there
                assert pickers.routes[i][-1] == pickers.slots[pickers.slot[i]].tolist()


def test_observed_segments_and_hit_candidates_come_from_the_stable_order_of_the_distances():
    """The observed segments are the first of the distances' stable order within range, and a rack or wall hit is
    the swept disc touching a segment, as with the distances themselves."""
    from sb3_crowdnav.sim.geometry import point_segment_distance

    env = gym.make("CrowdNavWarehouse-v0", num_humans=6)
    sim, rng = env.unwrapped.sim, np.random.default_rng(0)
    for episode in range(6):
        env.reset(seed=episode)
        terminated = truncated = False
        while not (terminated or truncated):
            p0 = sim.robot[Robot.POS].tolist()
            _, _, terminated, truncated, _ = env.step(int(rng.integers(80)))
            p1 = sim.robot[Robot.POS].tolist()
            d = sim._seg_dist
            np.testing.assert_allclose(d, point_segment_distance(np.array(p1), sim.segments[:, :2], sim.segments[:, 2:]),
                                       rtol=0, atol=1e-12)
            np.testing.assert_array_equal(sim._seg_order, np.argsort(d, kind="stable"))
            seen = np.argsort(d, kind="stable")[: min(16, int(np.count_nonzero(d <= sim.config.sensor_range)))]
            segments, mask = sim.observed_obstacles()
            np.testing.assert_array_equal(segments[: len(seen)], sim.segments[seen])
            assert mask.sum() == len(seen) and not segments[len(seen):].any()
            hit = segment_distance(np.array(p0), np.array(p1), sim.segments[:, :2], sim.segments[:, 2:]).min() < \
                sim.scene.robot_radius
            assert (not hit or terminated) and (hit or not sim.hit_obstacle)
