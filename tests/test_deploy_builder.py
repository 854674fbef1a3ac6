"""``ObservationBuilder``: the proof (an env's own people and robot, fed as a tracker and odometry, give the env's
observation), the tracker's rules (irregular times, drop-outs, new ids, more people than slots) and every refusal."""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import OrcaPolicy
from sb3_crowdnav.deploy import (
    BuilderError,
    FrameMismatch,
    GraphMetadata,
    MissingInput,
    NonFiniteInput,
    ObservationBuilder,
    TimeOrderError,
    UnknownId,
)
from sb3_crowdnav.sim.observation import Robot
from sb3_crowdnav.sim.recording import write_recording
from sb3_crowdnav.sim.warehouse.config import FULL_SIGHT

# RVO2 integrates in float32: a position differs from the previous one plus Δt x the reported velocity by float32
# rounding (within 8 m: 4.8e-7 m), which the env's velocity rule divides by Δt = 0.25 s; measured up to 1.1e-6 m/s
VELOCITY_TOLERANCE = 4 * float(np.spacing(np.float32(8.0))) / 0.25
FLOAT32 = float(np.spacing(np.float32(16.0)))  # the observation's rounding of a value below 16
OPEN = dict(time_step=0.25, history_length=5, max_humans=3, robot_radius=0.3, robot_v_pref=1.0, human_radius=0.3)


def _odometry(builder: ObservationBuilder, t: float, robot: np.ndarray, frame: str = "odom") -> None:
    builder.odometry(t, *robot[Robot.POS], robot[Robot.HEADING], *robot[Robot.VEL], frame=frame)


def _run(env: gym.Env, seed: int, velocities: bool, steps: int = 40, frame: str = "odom"):
    """Drive ``env`` with the ORCA robot; at each step feed the builder the env's robot and the people the robot sees
    (ids: their slots; positions, and velocities when ``velocities``) at the step's time. Yields the env's and the
    builder's observation and the builder's slots."""
    base = env.unwrapped
    builder = ObservationBuilder.from_env(env, frame=frame)
    policy = OrcaPolicy.from_env(env, mapping="constrained")
    obs, _ = env.reset(seed=seed)
    sim = base.sim
    replans = None
    if base.schema.num_waypoints:
        builder.layout(sim.layout, frame=frame)
    else:
        builder.goal(*sim.robot[Robot.GOAL], frame=frame)
    for k in range(steps):
        t = k * base.scene.time_step
        _odometry(builder, t, sim.robot, frame)
        if base.schema.num_waypoints and sim.replans != replans:  # the robot's planner gives the route it follows
            builder.route(sim.route[sim.route_index:], frame=frame)
            replans = sim.replans
        history, mask = sim.observed()
        columns = slice(0, 4) if velocities else slice(0, 2)
        builder.people(t, [(i, *history[-1, i, columns]) for i in np.flatnonzero(mask)], frame=frame)
        yield obs, builder.observation(t), builder.slots
        obs, _, terminated, truncated, _ = env.step(int(policy.predict(obs)[0]))
        if terminated or truncated:
            return


def _compare(env: gym.Env, expected: dict, got: dict, slots: dict, velocities: bool) -> int:
    """Assert ``got`` is ``expected`` with the env's slot i in the builder's slot ``slots[i]``; the number of history
    states whose velocity differs beyond the tolerance (each a person's first state, 0 in the builder)."""
    schema = env.unwrapped.schema
    assert list(got) == list(expected) and all(a.dtype == np.float32 for a in got.values())
    for key in expected:
        if key not in ("humans", "humans_mask"):
            np.testing.assert_array_equal(got[key], expected[key], err_msg=key)
    ours, theirs = schema.humans_view(got["humans"]), schema.humans_view(expected["humans"])
    assert sorted(slots) == np.flatnonzero(expected["humans_mask"]).tolist()
    assert got["humans_mask"].sum() == len(slots) and all(got["humans_mask"][s] == 1 for s in slots.values())
    assert not ours[:, got["humans_mask"] == 0].any()  # every other slot padded
    first_sight = 0
    for person, s in slots.items():
        np.testing.assert_array_equal(ours[:, s, [0, 1, 4]], theirs[:, person, [0, 1, 4]])
        gap = np.abs(ours[:, s, 2:4] - theirs[:, person, 2:4]).max(axis=-1)
        if velocities:
            assert not gap.any()
        else:
            far = gap > VELOCITY_TOLERANCE
            assert not ours[far, s, 2:4].any()
            first_sight += int(far.sum())
    return first_sight


