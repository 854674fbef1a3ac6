"""The ``CrowdNav-v0`` family: checkers, registration, determinism, info, episode end and rendering."""

import importlib
import math
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_crowdnav
from sb3_crowdnav import ENV_IDS, CrowdNavEnv
from sb3_crowdnav.sim.observation import Human, Robot

REWARD_KEYS = ("reward_success", "reward_collision", "reward_discomfort", "reward_social", "reward_angular")
STATS_KEYS = ("outcome", "navigation_time", "path_length", "min_separation", "discomfort_frequency",
              "comfort_zone_time", "heading_change", "discounted_return", "num_humans", "steps_with_people",
              "discomfort_separation", "comfort_zone_separation", "sharp_turns",
              # the safety figures
              "min_time_to_collision", "near_misses", "steps_near_people", "speed_near_people", "peak_acceleration",
              "peak_turn_rate")


@pytest.mark.parametrize("env_id", sorted(ENV_IDS))
def test_checkers_pass_without_warnings(env_id):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(env_id)
        gym_check_env(env.unwrapped)  # also builds every render mode from the spec
        sb3_check_env(env.unwrapped, warn=True)
        sb3_check_env(gym.make(env_id), warn=True)
        env.close()
    assert [str(w.message) for w in caught] == []


def test_registered_ids_build_the_documented_variants():
    assert gym.make("CrowdNav-v0").unwrapped.reward_config.name == "crowdnav"
    assert gym.make("CrowdNavComfort-v0").unwrapped.reward_config.name == "comfort"
    assert gym.make("CrowdNavComfortAngular-v0").unwrapped.reward_config.name == "comfort_angular"
    assert gym.make("CrowdNavSquare-v0").unwrapped.scene.scenario == "square_crossing"
    env = gym.make("CrowdNav-v0", num_humans=3, reward="comfort")
    assert env.unwrapped.scene.num_humans == 3 and env.unwrapped.reward_config.name == "comfort"


def test_make_with_module_prefix_in_a_fresh_interpreter():
    code = (
        "import gymnasium as gym\n"
        "env = gym.make('sb3_crowdnav:CrowdNav-v0')\n"
        "obs, _ = env.reset(seed=0)\n"
        "print(type(env.unwrapped).__name__, sorted(obs))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "CrowdNavEnv ['humans', 'humans_mask', 'robot']"


def test_importing_twice_is_harmless():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        importlib.reload(sb3_crowdnav)
        importlib.reload(sb3_crowdnav)
    assert [str(w.message) for w in caught] == []
    for env_id in ENV_IDS:
        assert env_id in gym.registry


# ---------------------------------------------------------------------- determinism
def rollout(env, seed, n_steps=60):
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    episode = [(obs, info)]
    for _ in range(n_steps):
        obs, reward, terminated, truncated, info = env.step(int(rng.integers(80)))
        episode.append((obs, reward, terminated, truncated, info))
        if terminated or truncated:
            obs, info = env.reset()
            episode.append((obs, info))
    return episode


def assert_same(a, b):
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            assert_same(a[k], b[k])
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            assert_same(x, y)
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b)
    else:
        assert a == b


@pytest.mark.parametrize("seed", [0, 1, 123])
def test_same_seed_same_episode(seed):
    kwargs = dict(reward="comfort_angular", robot_visible=True, num_humans=(2, 8))
    assert_same(rollout(CrowdNavEnv(**kwargs), seed), rollout(CrowdNavEnv(**kwargs), seed))


