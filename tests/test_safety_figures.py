"""The safety figures of the episode statistics, records and tables: each on cases known by hand, and against readable
forms recomputed from an episode's trajectory."""

import csv
import itertools
import math

import gymnasium as gym
import numpy as np
import pytest
import shapely

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.envs import EpisodeStatistics
from sb3_crowdnav.evaluation import results_table, summarize
from sb3_crowdnav.evaluation.runner import run_episode
from sb3_crowdnav.evaluation.tables import SAFETY_COLUMNS
from sb3_crowdnav.sim import RewardConfig
from sb3_crowdnav.sim.actions import wrap
from sb3_crowdnav.sim.observation import Robot
from sb3_crowdnav.sim.proximity import NEAR_MISS_DISTANCE, TTC_HORIZON, min_time_to_collision
from sb3_crowdnav.sim.rewards import RewardTerms
from sb3_crowdnav.sim.warehouse import kernels

LAYOUT = {"width": 16.0, "height": 10.0, "racks": [{"rect": [-6.0, -3.0, -1.0, -2.0]}, {"rect": [1.0, -3.0, 6.0, -2.0]},
                                                  {"rect": [-0.5, -0.4, 0.5, 0.4]}]}
STRAIGHT = 64  # speed index 4 (v_pref), direction index 0 (straight on)
SLOW_STRAIGHT = 0  # 0.2 v_pref, straight on
STOP = 80  # actions="with_stop"


def reference_ttc(robot, humans, mask, horizon=TTC_HORIZON):
    """The readable form: the smaller root of |Δp + Δv t|² = (r + r_i)² per present person, 0 when overlapping."""
    (px, py, vx, vy, radius), best = robot, horizon
    for (hx, hy, hvx, hvy, hr), present in zip(humans, mask, strict=True):
        if not present:
            continue
        dp, dv, reach = np.array([hx - px, hy - py]), np.array([hvx - vx, hvy - vy]), radius + hr
        if dp @ dp <= reach * reach:
            return 0.0
        roots = np.roots([dv @ dv, 2 * dp @ dv, dp @ dp - reach * reach]) if dv @ dv > 0 else []
        ahead = [t.real for t in np.atleast_1d(roots) if abs(t.imag) < 1e-12 and t.real >= 0]
        best = min([best, *ahead])
    return best


def human(x, y, vx=0.0, vy=0.0, r=0.3):
    return [x, y, vx, vy, r]


# ---------------------------------------------------------------- time-to-collision
def test_head_on_ttc_is_gap_over_closing_speed():
    humans = np.array([human(5.0, 0.0, -0.5), human(0.0, 0.0), human(-3.0, 8.0)])
    # the robot at 1 m/s, a person 5 m ahead at 0.5 m/s towards it: (5 - 0.6) / 1.5; the padded slot is not present
    ttc = min_time_to_collision(0.0, 0.0, 1.0, 0.0, 0.3, humans, np.array([True, False, False]), TTC_HORIZON)
    assert ttc == pytest.approx(4.4 / 1.5)
    # overlapping now: 0; walking away, passing 1 m aside, or standing 200 m ahead: the cap; no one present: the cap
    assert min_time_to_collision(0.0, 0.0, 1.0, 0.0, 0.3, np.array([human(0.5, 0.0)]), np.array([True]), 10.0) == 0.0
    for h in (human(5.0, 0.0, 2.0), human(5.0, 1.0), human(200.0, 0.0)):
        assert min_time_to_collision(0.0, 0.0, 1.0, 0.0, 0.3, np.array([h]), np.array([True]), 10.0) == 10.0
    assert min_time_to_collision(0.0, 0.0, 1.0, 0.0, 0.3, humans, np.zeros(3, dtype=bool), 10.0) == 10.0


def test_ttc_kernel_matches_the_readable_form():
    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(0, 6))
        humans = np.column_stack([rng.uniform(-6, 6, (n, 2)), rng.uniform(-1.5, 1.5, (n, 2)), rng.uniform(0.2, 0.4, n)])
        mask = rng.random(n) < 0.8
        robot = (*rng.uniform(-1, 1, 2), *rng.uniform(-1, 1, 2), 0.3)
        assert min_time_to_collision(*robot, humans.reshape(n, 5), mask, 10.0) == pytest.approx(
            reference_ttc(robot, humans.reshape(n, 5), mask), abs=1e-9)