WORLDS = {
    "open floor": ("CrowdNav-v0", {}, 0),
    "open floor, 3 m range": ("CrowdNav-v0", {"people_sensor_range": 3.0}, 1),
    "warehouse, occlusion": ("CrowdNavWarehouse-v0", {}, 3),
    "warehouse, full sight": ("CrowdNavWarehouse-v0", FULL_SIGHT, 0),
}


@pytest.mark.parametrize("velocities", [True, False], ids=["tracker velocities", "positions only"])
@pytest.mark.parametrize("world", list(WORLDS))
def test_the_envs_own_people_and_robot_give_the_envs_observation(world, velocities):
    env_id, kwargs, seed = WORLDS[world]
    env = gym.make(env_id, **kwargs)
    steps = changes = first_sight = 0
    previous = None
    for expected, got, slots in _run(env, seed, velocities):
        first_sight += _compare(env, expected, got, slots, velocities)
        changes += previous is not None and bool((previous != expected["humans_mask"]).any())
        previous = expected["humans_mask"]
        steps += 1
    assert steps >= 25
    sensing = env.unwrapped.sim.sensor is not None
    assert (changes > 0) == sensing  # the proof saw people hidden and seen again where a sensor hides them
    # positions only: the velocity of a person seen again is the env's true one; the builder's, without a track a
    # whole Δt long, is 0 (as at the env's reset, where everyone is at rest: the open floor's are then equal too)
    assert (first_sight > 0) == (sensing and not velocities)


def test_more_people_than_slots_are_the_nearest_as_replay_tracks_them(tmp_path):
    """A replayed street with ``tracked="nearest"`` (the rule the models were evaluated with on recorded crowds): the
    builder fed with everyone present (ids: their recording columns) fills the same slots with the same histories."""
    rng = np.random.default_rng(0)
    times = np.arange(0.0, 40.0, 0.4)
    positions = np.zeros((len(times), 24, 2))
    present = np.zeros((len(times), 24), dtype=bool)
    for j in range(24):
        a = int(rng.integers(0, len(times) - 50))
        side = 1.0 if j % 2 else -1.0
        t = times[a:a + 40] - times[a]
        positions[a:a + 40, j] = np.stack([-8 * side + side * rng.uniform(1.0, 1.6) * t, rng.uniform(-3, 3) + 0 * t], -1)
        present[a:a + 40, j] = True
    write_recording(tmp_path / "street.csv", times, positions, present)
    env = gym.make("CrowdNav-v0", crowd="replay", max_humans=6, time_limit=10.0,
                   crowd_kwargs={"path": tmp_path / "street.csv", "start_time": 10.0, "tracked": "nearest"})
    obs, _ = env.reset(seed=0)
    sim, model = env.unwrapped.sim, env.unwrapped.sim.crowd
    builder = ObservationBuilder.from_env(env)
    builder.goal(*sim.robot[Robot.GOAL], frame="odom")
    pos, vel, here = model.tracks
    held = set()
    for k in range(40):
        t = k * sim.scene.time_step
        _odometry(builder, t, sim.robot)
        builder.people(t, [(j, *pos[k, j], *vel[k, j]) for j in np.flatnonzero(here[k])], frame="odom")
        got = builder.observation(t)
        assert builder.slots == {p: s for s, p in enumerate(model.slot_person.tolist()) if p >= 0}
        for key in obs:
            np.testing.assert_array_equal(got[key], obs[key], err_msg=f"{key} at step {k}")
        held |= set(builder.slots)
        obs, *_ = env.step(64)
    assert here[:40].sum(axis=1).max() > 6 and len(held) > 6  # more people than slots, and people came and went


# ---------------------------------------------------------------------- the tracker's rules
def _builder(**kwargs) -> ObservationBuilder:
    builder = ObservationBuilder(**{**OPEN, **kwargs})
    builder.goal(5.0, 0.0, frame="odom")
    return builder


