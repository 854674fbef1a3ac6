"""The protective field: a wrapper around any policy that caps the robot's speed while a person is inside the field."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import OrcaPolicy
from sb3_crowdnav.cli import main
from sb3_crowdnav.evaluation.runner import run_episodes
from sb3_crowdnav.safety import ProtectedPolicy, ProtectiveField
from sb3_crowdnav.sim.actions import N_DIRECTIONS, STOP_ACTION, action_table
from sb3_crowdnav.sim.observation import Robot


class Fixed:
    """A policy that always answers ``action``."""

    def __init__(self, action: int) -> None:
        self.action = action

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.int64(self.action), state


def _obs(env, person: tuple[float, float] | None, seen: bool = True) -> dict[str, np.ndarray]:
    """An observation of ``env`` with the robot at the origin heading +x and one person at ``person``."""
    obs = {k: np.zeros(v.shape, dtype=np.float32) for k, v in env.observation_space.spaces.items()}
    obs["robot"][Robot.RADIUS], obs["robot"][Robot.V_PREF] = 0.3, 1.0
    if person is not None:
        humans = env.unwrapped.schema.humans_view(obs["humans"])
        humans[:, 0] = (*person, 0.0, 0.0, 0.3)
        obs["humans_mask"][0] = float(seen)
    return obs


@pytest.mark.parametrize(("cap", "actions", "expected_speed"), [
    (0.5, "paper", 0.4), (0.3, "paper", 0.2), (1.0, "paper", 1.0), (0.1, "with_stop", 0.0), (0.0, "with_stop", 0.0),
])
def test_a_person_inside_caps_every_action_to_the_fastest_of_its_direction_at_or_below_the_cap(cap, actions,
                                                                                           expected_speed):
    env = gym.make("CrowdNav-v0", actions=actions)
    speeds, directions = action_table(1.0, 2 * math.pi, actions)
    inside = _obs(env, (0.3 + 0.3 + 0.4, 0.0))  # 0.4 m from the robot's disc
    for a in range(len(speeds)):
        protected = ProtectedPolicy(Fixed(a), ProtectiveField(0.5, cap), env)
        b = int(protected.predict(inside)[0])
        assert speeds[b] == pytest.approx(min(speeds[a], expected_speed) if speeds[a] > cap else speeds[a])
        if b != STOP_ACTION:
            assert b % N_DIRECTIONS == a % N_DIRECTIONS  # the same direction
        assert directions[b] == directions[a] or b == STOP_ACTION
        assert protected.capped == int(b != a)


@pytest.mark.parametrize(("person", "seen", "field", "capped"), [
    ((1.0, 0.0), True, ProtectiveField(0.5, 0.2), True),  # 0.4 m away: inside
    ((1.2, 0.0), True, ProtectiveField(0.5, 0.2), False),  # 0.6 m away: outside
    ((1.0, 0.0), False, ProtectiveField(0.5, 0.2), False),  # inside but not observed (behind a rack): the field is blind
    ((-1.0, 0.0), True, ProtectiveField(0.5, 0.2, math.pi / 2), False),  # behind a front field
    ((0.0, 1.0), True, ProtectiveField(0.5, 0.2, math.pi / 2), True),  # at its edge: the disc reaches into it
    ((-1.0, 0.0), True, ProtectiveField(0.5, 0.2), True),  # behind, all around
    (None, True, ProtectiveField(0.5, 0.2), False),  # no one
])
def test_who_is_inside_the_field(person, seen, field, capped):
    env = gym.make("CrowdNav-v0")
    protected = ProtectedPolicy(Fixed(79), field, env)  # full speed
    assert (int(protected.predict(_obs(env, person, seen))[0]) != 79) == capped


def test_batches_are_capped_row_by_row():
    env = gym.make("CrowdNav-v0")
    rows = [_obs(env, (1.0, 0.0)), _obs(env, (3.0, 0.0))]
    batch = {k: np.stack([r[k] for r in rows]) for k in rows[0]}

    class Batch:
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            return np.array([79, 79]), state

    actions, _ = ProtectedPolicy(Batch(), ProtectiveField(0.5, 0.2), env).predict(batch)
    assert actions[0] != 79 and actions[1] == 79


def test_behind_the_field_the_robot_never_drives_faster_than_the_cap_near_people():
    """The ORCA robot (the paper's robot: a command is reached at once) behind a 1 m field capped at 0.4 m/s: every
    step that starts with someone observed inside the field ends at or below 0.4 m/s, and the field acted."""
    env = gym.make("CrowdNav-v0", num_humans=10)
    field = ProtectiveField(1.0, 0.4)
    protected = ProtectedPolicy(OrcaPolicy.from_env(env), field, env)
    checked = 0
    for seed in range(5):
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            inside = bool(protected.inside(obs)[0])
            action, _ = protected.predict(obs)
            obs, _, terminated, truncated, _ = env.step(int(action))
            done = terminated or truncated
            if inside:
                assert np.hypot(*obs["robot"][Robot.VEL]) <= 0.4 + 1e-6
                checked += 1
    assert checked > 0 and protected.capped > 0


def test_the_runner_wraps_every_policy_and_the_field_changes_the_episodes():
    plain = run_episodes("orca", 3, {"num_humans": 10})
    fielded = run_episodes("orca", 3, {"num_humans": 10}, protective_field=ProtectiveField(1.0, 0.2))
    assert [r.navigation_time for r in plain] != [r.navigation_time for r in fielded]


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    ({"distance": 0.0}, ValueError, "distance must be > 0"),
    ({"distance": -1.0}, ValueError, "distance must be > 0"),
    ({"speed_cap": -0.1}, ValueError, "speed_cap must be >= 0"),
    ({"half_angle": 0.0}, ValueError, "half_angle must be > 0"),
    ({"half_angle": 4.0}, ValueError, "half_angle must be <= "),
    ({"distance": "1"}, TypeError, "distance must be a real number"),
])
def test_infeasible_fields_are_refused_at_construction(kwargs, error, match):
    with pytest.raises(error, match=match):
        ProtectiveField(**kwargs)


def test_a_cap_no_action_can_follow_is_refused_and_the_cli_answers_bad_fields_with_exit_2(capsys):
    with pytest.raises(ValueError, match=r"speed_cap: 0\.1 m/s is below the slowest action.s 0\.2 m/s"):
        ProtectedPolicy(Fixed(0), ProtectiveField(0.5, 0.1), gym.make("CrowdNav-v0"))
    ProtectedPolicy(Fixed(0), ProtectiveField(0.5, 0.1), gym.make("CrowdNav-v0", actions="with_stop"))  # the stop
    for bad in ("0.5", "0.5,x", "-1,0.3", "0.5,0.3,0"):
        with pytest.raises(SystemExit) as exc:
            main(["evaluate", "--policy", "orca", "--episodes", "1", "--protective-field", bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "--protective-field" in err and len(err.strip().splitlines()) == 1


def test_benchmark_sweep_runs_behind_the_field_too(tmp_path, monkeypatch):
    """--protective-field reaches every run of benchmark, its --sweep included."""
    from sb3_crowdnav.evaluation import runner

    seen = {}
    real = runner.run_sweep

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(runner, "run_sweep", spy)
    assert main(["benchmark", "--policy", "orca", "--episodes", "1", "--sweep", "2", "--no-gif", "--no-progress",
                 "--protective-field", "0.5,0.3", "--out", str(tmp_path / "b")]) == 0
    assert str(seen["protective_field"]) == str(ProtectiveField.parse("0.5,0.3"))
