"""``crowd="replay"``: recorded people (a ``t,id,x,y`` CSV or the ETH/UCY text format), the reader's refusals, the
presence seam (people who come and go), the seeded placement of the robot and the proof: a ``CrowdNav-v0`` episode's
own people, recorded and replayed with the same actions, give the same observations and outcome."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import OrcaPolicy
from sb3_crowdnav.envs.crowd_nav import CrowdNavEnv
from sb3_crowdnav.evaluation import summarize
from sb3_crowdnav.evaluation.runner import run_episode
from sb3_crowdnav.sim import SceneConfig
from sb3_crowdnav.sim.observation import Human
from sb3_crowdnav.sim.recording import MAX_COORDINATE, MAX_SPEED, read_recording, write_recording


def _walkers(path: Path, n: int = 8, seconds: float = 60.0, seed: int = 0, step: float = 0.4) -> Path:
    """A synthetic recording: ``n`` people crossing a 16 m wide street at 1-1.6 m/s, each for 12-20 s from a random
    time, sampled every ``step`` s."""
    rng = np.random.default_rng(seed)
    times = np.arange(0.0, seconds, step)
    positions = np.zeros((len(times), n, 2))
    present = np.zeros((len(times), n), dtype=bool)
    for j in range(n):
        a = int(rng.integers(0, len(times) - 50))
        b = a + int(rng.integers(30, 50))
        side = 1.0 if j % 2 else -1.0
        t = times[a:b + 1] - times[a]
        positions[a:b + 1, j, 0] = -8.0 * side + side * rng.uniform(1.0, 1.6) * t
        positions[a:b + 1, j, 1] = rng.uniform(-3.0, 3.0) + 0.1 * np.sin(t)
        present[a:b + 1, j] = True
    write_recording(path, times, positions, present)
    return path


@pytest.fixture
def street(tmp_path: Path) -> Path:
    return _walkers(tmp_path / "street.csv")


# ---------------------------------------------------------------------- the proof
def _record_episode(env: gym.Env, actions: list[int] | None, seed: int) -> tuple[list[int], list, str, np.ndarray]:
    """Run one episode (the ORCA robot's actions when ``actions`` is None); its actions, observations, outcome and
    the people's positions at every step (steps + 1, n, 2)."""
    policy = OrcaPolicy.from_env(env, mapping="constrained") if actions is None else None
    obs, _ = env.reset(seed=seed)
    sim = env.unwrapped.sim
    n = sim.num_humans
    positions, observations, taken = [sim.history[-1, :n, Human.POS].copy()], [obs], []
    for k in range(env.unwrapped.max_steps):
        action = int(policy.predict(obs)[0]) if actions is None else actions[k]
        obs, _, terminated, truncated, info = env.step(action)
        taken.append(action)
        observations.append(obs)
        positions.append(sim.history[-1, :n, Human.POS].copy())
        if terminated or truncated:
            return taken, observations, info["outcome"], np.array(positions)
    raise AssertionError("the episode did not end")


@pytest.mark.parametrize(("seed", "robot"), [(0, "orca"), (3, "straight")])
def test_replaying_a_crowdnav_episodes_people_reproduces_its_observations_and_outcome(tmp_path, seed, robot):
    """CrowdNav-v0's people are at rest at reset: the recording begins one Δt before the episode with everyone at
    its start (the documented rule), so that the backward-difference velocity of the first step is zero too."""
    env = gym.make("CrowdNav-v0")
    dt = env.unwrapped.scene.time_step
    actions, observations, outcome, positions = _record_episode(env, None if robot == "orca" else [64] * 100, seed)
    steps = len(positions) - 1
    times = np.arange(-1, steps + 1) * dt
    path = tmp_path / "episode.csv"
    write_recording(path, times, np.concatenate([positions[:1], positions]))
    replay = gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={
        "path": path, "robot_start": (0.0, -4.0), "robot_goal": (0.0, 4.0), "start_time": 0.0})
    obs, info = replay.reset(seed=123)
    assert info["num_humans"] == positions.shape[1]
    replayed = [obs]
    for action in actions:
        obs, _, terminated, truncated, info = replay.step(action)
        replayed.append(obs)
    assert terminated or truncated
    assert info["outcome"] == outcome
    assert len(replayed) == len(observations)
    # RVO2 computes in float32: its positions (within 8 m) carry float32 rounding, which the replay's backward
    # difference divides by Δt; everything else is equal to the float32 observation's rounding
    atol = 2 * float(np.spacing(np.float32(8.0))) / dt
    for ours, theirs in zip(replayed, observations, strict=True):
        for key in theirs:
            np.testing.assert_allclose(ours[key], theirs[key], rtol=0, atol=atol)
    expected = {"orca": "success", "straight": "collision"}[robot]  # the proof covers both ends
    assert outcome == expected