# ---------------------------------------------------------------- the statistics, step by step
def _terms(min_distance):
    zero = np.float64(0.0)
    return RewardTerms(zero, np.bool_(False), np.bool_(min_distance < 0), zero, zero, zero, zero, zero,
                       np.float64(min_distance), np.bool_(False))


def _robot(x, y, vx, vy, heading=0.0):
    state = [0.0] * 9
    state[0], state[1], state[2], state[3], state[Robot.RADIUS], state[Robot.HEADING] = x, y, vx, vy, 0.3, heading
    return state


def test_statistics_on_a_scripted_approach():
    stats = EpisodeStatistics(RewardConfig(), gamma=0.9, time_step=0.25, v_pref=1.0)
    mask = np.array([True, False])
    # 1: the robot at 1 m/s (from rest: 4 m/s²) towards a person 3 m ahead walking at it at 0.5 m/s
    stats.update(_robot(0, 0, 0, 0), _robot(0.25, 0, 1.0, 0), _terms(2.15), 0.0,
                 np.array([human(3.0, 0.0, -0.5), human(0, 0)]), mask)
    # 2: the robot turns by π/2 at 0.8 m/s, the person passes 0.1 m from its disc (a near miss, within 1 m)
    stats.update(_robot(0.25, 0, 1.0, 0), _robot(0.25, 0.2, 0, 0.8, math.pi / 2), _terms(0.1), 0.0,
                 np.array([human(0.25, -0.5, -0.5), human(0, 0)]), mask)
    # 3: the robot stops (0.8 -> 0 m/s: 3.2 m/s²), the person 0.5 m away
    stats.update(_robot(0.25, 0.2, 0, 0.8, math.pi / 2), _robot(0.25, 0.2, 0, 0, math.pi / 2), _terms(0.5), 0.0,
                 np.array([human(-0.85, 0.2, -0.5), human(0, 0)]), mask)
    s = stats.summary("timeout", 1)
    assert s["min_time_to_collision"] == pytest.approx((2.75 - 0.6) / 1.5)  # step 1's; then walking apart
    assert s["near_misses"] == 1 and s["steps_near_people"] == 2
    assert s["speed_near_people"] == pytest.approx((0.8 + 0.0) / 2)
    # the velocity vector's change: step 2's turn (|(0, 0.8) - (1, 0)| / 0.25) beats step 1's 4 m/s²
    assert s["peak_acceleration"] == pytest.approx(math.hypot(1.0, 0.8) / 0.25)
    assert s["peak_turn_rate"] == pytest.approx(2 * math.pi)  # π/2 in 0.25 s


def test_touching_a_person_is_no_near_miss_and_leaves_no_time():
    stats = EpisodeStatistics(RewardConfig(), gamma=0.9, time_step=0.25, v_pref=1.0)
    far = np.array([human(9.0, 9.0)])
    stats.update(_robot(0, 0, 0, 0), _robot(0, 0, 0, 0), _terms(NEAR_MISS_DISTANCE), 0.0, far, np.array([True]))
    stats.update(_robot(0, 0, 0, 0), _robot(0, 0, 0, 0), _terms(-0.01), 0.0, far, np.array([True]))
    s = stats.summary("collision", 1)
    assert s["near_misses"] == 0  # 0.2 m is not closer than 0.2 m; a collision is not a miss
    assert s["min_time_to_collision"] == 0.0  # the discs met during the step, wherever its end leaves them
    stats.reset()
    stats.update(_robot(0, 0, 0, 0), _robot(0, 0.25, 0, 1.0), _terms(math.inf), 0.0, np.zeros((2, 5)),
                 np.zeros(2, dtype=bool))
    s = stats.summary("running", 0)  # no one: the cap, and no step near anyone
    assert s["min_time_to_collision"] == TTC_HORIZON and s["steps_near_people"] == 0
    assert math.isnan(s["speed_near_people"])


# ---------------------------------------------------------------- in the env
def test_braking_in_one_step_is_four_metres_per_second_squared():
    env = gym.make("CrowdNav-v0", num_humans=0, actions="with_stop").unwrapped
    env.reset(seed=0)
    env.step(STRAIGHT)  # 0 -> 1 m/s
    env.stats.reset()  # the braking alone
    env.step(STOP)  # 1 -> 0 m/s
    assert env.sim.robot[Robot.VEL].tolist() == [0.0, 0.0]
    s = env.stats.summary("running", 0)
    assert s["peak_acceleration"] == pytest.approx(1.0 / 0.25) and s["peak_turn_rate"] == 0.0
    limited = gym.make("CrowdNav-v0", num_humans=0, actions="with_stop", max_acceleration=1.0).unwrapped
    limited.reset(seed=0)
    for action in (STRAIGHT, STRAIGHT, STOP, STOP):
        limited.step(action)
    assert limited.stats.summary("running", 0)["peak_acceleration"] == pytest.approx(1.0)


