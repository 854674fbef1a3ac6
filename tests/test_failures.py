"""The failure analysis (``sb3_crowdnav.evaluation.failures``): scripted collisions whose classes are known, the rules
against the env's own motion and collision, timeouts, the summary and the script's bad input."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from example_scripts import load_example

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.evaluation import failures
from sb3_crowdnav.evaluation.failures import (
    CollisionAnalysis,
    EpisodeLog,
    EpisodeRecorder,
    FailureRecord,
    FailureRules,
    TimeoutAnalysis,
    analyse_collision,
    analyse_episode,
    analyse_episodes,
    closer_of,
    side_of,
    summarize_failures,
)
from sb3_crowdnav.evaluation.metrics import wilson_interval
from sb3_crowdnav.evaluation.records import Trajectory
from sb3_crowdnav.evaluation.runner import make_policy, run_episode
from sb3_crowdnav.sim import SceneConfig
from sb3_crowdnav.sim.actions import STOP_ACTION, action_table, apply_action
from sb3_crowdnav.sim.observation import Robot
from sb3_crowdnav.sim.recording import write_recording
from sb3_crowdnav.sim.rewards import closest_approach
from sb3_crowdnav.sim.sensing import PeopleSensor
from sb3_crowdnav.sim.warehouse.layout import layout_from_sizes
from sb3_crowdnav.sim.warehouse.sight import RackSight

STRAIGHT = 64  # full speed, straight on (speed index 4, direction index 0)


class Fixed:
    """A policy that always takes the same action."""

    def __init__(self, action: int) -> None:
        self.action = action

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.array(self.action), None


def _replay_env(tmp_path: Path, positions: np.ndarray, **kwargs) -> EpisodeRecorder:
    """CrowdNav-v0 with one recorded person (positions (K, 2) at 0, 0.25, ... s), the robot from (0, 0) to (4, 0)."""
    path = tmp_path / "person.csv"
    write_recording(path, np.arange(len(positions)) * 0.25, positions[:, None, :])
    return EpisodeRecorder(gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={
        "path": path, "robot_start": (0.0, 0.0), "robot_goal": (4.0, 0.0), "start_time": 0.0}, **kwargs))


def test_a_person_walking_into_a_standing_robot_from_behind_closes_from_behind_and_driving_on_avoids_it(tmp_path):
    t = np.arange(0, 41) * 0.25
    env = _replay_env(tmp_path, np.stack([-2.3 + 1.5 * t, np.zeros_like(t)], axis=1), actions="with_stop")
    record = analyse_episode(env, Fixed(STOP_ACTION), seed=0)
    c = record.collision
    assert record.outcome == "collision" and c.hit == "human"
    assert (c.closer, c.side) == ("person", "behind")
    assert c.robot_closing == pytest.approx(0.0) and c.person_closing == pytest.approx(1.5)
    assert abs(c.bearing) == pytest.approx(180.0)
    assert c.seen and c.seen_for == pytest.approx((c.step + 1) * 0.25)  # on the open floor, seen all along
    assert c.avoidable and c.avoidable_with_warning
    # the reason: driving straight on at full speed in the colliding step keeps the discs apart
    log_robot, person = record.clip.robot, record.clip.humans[:, 0]
    speeds, directions = action_table(1.0, 2 * math.pi, "with_stop")
    moved = apply_action(log_robot[-2, Robot.POS], log_robot[-2, Robot.HEADING], log_robot[-2, Robot.GOAL],
                         speeds[STRAIGHT], directions[STRAIGHT], "unicycle", 0.25)
    assert closest_approach(log_robot[-2, Robot.POS], moved.position, person[-2, :2], person[-1, :2]) > 0.6


@pytest.mark.parametrize("limited", [False, True])
def test_a_robot_driving_into_a_standing_person_closes_on_them_in_front(tmp_path, limited):
    """With the warehouse AMR's limits (1 m/s², 1.5 rad/s) it cannot brake or turn away in the last step, but it could
    have a second earlier; without limits one step is enough."""
    limits = dict(actions="with_stop", max_acceleration=1.0, max_turn_rate=1.5) if limited else {}
    env = _replay_env(tmp_path, np.tile([2.0, 0.0], (41, 1)), **limits)
    c = analyse_episode(env, Fixed(STRAIGHT), seed=0).collision
    assert (c.closer, c.side, c.seen) == ("robot", "front", True)
    assert c.person_closing == pytest.approx(0.0) and c.robot_closing == pytest.approx(1.0)
    assert c.bearing == pytest.approx(0.0)
    assert c.contact == pytest.approx((1.7, 0.0))  # where the discs touch: the person's radius short of them
    assert c.avoidable is not limited
    assert c.avoidable_with_warning


def _picker_log(latency: int) -> EpisodeLog:
    """The robot drives up the end aisle of an 8 x 1 m rack at 1 m/s while a picker walks round the rack's end at
    1.3 m/s along the aisle above it; the warehouse's people sensor (the rack hides the picker; ``latency`` steps
    late) gives who was seen. They touch in step 7, the picker first in sight at state 5."""
    layout = layout_from_sizes(1, 1, 8.0, 1.0, 2.0, 2.0)  # the rack is [-4, 4] x [-0.5, 0.5]
    scene = SceneConfig(people_sensor_latency=latency)
    sensor = PeopleSensor(scene, RackSight(layout))
    robot, humans, seen = [], [], []
    for k in range(9):
        t = k * scene.time_step
        robot.append([4.35, -1.6 + t, 0.0, 1.0, scene.robot_radius, 4.35, 5.0, 1.0, math.pi / 2])
        humans.append([[2.0 + 1.3 * t, 0.85, 1.3, 0.0, scene.human_radius]])
        row = np.zeros((scene.max_humans, 5))
        row[0] = humans[-1][0]
        present = np.arange(scene.max_humans) == 0
        if k == 0:
            sensor.reset(np.random.default_rng(0), *robot[-1][:2], row, present)
        else:
            sensor.step(*robot[-1][:2], row, present)
        seen.append(sensor.mask[:1].copy())
    traj = Trajectory(robot=np.array(robot), humans=np.array(humans), human_goals=np.full((1, 2), np.nan), scene=scene,
                      obstacles=tuple(layout.polygons))
    return EpisodeLog(traj, np.array(seen), np.ones((9, 1), dtype=bool), np.zeros((9, 1), dtype=bool),
                      np.full(8, STRAIGHT), layout.segments)


def test_a_picker_hidden_by_a_rack_is_unseen_and_one_just_come_into_sight_is_seen_too_late():
    late = analyse_collision(_picker_log(latency=4))  # the sensor still shows the frame of 1 s ago: behind the rack
    assert late.step == 7 and not late.seen and late.seen_for == 0.0
    now = analyse_collision(_picker_log(latency=0))
    assert now.seen and now.seen_for == pytest.approx(0.75)  # states 5, 6, 7: less than the 1 s warning
    for c in (late, now):
        assert (c.closer, c.side) == ("robot", "front")  # the robot drove into the picker stepping round the end
        assert c.avoidable and c.avoidable_with_warning  # (no limits: it could have turned away from the rack)


def test_a_robot_driving_into_a_rack_is_an_obstacle_collision_touching_the_rack_face():
    layout = layout_from_sizes(1, 1, 8.0, 1.0, 2.0, 2.0)  # the rack is [-4, 4] x [-0.5, 0.5]
    scene = SceneConfig()
    robot = [[-5.5 + 0.25 * k, 0.1, 1.0, 0.0, scene.robot_radius, 0.0, 3.0, 1.0, 0.0] for k in range(6)]
    traj = Trajectory(robot=np.array(robot), humans=np.zeros((6, 0, 5)), human_goals=np.zeros((0, 2)), scene=scene,
                      obstacles=tuple(layout.polygons))
    none = np.zeros((6, 0), dtype=bool)
    c = analyse_collision(EpisodeLog(traj, none, none, none, np.full(5, STRAIGHT), layout.segments), hit="obstacle")
    assert (c.hit, c.step, c.person, c.closer, c.side) == ("obstacle", 4, -1, "", "")
    assert c.clearance == pytest.approx(-0.05)  # the swept disc's centre ends 0.25 m from the face, radius 0.3
    assert c.contact == pytest.approx((-4.0, 0.1))
    assert c.avoidable and c.avoidable_with_warning  # (no limits: turning away in the step is enough)


def test_a_replayed_person_appearing_on_the_robot_closes_on_no_one_and_was_not_seen():
    scene = SceneConfig()
    robot = np.tile([0.0, 0.0, 0.0, 0.0, scene.robot_radius, 4.0, 0.0, 1.0, 0.0], (4, 1))
    humans = np.zeros((4, 1, 5))
    humans[3, 0] = [0.4, 0.1, -1.0, 0.0, scene.human_radius]  # appears 0.4 m ahead: overlapping
    arrived = np.array([[False], [False], [False], [True]])
    traj = Trajectory(robot=robot, humans=humans, human_goals=np.zeros((1, 2)), scene=scene)
    c = analyse_collision(EpisodeLog(traj, arrived, arrived, arrived, np.full(3, STRAIGHT)))
    assert (c.closer, c.side, c.seen, c.seen_for) == ("none", "front", False, 0.0)
    assert c.gap < 0 and not c.avoidable  # already touching: no action helps in the step
    assert not c.sees_robot  # a log that says nothing of who sees the robot: nobody
    sees = analyse_collision(EpisodeLog(traj, arrived, arrived, arrived, np.full(3, STRAIGHT), sees_robot=np.ones(1, bool)))
    assert sees.sees_robot and sees == dataclasses.replace(c, sees_robot=True)  # the person hit's own, nothing else


@pytest.mark.parametrize("env_id", ["CrowdNav-v0", "CrowdNavWarehouse-v0"])
def test_the_log_says_which_people_see_the_robot_and_a_collision_which_one_it_was(env_id):
    """Half the people see the robot: the log holds the simulator's draw of the episode (both kinds occur), the
    analysis of a collision the draw of the person it names; everyone or nobody with True or False."""
    kinds, analysed = set(), 0
    for visible in (0.5, True, False):
        env = EpisodeRecorder(gym.make(env_id, robot_visible=visible, num_humans=8))
        policy = make_policy("random:3", env)
        for seed in range(6):
            record = run_episode(env, policy, seed, keep_trajectory=True)
            log = env.log(record.trajectory)
            drawn = env.unwrapped.sim.pickers.sees_robot if env_id != "CrowdNav-v0" else env.unwrapped.sim.people.sees_robot
            np.testing.assert_array_equal(log.sees_robot, drawn)
            if visible is not True and visible is not False:
                kinds.update(log.sees_robot.tolist())
            else:
                assert log.sees_robot.all() == visible and log.sees_robot.any() == visible
            if record.outcome == "collision" and record.collision_with == "human":
                c = analyse_collision(log)
                assert c.sees_robot == bool(log.sees_robot[c.person])
                analysed += 1
    assert kinds == {True, False}
    assert analysed >= 5 or env_id == "CrowdNavWarehouse-v0"  # (random actions meet the racks before the pickers)


def test_the_rules_reproduce_every_step_of_the_env_and_its_collision():
    """Re-applying the taken action (the analysis' motion rule) gives the recorded next state, and its collision test
    flags exactly the last step of a collision episode, with people, racks and walls."""
    for env_id, n_episodes in (("CrowdNav-v0", 4), ("CrowdNavWarehouse-v0", 3)):
        env = EpisodeRecorder(gym.make(env_id))
        policy = make_policy("random:5", env)
        scene = env.unwrapped.scene
        speeds, directions = action_table(scene.robot_v_pref, scene.rotation_range, scene.actions)
        for seed in range(n_episodes):
            record = run_episode(env, policy, seed, keep_trajectory=True)
            log = env.log(record.trajectory)
            robot = log.trajectory.robot
            for k, a in enumerate(log.actions.tolist()):
                moved = apply_action(robot[k, Robot.POS], robot[k, Robot.HEADING], robot[k, Robot.GOAL], speeds[a],
                                     directions[a], scene.kinematics, scene.time_step, velocity=robot[k, Robot.VEL],
                                     max_acceleration=scene.max_acceleration, max_turn_rate=scene.max_turn_rate)
                np.testing.assert_allclose(moved.position, robot[k + 1, Robot.POS], rtol=0, atol=1e-12)
                hit = failures._collides(log, k, robot[k, Robot.POS][None], moved.position[None], scene.robot_radius)
                assert bool(hit[0]) == (record.outcome == "collision" and k == record.steps - 1), (env_id, seed, k)


def test_a_timeout_on_an_empty_floor_has_nobody_in_view():
    env = EpisodeRecorder(gym.make("CrowdNav-v0", num_humans=0, time_limit=6.0))
    record = analyse_episode(env, Fixed(8), seed=0)  # the slowest speed, turning round: never arrives
    assert record.outcome == "timeout"
    t = record.timeout
    assert t.nobody_in_view and t.unseen_time == pytest.approx(6.0) and not t.people_present
    assert t.distance_left > 7.0
    crowded = analyse_episode(EpisodeRecorder(gym.make("CrowdNav-v0", time_limit=6.0)), Fixed(8), seed=0).timeout
    assert not crowded.nobody_in_view and crowded.unseen_time == 0.0 and crowded.people_present


@pytest.mark.parametrize(("robot", "person", "expected"), [
    (1.0, 0.0, "robot"), (0.0, 1.5, "person"), (1.0, 1.0, "both"), (0.55, 0.45, "both"), (0.65, 0.35, "robot"),
    (-0.5, 1.0, "person"), (-1.0, 0.5, "none"), (0.0, 0.0, "none")])
def test_who_closes_is_the_larger_share_of_the_closing_speed_with_a_tolerance(robot, person, expected):
    assert closer_of(robot, person, tolerance=0.1) == expected


@pytest.mark.parametrize(("bearing", "expected"), [
    (0.0, "front"), (-44.9, "front"), (45.0, "side"), (-90.0, "side"), (135.0, "side"), (135.1, "behind"),
    (180.0, "behind"), (-170.0, "behind")])
def test_the_side_is_the_bearing_from_the_robots_heading(bearing, expected):
    assert side_of(bearing) == expected


def test_the_side_angles_move_the_bounds():
    rules = FailureRules(side_angles=(30.0, 150.0))
    assert [side_of(b, rules) for b in (40.0, 140.0, 151.0)] == ["side", "side", "behind"]
    assert side_of(40.0) == "front"


@pytest.mark.parametrize(("kwargs", "error"), [
    ({"both_tolerance": 0.5}, ValueError), ({"side_angles": (45.0, 30.0)}, ValueError), ({"side_angles": 45.0}, TypeError),
    ({"side_angles": (-1.0, 90.0)}, ValueError), ({"warning": 0.0}, ValueError), ({"blind_window": "5"}, TypeError),
    ({"clip": -1.0}, ValueError)])
def test_bad_rules_are_refused_naming_the_parameter(kwargs, error):
    with pytest.raises(error, match=next(iter(kwargs))):
        FailureRules(**kwargs)


def _collision(closer: str, side: str, **kwargs) -> FailureRecord:
    fields = dict(hit="human", step=3, time=0.75, robot_speed=1.0, avoidable=True, avoidable_with_warning=True,
                  contact=(0.0, 0.0), clearance=math.nan, person=0, closer=closer, robot_closing=0.2,
                  person_closing=1.0, bearing=0.0, side=side, gap=0.1, seen=True, seen_for=2.0)
    return FailureRecord(0, "collision", 4, collision=CollisionAnalysis(**{**fields, **kwargs}))


def test_the_summary_counts_the_classes_and_gives_wilson_intervals():
    records = [_collision("person", "behind", robot_speed=0.0, sees_robot=True),
               _collision("person", "behind", seen=False, seen_for=0.0, robot_speed=0.2),
               _collision("robot", "front", avoidable=False, robot_closing=1.0, person_closing=0.0),
               _collision("none", "side", gap=-0.2, robot_speed=0.5),
               FailureRecord(1, "collision", 9, collision=CollisionAnalysis(
                   "obstacle", 8, 2.0, 0.5, False, True, (1.0, 1.0), -0.04)),
               FailureRecord(2, "timeout", 100, timeout=TimeoutAnalysis(25.0, True, 3.0, False)),
               FailureRecord(3, "timeout", 100, timeout=TimeoutAnalysis(0.0, False, 5.0, True)),
               *[FailureRecord(4 + i, "success", 40) for i in range(4)]]
    s = summarize_failures(records)
    assert (s.episodes, s.collisions, s.obstacle_collisions, s.timeouts) == (11, 4, 1, 2)
    assert (s.table["person"]["behind"], s.table["robot"]["front"], s.table["none"]["side"]) == (2, 1, 1)
    assert sum(sum(row.values()) for row in s.table.values()) == 4
    # the person closes faster in three, but one of them was already overlapping (a replay's arrival): not counted
    assert (s.shares["person_faster"].count, s.shares["person_faster"].total) == (2, 4)
    assert (s.shares["seen"].count, s.shares["seen_warned"].count, s.shares["avoidable"].count) == (3, 3, 3)
    assert (s.shares["sees_robot"].count, s.shares["sees_robot"].total) == (1, 4)
    assert s.robot_speed == pytest.approx(0.35)  # the median of the four collisions with people (not the rack's 0.5)
    assert (s.shares["obstacle_avoidable"].count, s.shares["obstacle_avoidable_with_warning"].count) == (0, 1)
    assert s.shares["nobody_in_view"].value == 0.5
    assert (s.shares["collision"].low, s.shares["collision"].high) == wilson_interval(5, 11)
    assert s.obstacle_clearance == pytest.approx(-0.04) and s.distance_left == pytest.approx(4.0)
    assert math.isnan(summarize_failures([]).shares["seen"].value) and math.isnan(summarize_failures([]).robot_speed)


@pytest.mark.slow
def test_records_are_the_same_with_two_workers():
    one = analyse_episodes("orca-constrained", 4, {"num_humans": 10})
    two = analyse_episodes("orca-constrained", 4, {"num_humans": 10}, workers=2)
    assert one == two


def test_the_script_writes_its_report_and_refuses_bad_input_in_one_line(tmp_path, capsys):
    script = load_example("failure_analysis")
    script.main(["--policy", "random:1", "--episodes", "3", "--out", str(tmp_path), "--env-kwargs",
                 "dict(time_limit=6.0)"])
    report = json.loads((tmp_path / "failures.json").read_text())["policies"]["Random"]
    collided = report["summary"]["collisions"] + report["summary"]["obstacle_collisions"]
    assert len(report["failures"]) == collided + report["summary"]["timeouts"]
    assert (tmp_path / "collisions_Random.png").exists() == (collided > 0)
    assert "## Random" in (tmp_path / "failures.md").read_text()
    assert "3 test episodes per policy (seeds 1,000,000 + i)" in (tmp_path / "failures.md").read_text()
    script.main(["--policy", "random:1", "--episodes", "1", "--seed-offset", "2000000", "--out", str(tmp_path / "v"),
                 "--env-kwargs", "dict(time_limit=2.0)"])
    assert "1 validation episodes per policy (seeds 2,000,000 + i)" in (tmp_path / "v" / "failures.md").read_text()
    for bad in (["--policy", "pretrained:nothing"], ["--policy", "orca", "--crowd", "nobody"],
                ["--policy", "orca", "--warning", "0"], ["--policy", "orca", "--env", "CartPole-v1"]):
        with pytest.raises(SystemExit) as exit_info:
            script.main([*bad, "--episodes", "2", "--out", str(tmp_path / "bad")])
        assert exit_info.value.code == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_the_summary_puts_analysis_folders_into_one_table_block_with_their_figures(tmp_path, capsys):
    analysis, summary = load_example("failure_analysis"), load_example("failure_summary")
    folder = tmp_path / "random"
    analysis.main(["--policy", "random:1", "--policy", "random:2", "--episodes", "3", "--out", str(folder),
                   "--env-kwargs", "dict(time_limit=6.0)"])
    report = json.loads((folder / "failures.json").read_text())["policies"]
    page = tmp_path / "docs" / "page.md"
    page.parent.mkdir()
    page.write_text("before\n<!-- f:begin -->\nold\n<!-- f:end -->\nafter\n")
    summary.main([f"tight time={folder}", "--figures", str(tmp_path / "figs"), "--markdown-into", str(page),
                  "--block", "f"])
    text = page.read_text()
    assert text.startswith("before\n<!-- f:begin -->\n| crowd | policy |") and text.endswith("<!-- f:end -->\nafter\n")
    assert "old" not in text
    for label, entry in report.items():  # one row per policy, its counts as the analysis wrote them
        s = entry["summary"]
        row = next(line for line in text.splitlines() if line.startswith(f"| tight time | {label} |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[2:4] == [str(s["episodes"]), f"{s['collisions']} / {s['obstacle_collisions']}"]
        assert cells[12] == str(s["timeouts"])
        assert cells[8] == (f"{s['shares']['sees_robot']['count']} / {s['collisions']}" if s["collisions"] else "–")
        assert cells[11] == (f"{s['robot_speed']:.2f}" if s["collisions"] else "–")
        assert cells[4] == (f"{sum(s['table']['none'].values())} / {s['collisions']}" if s["collisions"] else "–")
    figures = sorted((tmp_path / "figs" / "tight_time").glob("*.png"))
    assert [p.name for p in figures] == sorted(p.name for p in folder.glob("collisions_*.png"))
    assert all(f"](../figs/tight_time/{p.name})" in text for p in figures)
    for bad in (["nofolder"], [f"x={tmp_path}"], [f"x={folder}", "--markdown-into", str(page), "--block", "g"]):
        with pytest.raises(SystemExit) as exit_info:
            summary.main(bad)
        assert exit_info.value.code == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert page.read_text() == text  # a refused run writes nothing