# ---------------------------------------------------------------------- reading
def test_written_recordings_read_back_exactly(tmp_path):
    rng = np.random.default_rng(1)
    times = np.cumsum(rng.uniform(0.1, 0.5, 20))
    positions = rng.uniform(-5, 5, (20, 3, 2))
    positions[1:] = positions[:1] + np.cumsum(rng.uniform(-0.05, 0.05, (19, 3, 2)), axis=0)
    present = np.ones((20, 3), dtype=bool)
    present[:5, 2] = False
    write_recording(tmp_path / "r.csv", times, positions, present)
    rec = read_recording(tmp_path / "r.csv")
    assert rec.ids == ("0", "1", "2")
    np.testing.assert_array_equal(rec.times[2], times[5:])
    np.testing.assert_array_equal(rec.positions[0], positions[:, 0])
    assert rec.frame_step is None


def test_the_eth_format_reads_frames_at_the_given_frame_rate_and_infers_the_step(tmp_path):
    """The Social-GAN layout of ETH (frame step 10 at 15 fps): two people, times frame / 15 s."""
    lines = [f"{780 + 10 * k}.0\t{p}.0\t{1.0 + 0.8 * k + p:.2f}\t{3.5 - p:.2f}" for k in range(4) for p in (1, 2)]
    path = tmp_path / "biwi_eth.txt"
    path.write_text("\n".join(lines) + "\n")
    rec = read_recording(path, frame_rate=15.0)
    assert rec.ids == ("1", "2") and rec.frame_step == 10.0
    np.testing.assert_allclose(rec.times[0], (780 + 10 * np.arange(4)) / 15.0)
    np.testing.assert_allclose(rec.max_speed, 0.8 / (10 / 15))  # 1.2 m/s, not the 2 m/s of 0.4 s per row
    with pytest.raises(ValueError, match=r"frame_rate.*required"):
        read_recording(path)
    with pytest.raises(ValueError, match="frame_rate"):
        gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={"path": str(path)})
    env = gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={"path": str(path), "frame_rate": 15})
    env.reset(seed=0)


BAD_CSV = [  # (file text, the line named, what the message says)
    ("t,id,x,y\n0,1,0,0\n0.4,1,0.5,abc\n", 3, "not a number"),
    ("t,id,x,y\n0,1,0,0\n0.4,1,nan,0\n", 3, "finite"),
    ("t,id,x,y\n0,1,0,0\ninf,1,0,0\n", 3, "finite"),
    ("t,id,x,y,z\n0,1,0,0,0\n", 1, "unknown \\['z'\\]"),
    ("t,id,x\n0,1,0\n", 1, "missing \\['y'\\]"),
    ("time,id,x,y\n0,1,0,0\n", 1, "unknown \\['time'\\]"),
    ("t,id,x,y\n0,1,0,0\n0.4,1,0.5\n", 3, "expected 4 columns"),
    ("t,id,x,y\n0,1,0,0\n0.8,1,0.5,0\n0.4,1,0.7,0\n", 4, "increase strictly"),
    ("t,id,x,y\n0,1,0,0\n0,1,0.1,0\n", 3, "increase strictly"),
    ("t,id,x,y\n0,1,0,0\n0.4,1,0.5,0\n0.4,2,3,3\n", 4, "one sample"),
    ("t,id,x,y\n0,1,0,0\n0.4,1,1500,0\n", 3, "metres"),
    ("t,id,x,y\n0,1,0,0\n0.4,1,0,-2000.5\n", 3, "metres"),
    ("t,id,x,y\n0,1,0,0\n0.4,1,4.5,0\n", 3, f"faster than {MAX_SPEED:g} m/s"),  # 11.25 m/s: pixels or millimetres
    ("t,id,x,y\n0,,0,0\n", 2, "id is empty"),
]