def _decide(builder: ObservationBuilder, t: float) -> np.ndarray:
    """The history (T, M, 5) of a decision at t, the robot standing at the origin."""
    builder.odometry(t, 0.0, 0.0, 0.0, 0.0, 0.0, frame="odom")
    return builder.schema.humans_view(builder.observation(t)["humans"])


def _interp(times: np.ndarray, points: np.ndarray, at: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(at, times, points[:, 0]), np.interp(at, times, points[:, 1])], axis=-1)


@settings(max_examples=20, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=45, max_size=45), st.floats(0.0, 0.2))
def test_irregular_detections_give_the_interpolated_history(jitter, offset):
    """A person on a curve detected every 0.06-0.15 s, decisions every Δt between detections (the tracker's frame
    just after each): the history is the detections interpolated to the grid, the velocities their differences
    over Δt, and before the person's first decision their state then (a new history, as at the env's reset)."""
    builder = _builder(staleness=0.2, max_gap=0.5)
    times = np.cumsum(0.105 + 0.045 * np.array(jitter))
    path = np.stack([0.8 * times + 0.1 * times**2, 2.0 * np.sin(times)], axis=-1)
    fed = 0
    first = None
    for decision in 1.0 + offset + 0.25 * np.arange(6):
        while times[fed] <= decision:
            builder.people(float(times[fed]), [("walker", *path[fed])], frame="odom")
            fed += 1
        builder.people(float(times[fed]), [("walker", *path[fed])], frame="odom")  # a frame just after t
        fed += 1
        history = _decide(builder, float(decision))
        first = decision if first is None else first
        grid = np.maximum(decision - 0.25 * np.arange(4, -1, -1), first)
        np.testing.assert_allclose(history[:, 0, :2], _interp(times, path, grid), rtol=0, atol=FLOAT32)
        velocity = (_interp(times, path, grid) - _interp(times, path, grid - 0.25)) / 0.25
        np.testing.assert_allclose(history[:, 0, 2:4], velocity, rtol=0, atol=FLOAT32)


def test_past_the_newest_detection_a_person_walks_on_at_the_last_velocity():
    builder = _builder()
    velocity = np.array([0.7, -0.4])
    for k in range(12):
        builder.people(0.1 * k, [(1, *(velocity * 0.1 * k))], frame="odom")
    history = _decide(builder, 1.15)  # 0.05 s after the newest detection, within the staleness (0.125 s)
    np.testing.assert_allclose(history[-1, 0, :4], [*(velocity * 1.15), *velocity], rtol=0, atol=FLOAT32)
    assert (history[:, 0] == history[-1, 0]).all()  # the first decision: a new history


def test_a_person_gone_is_padded_and_seen_again_starts_a_new_history():
    builder = _builder()
    walk = lambda t: (1, 2.0 - 0.5 * t, 1.0)  # noqa: E731
    for k in range(4):  # seen at 0, 0.25, 0.5, 0.75
        builder.people(0.25 * k, [walk(0.25 * k)], frame="odom")
        history = _decide(builder, 0.25 * k)
    np.testing.assert_allclose(history[-2:, 0, :4], [[1.75, 1.0, -0.5, 0.0], [1.625, 1.0, -0.5, 0.0]], atol=FLOAT32)
    np.testing.assert_array_equal(history[:2, 0, :4], [[2.0, 1.0, 0.0, 0.0]] * 2)  # the first state, at rest
    builder.people(1.0, [], frame="odom")  # not detected: gone at 1.0 (its newest detection is 0.25 s old)
    gone = _decide(builder, 1.0)
    assert not gone.any() and builder.slots == {}
    for k in (5, 6):  # seen again: a new history, its velocity from detections a whole Δt back only
        builder.people(0.25 * k, [walk(0.25 * k)], frame="odom")
        history = _decide(builder, 0.25 * k)
    np.testing.assert_allclose(history[-1, 0, :4], [1.25, 1.0, -0.5, 0.0], atol=FLOAT32)
    np.testing.assert_array_equal(history[:-1, 0, :4], [[1.375, 1.0, 0.0, 0.0]] * 4)


