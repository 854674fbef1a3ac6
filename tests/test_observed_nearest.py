"""``observed="nearest"``: more people than the observation holds; the robot observes the nearest it sees."""

from __future__ import annotations

import itertools
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from hypothesis import given
from hypothesis import strategies as st

import sb3_crowdnav
from sb3_crowdnav.evaluation.episode_log import EpisodeRecorder
from sb3_crowdnav.evaluation.runner import run_episode
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.recording import write_recording
from sb3_crowdnav.sim.sensing import assign_slots

DENSE = {"num_humans": 14, "max_humans": 6, "observed": "nearest"}


def _frames(steps: int = 200, seed: int = 3, **kwargs):
    """(observation, true positions (n, 2), robot position, sensor slots, whether a reset gave it) after the reset and
    every step of the same random actions (episodes restart within)."""
    env = gym.make("CrowdNav-v0", **kwargs)
    sim = env.unwrapped.sim

    def frame(obs, reset):
        return obs, sim.history[-1, : sim.num_humans, :2].copy(), sim.robot[:2].copy(), sim.sensor.people.copy(), reset

    out = [frame(env.reset(seed=seed)[0], True)]
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        obs, _, terminated, truncated, _ = env.step(int(rng.integers(80)))
        out.append(frame(obs, False))
        if terminated or truncated:
            out.append(frame(env.reset()[0], True))
    return out


def _newest(obs: dict, slots: int, history: int = 5) -> tuple[np.ndarray, np.ndarray]:
    humans = obs["humans"].reshape(history, slots, -1).astype(np.float64)
    return humans, obs["humans_mask"] > 0.5