@pytest.mark.parametrize(("text", "line", "what"), BAD_CSV, ids=lambda x: str(x)[:30])
def test_bad_recordings_are_refused_at_construction_naming_the_line(tmp_path, text, line, what):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=what) as caught:
        read_recording(path)
    assert f"bad.csv:{line}:" in str(caught.value)
    with pytest.raises(ValueError, match=f"bad.csv:{line}:"):  # the env refuses it at construction
        gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={"path": path})


BAD_ETH = [
    ("0 1 0 0\n10 1 0.4 0\n20 1 0.8\n", 3, "expected 4"),
    ("0 1 0 0\n10 1 0.4 0\n20 1 0.8 0 0 0\n", 3, "expected 4"),  # obsmat.txt's 8 columns
    ("0 1 0 0\n10 1 x 0\n", 2, "not a number"),
    ("0 1 0 0\n10 1 NaN 0\n", 2, "finite"),
    ("10 1 0 0\n0 1 0.4 0\n", 2, "increase strictly"),
    ("0 1 0 0\n10 1 0.4 0\n10 2 1 1\n", 3, "one sample"),
    ("0 1 120 80\n10 1 900 1200\n", 2, "metres"),  # pixels
    ("0 1 0 0\n1 1 0.5 0\n", 2, "faster than"),  # 12.5 m/s at 25 fps: 0.5 m in one frame
]


@pytest.mark.parametrize(("text", "line", "what"), BAD_ETH, ids=lambda x: str(x)[:30])
def test_bad_eth_recordings_are_refused_naming_the_line(tmp_path, text, line, what):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=what) as caught:
        read_recording(path, frame_rate=25.0)
    assert f"bad.txt:{line}:" in str(caught.value)


def test_the_plausibility_bounds_are_the_documented_ones():
    assert MAX_COORDINATE == 1000.0 and MAX_SPEED == 10.0


# ---------------------------------------------------------------------- settings
BAD_SETTINGS = [  # (crowd_kwargs beyond the path, exception, the name the message gives)
    ({"frame_rate": 15.0}, ValueError, "frame_rate"),  # a CSV's times are in seconds
    ({"frame_rate": -1.0}, ValueError, "frame_rate"),
    ({"robot_start": (0.0, 0.0)}, ValueError, "robot_goal"),
    ({"robot_start": (1.0, 1.0), "robot_goal": (1.0, 1.0)}, ValueError, "differ"),
    ({"robot_start": (0.0,), "robot_goal": (1.0, 1.0)}, ValueError, "robot_start"),
    ({"robot_start": "origin", "robot_goal": (1.0, 1.0)}, TypeError, "robot_start"),
    ({"robot_start": (0.0, math.nan), "robot_goal": (1.0, 1.0)}, ValueError, "robot_start"),
    ({"robot_start": (0.0, -4.0), "robot_goal": (0.0, 4.0), "crossing_length": 6.0}, ValueError, "crossing_length"),
    ({"crossing_length": 0.0}, ValueError, "crossing_length"),
    ({"crossing_length": "8"}, TypeError, "crossing_length"),
    ({"start_time": 1e4}, ValueError, "start_time"),
    ({"start_time": "0"}, TypeError, "start_time"),
    ({"time_window": (30.0, 10.0)}, ValueError, "time_window"),
    ({"time_window": (1e4, 2e4)}, ValueError, "time_window"),
    ({"time_window": 10.0}, TypeError, "time_window"),
    ({"speed": 2.0}, ValueError, "crowd_kwargs"),
    ({"lead_in": -0.5}, ValueError, "lead_in"),
    ({"lead_in": 11.0}, ValueError, "lead_in"),
    ({"lead_in": math.inf}, ValueError, "lead_in"),
    ({"lead_in": "1"}, TypeError, "lead_in"),
]


@pytest.mark.parametrize(("extra", "exception", "name"), BAD_SETTINGS, ids=lambda x: str(x))
def test_bad_replay_settings_are_refused_by_name(street, extra, exception, name):
    with pytest.raises(exception, match=name):
        gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={"path": street, **extra})