def test_episode_figures_match_the_trajectory():
    """Every figure recomputed from the recorded states and the steps' separations (random actions, people about)."""
    env = gym.make("CrowdNav-v0", num_humans=5, circle_radius=2.0).unwrapped
    rng = np.random.default_rng(1)
    close = 0
    for seed in range(3):
        env.reset(seed=seed)
        separations, done = [], False
        while not done:
            *_, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
            separations.append(info["min_distance"])
            done = terminated or truncated
        stats = info["episode_stats"]
        robot = np.stack([r for r, _ in env.trajectory])
        people = [h for _, h in env.trajectory]
        ttc = [0.0 if d <= 0 else reference_ttc([*robot[t + 1, :5]], people[t + 1], np.ones(len(people[t + 1]), bool))
               for t, d in enumerate(separations)]
        speeds = np.linalg.norm(robot[1:, Robot.VEL], axis=1)
        near = np.array(separations) < 1.0
        assert stats["min_time_to_collision"] == pytest.approx(min(ttc))
        assert stats["near_misses"] == sum(0 < d < 0.2 for d in separations)
        assert stats["steps_near_people"] == near.sum()
        assert stats["speed_near_people"] == pytest.approx(speeds[near].mean() if near.any() else math.nan, nan_ok=True)
        dt = env.scene.time_step
        changes = np.linalg.norm(np.diff(robot[:, Robot.VEL], axis=0), axis=1)
        assert stats["peak_acceleration"] == pytest.approx(changes.max() / dt)
        turns = [abs(wrap(b - a)) for a, b in itertools.pairwise(robot[:, Robot.HEADING])]
        assert stats["peak_turn_rate"] == pytest.approx(max(turns) / dt)
        assert "min_clearance" not in stats  # the open floor has no racks
        close += stats["near_misses"] + (stats["min_time_to_collision"] < TTC_HORIZON)
    assert close  # the cases were not all empty


def test_clearance_to_a_rack_in_a_fixed_layout():
    env = gym.make("CrowdNavWarehouse-v0", layout=LAYOUT, num_humans=0, actions="with_stop").unwrapped
    env.reset(seed=0)
    sim = env.sim
    # the robot by hand 1 m below the pallet's centre (its edge at y = -0.4), at rest, facing it; the start forgotten
    sim.robot[Robot.POS], sim.robot[Robot.VEL], sim.robot[Robot.HEADING] = (0.0, -1.0), (0.0, 0.0), math.pi / 2
    sim.min_clearance = math.inf
    env.step(STOP)
    assert sim.min_clearance == pytest.approx(0.6 - 0.3)  # centre 0.6 m from the pallet, radius 0.3 m
    env.step(SLOW_STRAIGHT)  # 0.2 m/s for 0.25 s towards it
    assert sim.min_clearance == pytest.approx(0.55 - 0.3)


def _reference_clearance(layout, p0, p1, radius):
    path = shapely.LineString([p0, p1]) if not np.allclose(p0, p1) else shapely.Point(p0)
    obstacles = [*layout.rack_polygons, layout.hall.exterior]
    return min(path.distance(o) for o in obstacles) - radius


def test_warehouse_clearance_is_swept_and_negative_exactly_on_an_obstacle_hit():
    env = gym.make("CrowdNavWarehouse-v0", layout=LAYOUT, num_humans=2).unwrapped
    rng = np.random.default_rng(3)
    hits = 0
    for seed in range(4):
        env.reset(seed=seed)
        done, t, action = False, 0, 0
        while not done:
            action = int(rng.integers(env.action_space.n)) if t % 6 == 0 else action
            *_, terminated, truncated, info = env.step(action)
            done, t = terminated or truncated, t + 1
        robot = np.stack([r for r, _ in env.trajectory])[:, Robot.POS]
        expected = min(_reference_clearance(env.layout, a, b, env.scene.robot_radius)
                       for a, b in itertools.pairwise(robot))
        stats = info["episode_stats"]
        assert stats["min_clearance"] == pytest.approx(expected, abs=1e-9)
        hit = stats.get("collision_with") == "obstacle"
        hits += hit
        assert (stats["min_clearance"] < 0) == hit or stats.get("collision_with") == "human"
    assert hits  # random actions hit a rack or wall at least once