def test_a_gap_longer_than_max_gap_starts_a_new_track():
    builder = _builder(staleness=1.0, max_gap=0.3)
    builder.people(0.0, [(1, 0.0, 0.0)], frame="odom")
    builder.people(0.5, [(1, 1.0, 0.0)], frame="odom")  # 0.5 s after the previous detection
    history = _decide(builder, 0.5)
    np.testing.assert_array_equal(history[:, 0, :4], [[1.0, 0.0, 0.0, 0.0]] * 5)  # not 2 m/s from the old track


def test_new_people_take_the_lowest_free_slots_and_keep_them():
    builder = _builder()
    builder.people(0.0, [("a", 1.0, 0.0), ("b", 2.0, 0.0)], frame="odom")
    _decide(builder, 0.0)
    assert builder.slots == {"a": 0, "b": 1}
    builder.people(0.25, [("b", 2.0, 0.1), ("c", 3.0, 0.0), ("d", 4.0, 0.0)], frame="odom")  # a gone; c, d new
    history = _decide(builder, 0.25)
    assert builder.slots == {"b": 1, "c": 0, "d": 2}  # in the order their tracks began
    np.testing.assert_array_equal(history[-1, :, :2], np.float32([[3.0, 0.0], [2.0, 0.1], [4.0, 0.0]]))


def test_with_more_people_than_slots_the_nearest_to_the_robot_a_step_before_take_them():
    builder = _builder(max_humans=2)
    builder.odometry(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, frame="odom")
    builder.odometry(0.25, 5.0, 0.0, 0.0, 0.0, 0.0, frame="odom")  # the robot moved to (5, 0) by the decision
    people = [("far", 3.0, 0.0), ("near", 1.0, 0.0), ("mid", 2.0, 0.0), ("here", 5.0, 0.5)]
    builder.people(0.0, people, frame="odom")
    builder.people(0.25, people, frame="odom")
    builder.observation(0.25)
    assert builder.slots == {"near": 0, "mid": 1}  # ranked from (0, 0), where the robot was one Δt before
    builder.odometry(0.5, 5.0, 0.0, 0.0, 0.0, 0.0, frame="odom")
    builder.people(0.5, people, frame="odom")
    builder.observation(0.5)
    assert builder.slots == {"here": 0, "far": 1}  # from (5, 0) now: "here" enters nearest first


def test_the_robot_row_is_the_odometry_at_t_the_goal_and_the_contract():
    builder = _builder(robot_radius=0.4, robot_v_pref=1.2)
    builder.people(0.0, [], frame="odom")
    builder.odometry(0.0, 1.0, 2.0, 3.0, 0.5, 0.0, frame="odom")
    builder.odometry(0.2, 1.1, 2.0, 3 * math.pi / 2, 0.5, 0.2, frame="odom")  # -π/2 once wrapped
    robot = builder.observation(0.1)["robot"]  # between the samples: the heading along the shorter arc, past ±π
    expected = [1.05, 2.0, 0.5, 0.1, 0.4, 5.0, 0.0, 1.2, 3.0 + (3 * math.pi / 2 - 3.0) / 2 - 2 * math.pi]
    np.testing.assert_allclose(robot, np.float32(expected), rtol=0, atol=FLOAT32)
    builder.people(0.25, [], frame="odom")
    robot = builder.observation(0.25)["robot"]  # 0.05 s past the newest sample: along its velocity
    np.testing.assert_allclose(robot[:4], np.float32([1.125, 2.01, 0.5, 0.2]), rtol=0, atol=FLOAT32)
    assert robot[Robot.HEADING] == np.float32(-math.pi / 2)


# ---------------------------------------------------------------------- the world it serves
@pytest.mark.parametrize(("env_id", "kwargs"), [("CrowdNav-v0", {"max_humans": 7, "history_length": 3}),
                                                ("CrowdNavWarehouse-v0", {"waypoint_radius": 0.8})])