@pytest.mark.parametrize(("kwargs", "name"), [
    ({}, "path"), ({"crowd_kwargs": {"path": 3}}, "path"), ({"crowd_kwargs": {"path": "/no/such/file.csv"}}, "path")])
def test_a_replay_needs_a_readable_path(kwargs, name):
    with pytest.raises((ValueError, TypeError), match=name):
        gym.make("CrowdNav-v0", crowd="replay", **kwargs)


@pytest.mark.parametrize("kwargs", [
    {"num_humans": 4}, {"robot_visible": True}, {"robot_visible": 0.5}, {"human_speed": "measured"},
    {"stop_probability": 0.3}, {"human_v_pref": 1.3}, {"orca_neighbor_dist": 3.0}, {"circle_radius": 6.0},
    {"start_noise": 0.1}, {"square_width": 8.0}, {"stop_duration": (1.0, 2.0)}], ids=lambda k: next(iter(k)))
def test_what_the_recording_decides_is_refused_by_name(street, kwargs):
    name = next(iter(kwargs))
    with pytest.raises(ValueError, match=name):
        gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={"path": street}, **kwargs)
    if name in ("num_humans", "robot_visible", "human_speed", "stop_probability"):  # and by the scene itself
        with pytest.raises(ValueError, match=name):
            SceneConfig(crowd="replay", crowd_kwargs={"path": street}, **kwargs)


def test_more_people_at_once_than_max_humans_is_refused_naming_both_numbers(tmp_path):
    path = _walkers(tmp_path / "busy.csv", n=30, seconds=40.0)
    most = read_recording(path).max_present()
    assert most > 10
    with pytest.raises(ValueError, match=f"max_humans.*{most} people.*max_humans = 10"):
        gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={"path": path})
    env = gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={"path": path}, max_humans=most)
    seen = 0
    obs, _ = env.reset(seed=0)
    for _ in range(100):
        seen = max(seen, int(obs["humans_mask"].sum()))
        obs, *_ = env.step(8)
    assert 1 < seen <= most


def test_tracked_nearest_observes_the_max_humans_people_nearest_to_the_robot_each_in_its_slot(tmp_path):
    path = _walkers(tmp_path / "busy.csv", n=30, seconds=40.0)
    rec = read_recording(path)
    assert rec.max_present() > 6
    env = gym.make("CrowdNav-v0", crowd="replay", max_humans=6, time_limit=12.0,
                   crowd_kwargs={"path": path, "start_time": 10.0, "tracked": "nearest"})
    base = env.unwrapped
    obs, _ = env.reset(seed=0)
    model = base.sim.crowd
    track_pos, _, track_present = model.tracks
    kept = changed = 0
    previous = None
    for k in range(40):
        robot = obs["robot"][:2].astype(np.float64)
        obs, _, terminated, truncated, _ = env.step(k % 80)
        here = np.flatnonzero(track_present[k + 1])
        nearest = here[np.argsort(np.linalg.norm(track_pos[k + 1, here] - robot, axis=-1),
                                  kind="stable")[:6]]
        slots = model.slot_person.copy()
        assert sorted(slots[slots >= 0].tolist()) == sorted(nearest.tolist())  # the 6 nearest at the step's start
        assert obs["humans_mask"].sum() == min(6, len(here))
        humans = obs["humans"].reshape(base.scene.history_length, 6, -1)
        for s, person in enumerate(slots.tolist()):
            if person >= 0:
                np.testing.assert_allclose(humans[-1, s, :2], track_pos[k + 1, person], atol=1e-5)
        if previous is not None:  # a person who stays among the nearest keeps its slot
            for s, person in enumerate(previous.tolist()):
                if person >= 0 and person in slots:
                    assert slots[s] == person
                    kept += 1
            changed += int((slots != previous).any())
        previous = slots
        if terminated or truncated:
            break
    assert kept > 0 and changed > 0  # both happened: the test saw slots kept and people coming into view


def test_the_warehouse_refuses_a_replay(street):
    with pytest.raises(ValueError, match=r"crowd.*replay.*open floor"):
        gym.make("CrowdNavWarehouse-v0", crowd="replay", crowd_kwargs={"path": street})