def test_goal_progress_shaping_passes_the_checkers_and_keeps_the_paper_episodes():
    """``progress_reward``: the checkers pass without warnings; the same seed gives the same episode; the people, the
    robot and the outcomes are the paper env's, the rewards differ by ``info["reward_progress"]`` alone."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make("CrowdNav-v0", progress_reward=0.1)
        gym_check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)
        sb3_check_env(gym.make("CrowdNav-v0", progress_reward=0.1), warn=True)
    assert [str(w.message) for w in caught] == []
    kwargs = dict(reward="comfort_angular", num_humans=(2, 8))
    shaped = rollout(CrowdNavEnv(progress_reward=0.1, **kwargs), 4, 150)
    np.testing.assert_equal(shaped, rollout(CrowdNavEnv(progress_reward=0.1, **kwargs), 4, 150))  # nan == nan
    for step, paper in zip(shaped, rollout(CrowdNavEnv(**kwargs), 4, 150), strict=True):
        assert_same(step[0], paper[0])  # the observation
        info, paper_info = step[-1], paper[-1]
        if len(step) == 2:  # a reset
            assert_same(info, paper_info)
            continue
        assert step[2:4] == paper[2:4] and info.pop("reward_progress") == pytest.approx(step[1] - paper[1], abs=1e-12)
        stats, paper_stats = info.pop("episode_stats", {}), paper_info.pop("episode_stats", {})
        assert_same(info, paper_info)
        stats.pop("discounted_return", None)  # the return counts the shaping
        np.testing.assert_equal(stats, {k: v for k, v in paper_stats.items() if k != "discounted_return"})


def test_different_seeds_differ():
    env = CrowdNavEnv()
    first = [env.reset(seed=s)[0]["humans"] for s in range(3)]
    assert not np.array_equal(first[0], first[1]) and not np.array_equal(first[1], first[2])


def test_reset_without_seed_continues_the_stream():
    env = CrowdNavEnv()
    env.reset(seed=5)
    a = env.reset()[0]["humans"]
    env.reset(seed=5)
    assert np.array_equal(a, env.reset()[0]["humans"])


# ---------------------------------------------------------------------- observation
def test_observation_layout():
    env = CrowdNavEnv(num_humans=4, max_humans=6)
    obs, info = env.reset(seed=0)
    assert info["num_humans"] == 4
    assert obs["robot"].dtype == np.float32 and obs["robot"].shape == (9,)
    np.testing.assert_allclose(obs["robot"][Robot.POS], [0.0, -4.0])
    np.testing.assert_allclose(obs["robot"][Robot.GOAL], [0.0, 4.0])
    assert obs["robot"][Robot.HEADING] == pytest.approx(math.pi / 2)
    hist = obs["humans"].reshape(5, 6, 5)
    assert np.array_equal(hist[0], hist[-1])  # the first state is repeated at reset
    assert obs["humans_mask"].tolist() == [1, 1, 1, 1, 0, 0]
    obs, *_ = env.step(64)
    hist = obs["humans"].reshape(5, 6, 5)
    assert np.all(hist[:, 4:] == 0.0)
    np.testing.assert_allclose(obs["robot"][Robot.POS], [0.0, -3.75], atol=1e-6)
    assert np.array_equal(hist[-2], env.reset(seed=0)[0]["humans"].reshape(5, 6, 5)[-1])  # shifted by one
    assert np.all(np.abs(hist[-1, :4, Human.VEL]).sum(axis=-1) > 0)


def test_observations_are_fresh_arrays():
    env = CrowdNavEnv()
    obs0, _ = env.reset(seed=0)
    keep = {k: v.copy() for k, v in obs0.items()}
    env.step(64)
    env.step(64)
    assert_same(obs0, keep)


# ---------------------------------------------------------------------- info and episode end
def test_info_has_every_term_and_stats_only_at_the_end():
    env = CrowdNavEnv(reward="comfort_angular")
    env.reset(seed=2)
    done, total = False, 0.0
    while not done:
        _, reward, terminated, truncated, info = env.step(64)
        done = terminated or truncated
        total += reward
        for key in ("is_success", "outcome", "min_distance", "in_comfort_zone", "time", *REWARD_KEYS):
            assert key in info
        assert reward == pytest.approx(sum(info[k] for k in REWARD_KEYS))
        assert ("episode_stats" in info) == done
    collided = info["outcome"] == "collision"
    assert set(info["episode_stats"]) == set(STATS_KEYS) | ({"collision_with"} if collided else set())
    assert info.get("collision_with") == info["episode_stats"].get("collision_with") == ("human" if collided else None)
    assert info["outcome"] == info["episode_stats"]["outcome"] in ("success", "collision", "timeout")
    assert info["is_success"] == (info["outcome"] == "success")


def test_timeout_is_truncation():
    env = CrowdNavEnv(num_humans=0, human_policy="linear")  # 100 steps of turning in circles
    env.reset(seed=0)
    circle = 0 * 16 + 4  # slowest speed, +π/2 each step
    for step in range(1, 101):
        _, _, terminated, truncated, info = env.step(circle)
        assert not terminated
        assert truncated == (step == 100)
    assert info["outcome"] == "timeout" and not info["is_success"]
    stats = info["episode_stats"]
    assert stats["navigation_time"] == pytest.approx(25.0)
    assert stats["path_length"] == pytest.approx(100 * 0.2 * 0.25)
    assert stats["heading_change"] == pytest.approx(100 * math.pi / 2)
    assert stats["sharp_turns"] == 100  # every turn is exactly the default threshold, π/2 (counted, as Eq. 13 does)

    gentle = CrowdNavEnv(num_humans=0, time_limit=1.25, angular_penalty_threshold=math.pi / 2 + 0.01)  # 5 steps
    gentle.reset(seed=0)
    for action in (circle, circle, circle, 0, 8):  # three quarter turns, straight on, a half turn (index 8: π)
        *_, truncated, info = gentle.step(action)
    assert truncated
    assert info["episode_stats"]["heading_change"] == pytest.approx(3 * math.pi / 2 + math.pi)
    assert info["episode_stats"]["sharp_turns"] == 1  # only the half turn reaches π/2 + 0.01

    short = CrowdNavEnv(num_humans=0, time_limit=2.0)
    short.reset(seed=0)
    ends = [short.step(circle)[3] for _ in range(8)]
    assert ends == [False] * 7 + [True]


def test_success_episode_statistics():
    env = CrowdNavEnv(num_humans=0, gamma=0.9)
    env.reset(seed=0)
    rewards = []
    while True:
        _, reward, terminated, truncated, info = env.step(64)  # straight to the goal 8 m ahead
        rewards.append(reward)
        if terminated or truncated:
            break
    assert terminated and info["is_success"] and info["outcome"] == "success"
    stats = info["episode_stats"]
    steps = len(rewards)
    assert steps == 31  # within 0.3 m of the goal after 7.75 s
    assert stats["navigation_time"] == pytest.approx(steps * 0.25)
    assert stats["path_length"] == pytest.approx(steps * 0.25)
    assert stats["discounted_return"] == pytest.approx(0.9 ** ((steps - 1) * 0.25))
    # no one present: the finite no-one distance (the diagonal of the observable positions), not inf
    assert stats["min_separation"] == env.no_one_distance and stats["discomfort_frequency"] == 0.0


def test_in_zone_separation_statistics_match_the_steps():
    """The episode's in-zone separations are the means of the per-step ``min_distance`` in those steps."""
    from sb3_crowdnav import OrcaPolicy

    env = CrowdNavEnv(reward="comfort")
    orca = OrcaPolicy.from_env(env)
    checked = 0
    for seed in range(40):
        obs, _ = env.reset(seed=seed)
        steps = []
        while True:
            action, _ = orca.predict(obs)
            obs, _, terminated, truncated, info = env.step(int(action))
            steps.append((info["min_distance"], info["in_comfort_zone"]))
            if terminated or truncated:
                break
        stats = info["episode_stats"]
        close = [d for d, _ in steps if d < env.reward_config.discomfort_dist]
        zone = [d for d, inside in steps if inside]
        assert stats["discomfort_frequency"] == pytest.approx(len(close) / len(steps))
        assert stats["comfort_zone_time"] == pytest.approx(len(zone) * 0.25)
        for key, values in (("discomfort_separation", close), ("comfort_zone_separation", zone)):
            if values:
                assert stats[key] == pytest.approx(np.mean(values))
            else:
                assert math.isnan(stats[key])
        checked += bool(close) and bool(zone) and len(close) != len(zone)
        if checked >= 3:
            break
    assert checked >= 3, "too few episodes with both kinds of step to check"