def _same_set(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.array(sorted(map(tuple, a))), np.array(sorted(map(tuple, b)))
    return a.shape == b.shape and np.allclose(a, b, atol=1e-5)


@pytest.mark.parametrize(("sensor_range", "slots"), [(None, 6), (3.0, 3)])
def test_the_observation_holds_the_nearest_people_the_sensor_sees(sensor_range, slots):
    frames = _frames(num_humans=14, max_humans=slots, observed="nearest", people_sensor_range=sensor_range)
    crowded = 0
    for obs, people, robot, _, _ in frames:
        humans, mask = _newest(obs, slots)
        surface = np.hypot(*(people - robot).T) - 0.3
        seen = np.flatnonzero(surface <= sensor_range) if sensor_range is not None else np.arange(len(people))
        nearest = seen[np.argsort(np.hypot(*(people[seen] - robot).T), kind="stable")[:slots]]
        assert _same_set(humans[-1, mask, :2], people[nearest])
        crowded += len(seen) > slots
    assert crowded > 20  # the rule was tested with more people in sight than slots


def test_a_person_keeps_their_slot_and_a_newcomer_starts_a_new_history():
    frames = _frames(**DENSE)
    kept = entered = 0
    for (o0, _, _, slots0, _), (o1, people1, _, slots1, reset) in itertools.pairwise(frames):
        h0, m0 = _newest(o0, 6)
        h1, m1 = _newest(o1, 6)
        for j in np.flatnonzero(m1):
            assert np.allclose(h1[-1, j, :2], people1[slots1[j]], atol=1e-5)  # slot j shows the person it names
            if not reset and m0[j] and slots0[j] == slots1[j]:  # the same person: the window shifts by one step
                np.testing.assert_array_equal(h1[:-1, j], h0[1:, j])
                kept += 1
            else:  # a newcomer, one seen again or a new episode: their state repeated over the window
                assert (h1[:, j] == h1[-1, j]).all()
                entered += not reset
    assert kept > 100 and entered > 10


def test_everyone_walks_and_collisions_count_with_people_not_observed():
    # (with a latency the person closest now is at times not among the two observed: sensed as they were 3 steps ago)
    env = gym.make("CrowdNav-v0", num_humans=14, max_humans=2, observed="nearest", people_sensor_latency=3)
    sim = env.unwrapped.sim
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    walked, collisions, episodes, unobserved_closest = np.zeros(14), 0, 0, 0
    for _ in range(400):
        before = sim.history[-1, : sim.num_humans, :2].copy()
        _, _, terminated, truncated, info = env.step(int(rng.integers(80)))
        after = sim.history[-1, : sim.num_humans, :2]
        assert sim.num_humans == 14 and sim.mask[:14].all() and sim.seen_people.sum() <= 2
        walked += np.hypot(*(after - before).T)
        surface = np.hypot(*(after - sim.robot[:2]).T) - 0.6
        assert info["min_distance"] <= surface.min() + 1e-9  # against everyone (the step's sweep can be closer)
        unobserved_closest += not sim.seen_people[int(np.argmin(surface))]
        if terminated or truncated:
            collisions += info["outcome"] == "collision"
            episodes += 1
            env.reset()
    assert (walked > 1.0).all()  # the people beyond the two slots walk as the others do
    assert 0 < collisions < episodes and unobserved_closest > 0
def test_with_room_for_everyone_the_slots_only_reorder_the_people():
    for obs, people, _, _, _ in _frames(steps=80, num_humans=6, observed="nearest"):
        humans, mask = _newest(obs, 10)
        assert mask.sum() == 6 and _same_set(humans[-1, mask, :2], people)


def test_latency_delivers_the_nearest_as_sensed_then():
    """The sensor moves no one: with a latency of L steps the episodes are the same, and the observation at step k
    holds the people the undelayed one held at step k - L (as sensed at the reset during an episode's first L)."""
    lag = 2
    late, now = _frames(steps=120, **DENSE, people_sensor_latency=lag), _frames(steps=120, **DENSE)
    started = 0
    compared = 0
    for k, ((o_late, people, robot, _, reset), (_, people_now, robot_now, _, _)) in enumerate(zip(late, now, strict=True)):
        np.testing.assert_array_equal(people, people_now)
        np.testing.assert_array_equal(robot, robot_now)
        started = k if reset else started
        humans, mask = _newest(o_late, 6)
        then, then_mask = _newest(now[max(k - lag, started)][0], 6)
        assert _same_set(humans[-1, mask, :2], then[-1, then_mask, :2])
        compared += k - lag > started
    assert compared > 50


def test_the_same_seed_gives_the_same_episode_and_the_checkers_pass():
    first, second = _frames(steps=60, **DENSE), _frames(steps=60, **DENSE)
    for (o1, *_), (o2, *_) in zip(first, second, strict=True):
        assert all(np.array_equal(o1[k], o2[k]) for k in o1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(gym.make("CrowdNav-v0", **DENSE).unwrapped)
    assert not caught, [str(w.message) for w in caught]


def test_a_model_trained_with_ten_slots_acts_among_more_people():
    model = sb3_crowdnav.pretrained("apg_robust")
    env = EpisodeRecorder(gym.make("CrowdNav-v0", num_humans=14, max_humans=10, observed="nearest",
                                         actions="with_stop"))
    record = run_episode(env, model, 7, keep_trajectory=True)
    log = env.log(record.trajectory)
    assert log.seen.shape[1] == 14 and log.seen.sum(axis=1).max() == 10  # per person, never more than the slots
    assert record.outcome in ("success", "collision", "timeout")


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"num_humans": 14}, "unless observed='nearest'"),
    ({"num_humans": (2, 12)}, "unless observed='nearest'"),
    ({"observed": "closest"}, r"observed must be one of \('all', 'nearest'\)"),
    ({"observed": "nearest", "num_humans": 17}, "cannot be placed reliably"),
    ({"observed": "nearest", "num_humans": 120, "circle_radius": 100.0}, "num_humans must be <= 100"),
])
def test_infeasible_settings_are_refused_at_construction(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("CrowdNav-v0", **kwargs)


def test_the_warehouse_and_a_recording_refuse_it(tmp_path):
    with pytest.raises(ValueError, match="observed='nearest' is the open floor's"):
        gym.make("CrowdNavWarehouse-v0", observed="nearest")
    path = tmp_path / "walk.csv"
    times = np.arange(0.0, 40.0, 0.4)
    write_recording(path, times, np.stack([np.stack([times * 0.2 - 4, np.full_like(times, k)], -1) for k in range(3)], 1))
    with pytest.raises(ValueError, match=r"observed must stay 'all' with crowd='replay'.*tracked"):
        SceneConfig(crowd="replay", crowd_kwargs={"path": str(path)}, observed="nearest")


@given(st.integers(1, 8).flatmap(lambda m: st.tuples(
    st.permutations(list(range(12))).map(lambda p, m=m: p[:m]),
    st.lists(st.booleans(), min_size=m, max_size=m),
    st.permutations(list(range(12))),
    st.integers(0, m))))
def test_assign_slots_keeps_people_in_their_slots_and_fills_the_lowest_free(case):
    people, occupied, order, count = case
    slots = [p if o else -1 for p, o in zip(people, occupied, strict=True)]
    chosen = list(order[:count])
    new, entered = assign_slots(slots, chosen)
    assert len(new) == len(slots) and sorted(p for p in new if p >= 0) == sorted(chosen)
    for s, p in enumerate(slots):
        if p in chosen:
            assert new[s] == p  # kept
    newcomers = [p for p in chosen if p not in slots]
    free = [s for s, p in enumerate(slots) if p not in chosen]
    assert entered == free[: len(newcomers)] and [new[s] for s in entered] == newcomers