# ---------------------------------------------------------------------- motion and presence
def test_people_come_and_go_in_free_slots_with_a_padded_history(tmp_path):
    """Three people: A from 0 to 2 s, B from 1 to 5 s, C from 3 to 6 s; C takes A's slot after A vanished."""
    rows = ["t,id,x,y"]
    for person, (t0, t1, y) in {"A": (0.0, 2.0, 1.0), "B": (1.0, 5.0, -1.0), "C": (3.0, 6.0, 2.0)}.items():
        for t in np.arange(t0, t1 + 1e-9, 0.5):
            rows.append(f"{t},{person},{t - t0 - 2.0},{y}")  # walking at 1 m/s along x
    path = tmp_path / "three.csv"
    path.write_text("\n".join(rows) + "\n")
    env = CrowdNavEnv(crowd="replay", history_length=3, crowd_kwargs={
        "path": str(path), "robot_start": (0.0, -6.0), "robot_goal": (0.0, -2.0), "start_time": 0.0})
    obs, info = env.reset(seed=0)
    assert info["num_humans"] == 2  # the most present at once
    masks, humans = [obs["humans_mask"][:2].tolist()], [env.schema.humans_view(obs["humans"])]
    for _ in range(26):
        obs, *_ = env.step(8)  # back and forth on the spot (the slowest speed, turning by π)
        masks.append(obs["humans_mask"][:2].tolist())
        humans.append(env.schema.humans_view(obs["humans"]))
        assert env.observation_space.contains(obs)
    by_time = dict(enumerate(masks))
    assert by_time[0] == [1, 0] and by_time[4] == [1, 1] and by_time[8] == [1, 1]  # A (slot 0) and B from 1 s
    assert by_time[9] == [0, 1] and by_time[11] == [0, 1]  # A vanished after 2 s
    assert by_time[12] == [1, 1] and by_time[20] == [1, 1] and by_time[21] == [1, 0]  # C in slot 0 from 3 s
    assert by_time[24] == [1, 0] and by_time[25] == [0, 0]
    gone = humans[10][:, 0]  # A's slot while empty: zeros over the whole window
    assert not gone.any()
    arrived = humans[12][:, 0]  # C at its first step: its state repeated over the window, as at reset
    np.testing.assert_allclose(arrived, np.repeat(arrived[-1:], 3, axis=0))
    np.testing.assert_allclose(arrived[-1], [-2.0, 2.0, 1.0, 0.0, 0.3])  # where it is, walking already
    np.testing.assert_allclose(humans[16][-1, 1], [2.0 - 2.0 + 1.0, -1.0, 1.0, 0.0, 0.3])  # B at 4 s, 3 s in


def test_a_lead_in_brings_people_in_earlier_walking_back_along_their_first_segment(tmp_path):
    """B's first sample is at 1 s: with lead_in=0.5 it is present from 0.5 s, at its first segment's line and velocity,
    and from 1 s on it is where it is without a lead-in; A (from 0 s, the recording's start) cannot come earlier."""
    rows = ["t,id,x,y"]
    for person, (t0, t1, y) in {"A": (0.0, 2.0, 1.0), "B": (1.0, 5.0, -1.0)}.items():
        for t in np.arange(t0, t1 + 1e-9, 0.5):
            rows.append(f"{t},{person},{t - t0 - 2.0},{y}")  # walking at 1 m/s along x
    path = tmp_path / "two.csv"
    path.write_text("\n".join(rows) + "\n")

    def run(lead_in):
        env = CrowdNavEnv(crowd="replay", history_length=3, crowd_kwargs={
            "path": str(path), "robot_start": (0.0, -6.0), "robot_goal": (0.0, -2.0), "start_time": 0.0,
            "lead_in": lead_in})
        obs, _ = env.reset(seed=0)
        out = [(obs["humans_mask"][:2].tolist(), env.sim.history[-1, :2].copy())]
        for _ in range(12):
            obs, *_ = env.step(8)
            out.append((obs["humans_mask"][:2].tolist(), env.sim.history[-1, :2].copy()))
        return out

    plain, early = run(0.0), run(0.5)
    assert [m for m, _ in plain[:5]] == [[1, 0]] * 4 + [[1, 1]]  # B from 1 s (step 4)
    assert [m for m, _ in early[:5]] == [[1, 0]] * 2 + [[1, 1]] * 3  # B from 0.5 s (step 2)
    np.testing.assert_allclose(early[2][1][1], [-2.5, -1.0, 1.0, 0.0, 0.3])  # half a metre back, walking
    for k in range(4, 13):  # from its first sample on, the same people at the same places
        assert early[k][0] == plain[k][0]
        np.testing.assert_allclose(early[k][1], plain[k][1], atol=1e-12)
    settings = early_env = CrowdNavEnv(crowd="replay", crowd_kwargs={
        "path": str(path), "robot_start": (0.0, -6.0), "robot_goal": (0.0, -2.0), "lead_in": 3.0}).scene.crowd_kwargs
    assert settings.recording.max_present(settings.window, settings.lead_in) == 2
    assert early_env.extent == max(settings.recording.extent + 3.0 * settings.recording.max_speed, 6.0)