def test_collision_ends_the_episode():
    env = CrowdNavEnv(num_humans=1, human_policy="linear")
    env.reset(seed=0)
    env.unwrapped.sim.history[:, 0, Human.POS] = [0.0, -3.5]  # a pedestrian right ahead of the robot
    env.unwrapped.sim.human_goals[0] = [0.0, -3.5]
    _, reward, terminated, truncated, info = env.step(64)
    assert terminated and not truncated and info["outcome"] == "collision" and not info["is_success"]
    assert reward == pytest.approx(-0.25) and info["min_distance"] < 0


def test_step_rejects_invalid_actions():
    env = CrowdNavEnv()
    env.reset(seed=0)
    for bad in (80, -1, 1.5, "a"):
        with pytest.raises(ValueError, match="action"):
            env.step(bad)
    env.step(np.int64(3))
    env.step(np.array(3))


# ---------------------------------------------------------------------- rendering
def test_rgb_array_rendering():
    env = gym.make("CrowdNav-v0", render_mode="rgb_array")
    env.reset(seed=0)
    env.step(64)
    frame = env.render()
    env.close()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.shape[0] > 100 and frame.shape[1] > 100
    assert frame.std() > 0  # something was drawn


def test_sharp_turns_are_the_turns_eq13_penalises():
    """``sharp_turns`` counts the steps turning by >= π/2; under ``"comfort_angular"`` exactly the non-terminal
    ones carry the angular penalty, and the count is the same under a reward that does not penalise turns."""
    counts = {}
    for reward in ("comfort_angular", "crowdnav"):
        env = CrowdNavEnv(reward=reward, num_humans=2)
        env.reset(seed=3)
        rng = np.random.default_rng(0)
        sharp = 0
        while True:
            h0 = float(env.sim.robot[Robot.HEADING])
            *_, terminated, truncated, info = env.step(int(rng.integers(80)))
            turn = abs((float(env.sim.robot[Robot.HEADING]) - h0 + math.pi) % (2 * math.pi) - math.pi)
            is_sharp = turn >= math.pi / 2 - 1e-6
            sharp += is_sharp
            if reward == "comfort_angular" and not terminated:
                assert (info["reward_angular"] < 0) == is_sharp
            if terminated or truncated:
                break
        assert info["episode_stats"]["sharp_turns"] == sharp > 5  # random directions turn sharply often
        counts[reward] = (sharp, info["episode_stats"]["heading_change"])
    assert counts["comfort_angular"] == counts["crowdnav"]