def test_a_graphs_contract_gives_the_envs_builder(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    base = env.unwrapped
    meta = GraphMetadata(kind="q_values", world=base.world, schema=base.schema, robot_radius=base.scene.robot_radius,
                         robot_v_pref=base.scene.robot_v_pref, policy="DQN", extractor="ApgExtractor")
    assert ObservationBuilder.from_policy(meta).settings == ObservationBuilder.from_env(env).settings
    with pytest.raises(TypeError, match="unknown keyword"):
        ObservationBuilder.from_env(env, time_step=0.1)  # the world's settings are the env's


def test_a_layout_file_and_a_route_give_the_warehouses_static_part(tmp_path):
    env = gym.make("CrowdNavWarehouse-v0", **FULL_SIGHT)
    obs, _ = env.reset(seed=5)
    sim = env.unwrapped.sim
    path = tmp_path / "layout.json"
    path.write_text(json.dumps(sim.layout.to_dict()))
    builder = ObservationBuilder.from_env(env, frame="map")
    builder.layout(str(path), frame="map")
    builder.route(sim.route[sim.route_index:], frame="map")
    _odometry(builder, 0.0, sim.robot, "map")
    builder.people(0.0, [], frame="map")
    got = builder.observation(0.0)
    for key in ("robot", "obstacles", "obstacles_mask", "waypoints"):
        np.testing.assert_array_equal(got[key], obs[key])
    waypoint = sim.route[sim.route_index]  # the robot reaches its current waypoint: it is dropped
    builder.odometry(0.25, *waypoint, 0.0, 0.0, 0.0, frame="map")
    builder.people(0.25, [], frame="map")
    rest = np.concatenate([sim.route[sim.route_index + 1:], np.repeat(sim.route[-1:], 3, axis=0)])[:3]
    np.testing.assert_array_equal(builder.observation(0.25)["waypoints"], rest.astype(np.float32).ravel())


# ---------------------------------------------------------------------- refusals
def _ready() -> ObservationBuilder:
    builder = _builder(ids=[1, 2, "x"])
    builder.odometry(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, frame="odom")
    builder.people(0.0, [(1, 1.0, 1.0)], frame="odom")
    builder.observation(0.0)
    return builder


BAD_INPUTS = {
    "people before the previous frame": (lambda b: b.people(-0.1, [], frame="odom"), TimeOrderError, "people: t="),
    "people at the previous frame's time": (lambda b: b.people(0.0, [], frame="odom"), TimeOrderError, "not after"),
    "odometry going back": (lambda b: b.odometry(0.0, 0, 0, 0, 0, 0, frame="odom"), TimeOrderError, "odometry"),
    "an observation going back": (lambda b: b.observation(-0.25), TimeOrderError, "observation"),
    "NaN x": (lambda b: b.people(0.1, [(1, math.nan, 0.0)], frame="odom"), NonFiniteInput, "x of id 1"),
    "infinite vx": (lambda b: b.people(0.1, [(1, 0.0, 0.0, math.inf, 0.0)], frame="odom"), NonFiniteInput, "vx"),
    "NaN time": (lambda b: b.people(math.nan, [], frame="odom"), NonFiniteInput, "people: t"),
    "NaN heading": (lambda b: b.odometry(0.1, 0, 0, math.nan, 0, 0, frame="odom"), NonFiniteInput, "heading"),
    "infinite goal": (lambda b: b.goal(math.inf, 0.0, frame="odom"), NonFiniteInput, "goal: x"),
    "NaN decision time": (lambda b: b.observation(math.nan), NonFiniteInput, "observation: t"),
    "an undeclared id": (lambda b: b.people(0.1, [(3, 0.0, 0.0)], frame="odom"), UnknownId, "id 3"),
    "people in another frame": (lambda b: b.people(0.1, [], frame="map"), FrameMismatch, "people.*'map'.*'odom'"),
    "odometry in another frame": (lambda b: b.odometry(0.1, 0, 0, 0, 0, 0, frame="base_link"), FrameMismatch,
                                  "odometry"),
    "a goal in another frame": (lambda b: b.goal(1.0, 1.0, frame="map"), FrameMismatch, "goal"),
    "a detection of 4 values": (lambda b: b.people(0.1, [(1, 0.0, 0.0, 1.0)], frame="odom"), BuilderError,
                                r"\(id, x, y\)"),
    "an id twice": (lambda b: b.people(0.1, [(1, 0.0, 0.0), (1, 1.0, 0.0)], frame="odom"), BuilderError, "twice"),
    "velocities from a tracker that gave none": (lambda b: b.people(0.1, [(1, 0.0, 0.0, 1.0, 0.0)], frame="odom"),
                                                 BuilderError, "same form"),
    "a layout on the open floor": (lambda b: b.layout("hall.json", frame="odom"), BuilderError, "max_obstacles=0"),
    "a route on the open floor": (lambda b: b.route([(1.0, 1.0)], frame="odom"), BuilderError, "num_waypoints=0"),
    "stale odometry": (lambda b: (b.people(0.5, [], frame="odom"), b.observation(0.5)), MissingInput,
                       "newest odometry"),
    "a silent tracker": (lambda b: (b.odometry(0.5, 0, 0, 0, 0, 0, frame="odom"), b.observation(0.5)), MissingInput,
                         "silent tracker"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_every_bad_input_raises_its_named_error_and_changes_nothing(case):
    call, error, message = BAD_INPUTS[case]
    builder = _ready()
    with pytest.raises(error, match=message):
        call(builder)
    assert issubclass(error, BuilderError) and issubclass(error, ValueError)
    builder.odometry(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, frame="odom")  # the builder goes on as before
    builder.people(1.0, [(1, 1.0, 1.0)], frame="odom")
    assert builder.observation(1.0)["humans_mask"][0] == 1


def test_an_observation_before_its_inputs_is_refused_naming_them():
    builder = ObservationBuilder(**OPEN)
    with pytest.raises(MissingInput, match="goal"):
        builder.observation(0.0)
    builder.goal(1.0, 1.0, frame="odom")
    with pytest.raises(MissingInput, match="no odometry"):
        builder.observation(0.0)
    builder.odometry(0.1, 0.0, 0.0, 0.0, 0.0, 0.0, frame="odom")
    with pytest.raises(MissingInput, match=r"first odometry is at 0\.1"):
        builder.observation(0.0)
    with pytest.raises(MissingInput, match="no people frame"):
        builder.observation(0.1)
    warehouse = ObservationBuilder(**OPEN, max_obstacles=4, num_waypoints=2, sensor_range=4.0, waypoint_radius=0.6)
    warehouse.route([(1.0, 1.0)], frame="odom")
    warehouse.odometry(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, frame="odom")
    warehouse.people(0.0, [], frame="odom")
    with pytest.raises(MissingInput, match="layout"):
        warehouse.observation(0.0)
    with pytest.raises(BuilderError, match="route"):
        warehouse.goal(1.0, 1.0, frame="odom")


@pytest.mark.parametrize(("kwargs", "error", "message"), [
    ({"time_step": 0.0}, ValueError, "time_step"),
    ({"time_step": "0.25"}, TypeError, "time_step"),
    ({"history_length": 2.0}, TypeError, "history_length"),
    ({"max_humans": 0}, ValueError, "max_humans"),
    ({"human_radius": math.nan}, ValueError, "human_radius"),
    ({"staleness": -0.1}, ValueError, "staleness"),
    ({"max_gap": 0.0}, ValueError, "max_gap"),
    ({"frame": ""}, TypeError, "frame"),
    ({"ids": "abc"}, TypeError, "ids"),
    ({"ids": [1, 2.5]}, TypeError, "person id"),
    ({"max_obstacles": 16}, ValueError, "num_waypoints"),
    ({"sensor_range": 4.0}, ValueError, "sensor_range"),
    ({"max_obstacles": 4, "num_waypoints": 2, "waypoint_radius": 0.6}, TypeError, "sensor_range"),
    ({"colour": "red"}, TypeError, "colour"),
])
def test_bad_settings_are_refused_at_construction(kwargs, error, message):
    with pytest.raises(error, match=message):
        ObservationBuilder(**{**OPEN, **kwargs})


def test_a_person_id_must_be_an_int_or_a_str():
    builder = _builder()
    for bad in (1.0, True, None):
        with pytest.raises(TypeError, match="person id"):
            builder.people(0.0, [(bad, 0.0, 0.0)], frame="odom")