def test_positions_are_interpolated_and_velocities_are_backward_differences(tmp_path):
    """A person turning: samples every 0.4 s, replayed every 0.25 s. p(t) is the piecewise-linear interpolant and
    v(t) = (p(t) - p(t - Δt)) / Δt; before the first sample p continues along the first segment."""
    times = np.arange(0.0, 30.0, 0.4)
    track = np.stack([np.cos(times / 4.0) * 3.0, np.sin(times / 4.0) * 3.0], axis=-1)
    path = tmp_path / "circle.csv"
    write_recording(path, times, track[:, None])
    env = CrowdNavEnv(crowd="replay", crowd_kwargs={
        "path": str(path), "robot_start": (0.0, -9.0), "robot_goal": (9.0, -9.0), "start_time": 0.1})

    def p(t):
        if t < times[0]:
            return track[0] + (t - times[0]) * (track[1] - track[0]) / 0.4
        return np.array([np.interp(t, times, track[:, 0]), np.interp(t, times, track[:, 1])])

    env.reset(seed=0)
    for k in range(40):
        t = 0.1 + k * 0.25
        state = env.sim.history[-1, 0]
        np.testing.assert_allclose(state[Human.POS], p(t), atol=1e-12)
        np.testing.assert_allclose(state[Human.VEL], (p(t) - p(t - 0.25)) / 0.25, atol=1e-9)
        env.step(8)


# ---------------------------------------------------------------------- the seeded placement
def test_the_placement_rule_crosses_the_busy_part_and_is_seeded(street):
    env = CrowdNavEnv(crowd="replay", crowd_kwargs={"path": street})
    placed = []
    for seed in range(20):
        obs, _ = env.reset(seed=seed)
        sim = env.sim
        start, goal = sim.robot[0:2].copy(), sim.robot[5:7].copy()
        assert np.linalg.norm(goal - start) == pytest.approx(8.0)
        present = sim.history[-1, : sim.num_humans][obs["humans_mask"][: sim.num_humans] > 0]
        gaps = np.linalg.norm(present[:, Human.POS] - start, axis=-1) if len(present) else np.array([np.inf])
        assert gaps.min() >= 0.8 - 1e-9  # two radii + 0.2 m clear of everyone at the start
        placed.append(np.concatenate([start, goal]))
        centre = (start + goal) / 2
        assert abs(centre[1]) < 3.5 and abs(centre[0]) < 8.5  # on the street, where the people walk
    assert len({tuple(np.round(p, 6)) for p in placed}) == 20  # start times and directions drawn per episode


def _episodes(env: gym.Env, seed: int, steps: int = 150) -> list[bytes]:
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    out = [obs["humans"].tobytes() + obs["robot"].tobytes()]
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(int(rng.integers(80)))
        out.append(obs["humans"].tobytes() + obs["humans_mask"].tobytes() + obs["robot"].tobytes()
                   + repr((reward, info["outcome"])).encode())
        if terminated or truncated:
            obs, _ = env.reset()
    return out


def test_same_seed_same_episodes_and_another_seed_others(street):
    def make():
        return gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={"path": street})

    first = _episodes(make(), 3)
    assert first == _episodes(make(), 3)
    assert first != _episodes(make(), 4)