def test_episode_statistics_accumulate_every_step_and_forget_at_reset():
    from sb3_crowdnav.envs import EpisodeStatistics
    from sb3_crowdnav.sim import RewardConfig
    from sb3_crowdnav.sim.rewards import RewardTerms

    def terms(min_distance, in_zone):
        zero = np.float64(0.0)
        return RewardTerms(zero, np.bool_(False), np.bool_(False), zero, zero, zero, zero, zero,
                           np.float64(min_distance), np.bool_(in_zone))

    def robot(x, y, heading):
        state = [0.0] * 9
        state[0], state[1], state[Robot.HEADING] = x, y, heading
        return state

    no_one = (np.zeros((3, 5)), np.zeros(3, dtype=bool))  # the people's state (the safety figures' input)
    stats = EpisodeStatistics(RewardConfig(), gamma=0.5, time_step=0.25, v_pref=2.0)
    stats.update(robot(0, 0, 0), robot(3, 4, math.pi / 2), terms(0.1, False), 1.0, *no_one)  # within discomfort_dist
    stats.update(robot(3, 4, math.pi / 2), robot(3, 4, -math.pi / 2), terms(0.5, True), 2.0, *no_one)  # comfort zone
    summary = stats.summary("timeout", 3)
    expected = {
        "outcome": "timeout", "navigation_time": 0.5, "path_length": 5.0, "min_separation": 0.1,
        "discomfort_frequency": 0.5, "comfort_zone_time": 0.25, "discomfort_separation": 0.1,
        "comfort_zone_separation": 0.5, "heading_change": 1.5 * math.pi, "sharp_turns": 2,
        "discounted_return": 1.0 + 2.0 * 0.5 ** (0.25 * 2.0), "num_humans": 3,
    }  # (the safety figures: tests/test_safety_figures.py)
    assert {k: summary[k] for k in expected} == pytest.approx(expected)
    stats.reset()
    stats.update(robot(0, 0, 0), robot(0, 1, 0), terms(1.0, False), 0.0, *no_one)
    summary = stats.summary("running", 3)
    assert summary["path_length"] == 1.0 and summary["sharp_turns"] == 0
    assert math.isnan(summary["discomfort_separation"]) and math.isnan(summary["comfort_zone_separation"])