def test_swept_segment_distance_by_hand():
    segments = np.array([[1.0, -1.0, 1.0, 1.0], [3.0, -1.0, 3.0, 1.0]])  # two vertical segments
    dist, order = np.empty(2), np.empty(2, dtype=np.int64)
    kernels.sense(segments, 0.0, 0.0, 0.5, 0.0, 1.0, 0.3, 4.0, 2, dist, order)  # fills dist, order from (0.5, 0)
    assert kernels.swept_segment_distance(segments, 0.0, 0.0, 0.5, 0.0, dist, order) == pytest.approx(0.5)
    kernels.sense(segments, 0.0, 2.0, 2.0, 2.0, 2.0, 0.3, 4.0, 2, dist, order)  # passing 1 m above the first's end
    assert kernels.swept_segment_distance(segments, 0.0, 2.0, 2.0, 2.0, dist, order) == pytest.approx(1.0)


# ---------------------------------------------------------------- records, summaries, tables, the CLI
def test_records_summary_and_tables_carry_the_figures(tmp_path):
    env = gym.make("CrowdNavWarehouse-v0", layout=LAYOUT, num_humans=2)
    from sb3_crowdnav import OrcaPolicy

    policy = OrcaPolicy.from_env(env.unwrapped, mapping="constrained")
    records = [run_episode(env, policy, seed) for seed in range(2)]
    for r in records:
        assert 0 <= r.min_time_to_collision <= TTC_HORIZON and math.isfinite(r.min_clearance)
    s = summarize(records)
    assert s.min_time_to_collision == pytest.approx(np.mean([r.min_time_to_collision for r in records]))
    assert s.peak_acceleration_max == max(r.peak_acceleration for r in records)
    assert s.min_clearance_worst == min(r.min_clearance for r in records)
    table = results_table({"ORCA": s})
    md = table.to_safety_markdown()
    assert md.startswith("| method | min TTC (s) | TTC < 1 s | near misses |") and "clearance to racks (m)" in md
    table.save(tmp_path / "results")
    assert (tmp_path / "results_safety.md").read_text() == md
    header = (tmp_path / "results.csv").read_text().splitlines()[0].split(",")
    assert header[-len(SAFETY_COLUMNS):] == list(SAFETY_COLUMNS)


def test_no_one_present_gives_the_cap_and_a_dash():
    env = gym.make("CrowdNav-v0", num_humans=0)
    from sb3_crowdnav import OrcaPolicy

    records = [run_episode(env, OrcaPolicy.from_env(env.unwrapped), seed) for seed in range(2)]
    s = summarize(records)
    assert s.min_time_to_collision == TTC_HORIZON and s.short_ttc_rate == 0.0 and s.near_misses == 0.0
    assert math.isnan(s.speed_near_people) and math.isnan(s.min_clearance)  # no step near anyone; no racks
    assert all(math.isfinite(getattr(s, k)) for k in ("peak_acceleration", "peak_acceleration_max", "peak_turn_rate"))
    row = results_table({"ORCA": s}).to_safety_markdown().splitlines()[2]
    assert row.startswith("| ORCA | 10.00 | 0.000 | 0.00 | - |") and "nan" not in row and "inf" not in row


def test_records_without_the_figures_leave_them_out():
    from test_evaluation_metrics import record

    s = summarize([record(0, "success", 40, 10.0, 1.0, 0.4, 0.1, 0.0)])
    assert all(math.isnan(getattr(s, k)) for k in ("min_time_to_collision", "near_misses", "peak_turn_rate_max"))
    assert results_table({"A": s}).to_safety_markdown().splitlines()[2] == "| A | - | - | - | - | - | - |"


def test_evaluate_prints_and_writes_the_safety_figures(tmp_path, capsys):
    from sb3_crowdnav.cli import main

    argv = ["evaluate", "--policy", "orca", "--episodes", "2", "--human-policy", "linear", "--humans", "3",
            "--no-progress", "--out", str(tmp_path)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "| method | min TTC (s) | TTC < 1 s | near misses | speed near people (m/s) |" in out
    assert (tmp_path / "results_safety.md").is_file()
    results = next(csv.DictReader((tmp_path / "results.csv").open()))
    assert set(SAFETY_COLUMNS) <= set(results) and float(results["min_ttc"]) <= TTC_HORIZON
    episodes = list(csv.DictReader((tmp_path / "episodes.csv").open()))
    for key in ("min_time_to_collision", "near_misses", "speed_near_people", "peak_acceleration", "peak_turn_rate"):
        assert key in episodes[0]