@pytest.mark.parametrize("env_id", ["CrowdNav-v0", "CrowdNavSquare-v0", "CrowdNavComfort-v0"])
def test_a_replay_passes_the_checkers_without_warnings(street, env_id):
    kwargs = {"crowd": "replay", "crowd_kwargs": {"path": street}}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(gym.make(env_id, **kwargs).unwrapped)
        sb3_check_env(gym.make(env_id, **kwargs).unwrapped, warn=True)
        sb3_check_env(gym.make(env_id, **kwargs), warn=True)
    assert not [str(w.message) for w in caught]


def test_a_window_past_the_recording_is_an_empty_floor(tmp_path):
    path = _walkers(tmp_path / "short.csv", n=4, seconds=24.0)
    env = gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={
        "path": path, "robot_start": (-4.0, -6.0), "robot_goal": (4.0, -6.0), "start_time": 20.0})
    env.reset(seed=0)
    for _ in range(40):
        obs, reward, *_, info = env.step(8)
    assert not obs["humans_mask"].any() and not obs["humans"].reshape(5, 10, 5)[-1].any()
    assert info["min_distance"] == env.unwrapped.no_one_distance and math.isfinite(reward)


def test_a_person_who_comes_after_the_robot_left_gives_no_gap(tmp_path):
    """P leaves before the robot starts (at 1 s), Q comes at 20 s and stands; the robot's 8 m are driven long before:
    the window has a person (num_humans 1), no one is present in any step, and the summary's gap leaves it out."""
    rows = ["t,id,x,y", "0.0,P,20.0,-20.0", "0.5,P,20.0,-20.0"]
    rows += [f"{t},Q,20.0,20.0" for t in np.arange(20.0, 40.0 + 1e-9, 0.5)]
    path = tmp_path / "late.csv"
    path.write_text("\n".join(rows) + "\n")
    env = gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={
        "path": path, "robot_start": (-4.0, 0.0), "robot_goal": (4.0, 0.0), "start_time": 1.0})
    record = run_episode(env, OrcaPolicy(), seed=0)
    assert record.outcome == "success" and record.num_humans == 1
    assert record.steps_with_people == 0 and record.min_separation == env.unwrapped.no_one_distance
    assert math.isnan(summarize([record]).min_separation)


def test_the_preparation_script_writes_each_scene_in_the_replay_format(tmp_path, capsys):
    """examples/prepare_recordings.py: OpenTraj's 8-column obsmat files become ``frame id x y`` files the replay reads
    at the scene's frame rate; a person seen once is dropped and named."""
    from example_scripts import load_example

    module = load_example("prepare_recordings")
    root = tmp_path / "OpenTraj"
    for path, _ in module.SCENES.values():
        rows = [(f, 1, 0.5 * f / 6, 0.0, 2.0, 1.0, 0.0, 0.0) for f in range(0, 60, 6)]  # 1.25 m/s at 15 fps ETH-like
        rows += [(f, 2, 3.0, 0.0, -0.1 * f / 6, 0.0, 0.0, -0.5) for f in range(6, 48, 6)]
        rows += [(12, 9, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0)]  # one sample only
        (root / path).parent.mkdir(parents=True, exist_ok=True)
        np.savetxt(root / path, rows)
    for path, _ in module.TRAINING_SCENES.values():  # TrajNet's copies: already frame id x y, every 10th frame
        rows = [(f, 4, 0.04 * f, 1.0) for f in range(0, 100, 10)] + [(20, 5, 2.0, 2.0), (30, 6, 0.0, 0.0)]
        rows += [(40, 6, 0.0, 0.5)]
        (root / path).parent.mkdir(parents=True, exist_ok=True)
        np.savetxt(root / path, rows)
    assert module.main([str(root), str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    assert printed.count("dropped the single-sample person(s) [9]") == len(module.SCENES)
    for name, (_, fps) in module.SCENES.items():
        rec = read_recording(tmp_path / "out" / f"{name}.txt", fps)
        assert rec.max_present() == 2
        np.testing.assert_allclose(rec.positions[0][1] - rec.positions[0][0], [0.5, 0.0])  # x and y, not z
        assert f"--scene {name}=" in printed and f"frame_rate={fps:g},tracked=nearest" in printed
    assert printed.count("dropped the single-sample person(s) [5]") == len(module.TRAINING_SCENES)
    for name, (_, fps) in module.TRAINING_SCENES.items():
        rec = read_recording(tmp_path / "out" / f"{name}.txt", fps)
        assert rec.max_present() == 2 and len(rec.positions) == 2
        np.testing.assert_allclose(rec.positions[0][1] - rec.positions[0][0], [0.4, 0.0])
        assert f"--scene {name}=" not in printed  # for training, not one of the evaluation scenes
        assert f"--recording {tmp_path / 'out' / name}.txt,frame_rate={fps:g}" in printed


def test_the_preparation_script_refuses_a_file_of_other_columns(tmp_path):
    """A TrajNet file that is not four columns (an obsmat put in its place) is refused, naming the file."""
    from example_scripts import load_example

    module = load_example("prepare_recordings")
    bad = tmp_path / "students001.txt"
    np.savetxt(bad, [(0, 1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (10, 1, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0)])
    with pytest.raises(ValueError, match=r"students001\.txt: expected the 4 columns of a frame id x y file, got 8"):
        module.convert(bad, tmp_path / "out.txt", columns=4)
    with pytest.raises(ValueError, match=r"columns must be 8 .* or 4 .*, got 5"):
        module.convert(bad, tmp_path / "out.txt", columns=5)
    assert not (tmp_path / "out.txt").exists()


def _standing_on_the_start(tmp_path: Path) -> Path:
    """P stands on the robot's start (0, 0) from 1 s on (its track starting late, as an annotator's may); seven
    others stand far away from 0 s (eight people at once: more than 6 observed slots, fewer than 10)."""
    rows = ["t,id,x,y"]
    for t in np.arange(0.0, 10.0 + 1e-9, 0.5):
        rows.extend(f"{t},Q{j},{10.0 + j},10.0" for j in range(7))
        if t >= 1.0:
            rows.append(f"{t},P,0.0,0.0")
    path = tmp_path / "standing.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("max_humans", [10, 6], ids=["slots", "tracked nearest"])
def test_appear_clear_holds_back_a_person_who_would_appear_on_the_robot(tmp_path, max_humans):
    """As recorded, P appears on the standing robot at 1 s and that is a collision no policy could avoid. With
    appear="clear" P is held back, absent and unobserved, while the robot stands there, and appears where the
    recording has them in the first step the robot's move does not touch them; then P is observed and counts."""
    path = _standing_on_the_start(tmp_path)

    def make(appear):
        return CrowdNavEnv(crowd="replay", actions="with_stop", max_humans=max_humans, crowd_kwargs={
            "path": str(path), "robot_start": (0.0, 0.0), "robot_goal": (4.0, 0.0), "start_time": 0.0,
            "tracked": "nearest", "appear": appear})

    stop, ahead = 80, 64  # the stop; full speed towards the goal (the robot faces it)
    env = make("as_recorded")
    env.reset(seed=0)
    outcomes = [env.step(stop)[4]["outcome"] for _ in range(4)]
    assert outcomes[-1] == "collision"  # at 1 s (step 4), P appears inside the robot's disc

    env = make("clear")
    env.reset(seed=0)
    seen = []
    for k in range(12):
        _, _, terminated, truncated, info = env.step(stop if k < 6 else ahead)
        assert not terminated and not truncated, info["outcome"]
        people = env.sim.history[-1, env.sim.mask][:, Human.POS]  # the observed people, where they are
        distance = math.hypot(*env.sim.robot[:2])  # the robot from P's spot
        seen.append(bool(np.any(np.hypot(*people.T) < 0.1)))  # P observed
        if distance < 0.6:  # the robot's disc on P's spot: P absent
            assert not seen[-1]
    assert not any(seen[:4]) and seen[-1]  # P absent before 1 s; observed once the robot moved off its spot


def test_appear_is_refused_outside_its_choices(street):
    with pytest.raises(ValueError, match="appear"):
        CrowdNavEnv(crowd="replay", crowd_kwargs={"path": str(street), "appear": "never"})
