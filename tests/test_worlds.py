"""``CrowdNavWorlds-v0``: episodes drawn from several crowds around one robot, and the ``apg_robust`` variant."""

from __future__ import annotations

import json
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.cli import main
from sb3_crowdnav.envs.worlds import ROBUST_WORLDS, CrowdNavWorldsEnv
from sb3_crowdnav.training.schedule import ScheduleConfig

TWO = [{"crowd": "orca"}, {"crowd": "orca", "human_speed": "measured", "robot_visible": 0.5}]


def _episode(env: gym.Env, seed: int, actions: list[int]) -> tuple[list[np.ndarray], list[float], dict]:
    obs, info = env.reset(seed=seed)
    observations, rewards = [np.concatenate([v.ravel() for v in obs.values()])], []
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        observations.append(np.concatenate([v.ravel() for v in obs.values()]))
        rewards.append(reward)
        if terminated or truncated:
            break
    return observations, rewards, info


@pytest.mark.parametrize("worlds", ["robust", TWO])
def test_both_checkers_pass_without_warnings(worlds):
    env = gym.make("CrowdNavWorlds-v0", worlds=worlds, num_humans=(0, 4))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env, warn=True)


def test_the_same_seed_gives_the_same_world_and_episode():
    actions = np.random.default_rng(0).integers(80, size=60).tolist()
    one = gym.make("CrowdNavWorlds-v0", worlds=TWO, num_humans=(0, 6))
    two = gym.make("CrowdNavWorlds-v0", worlds=TWO, num_humans=(0, 6))
    worlds = set()
    for seed in range(8):
        a, b = _episode(one, seed, actions), _episode(two, seed, actions)
        assert all(np.array_equal(x, y) for x, y in zip(a[0], b[0], strict=True)) and a[1] == b[1]
        assert a[2]["world"] == b[2]["world"]
        worlds.add(a[2]["world"])
    assert worlds == {0, 1}  # both drawn in 8 episodes (p = 1 - 2 / 2**8)


def test_an_episode_is_its_world_s_base_env_episode():
    env = gym.make("CrowdNavWorlds-v0", worlds=TWO, num_humans=5)
    actions = np.random.default_rng(1).integers(80, size=40).tolist()
    for seed in range(4):
        observations, rewards, info = _episode(env, seed, actions)
        inner = env.unwrapped.episode_seed
        base = gym.make("CrowdNav-v0", num_humans=5, **TWO[info["world"]])
        expected = _episode(base, inner, actions)
        assert all(np.array_equal(x, y) for x, y in zip(observations, expected[0], strict=True))
        assert rewards == expected[1]


def test_weights_choose_the_worlds():
    only_second = gym.make("CrowdNavWorlds-v0", worlds=TWO, weights=[0, 3], num_humans=2)
    assert {only_second.reset(seed=s)[1]["world"] for s in range(10)} == {1}
    env = gym.make("CrowdNavWorlds-v0", worlds=TWO, weights=[3, 1], num_humans=2)
    drawn = np.array([env.reset(seed=s)[1]["world"] for s in range(400)])
    assert 0.18 < drawn.mean() < 0.32  # P(world 1) = 0.25; 400 draws: sd 0.022


def test_observation_bounds_hold_every_world_s_observations():
    env = gym.make("CrowdNavWorlds-v0", worlds=TWO, num_humans=4).unwrapped
    for base in env.envs:
        for key, box in base.observation_space.spaces.items():
            wide = env.observation_space[key]
            assert np.all(wide.low <= box.low) and np.all(wide.high >= box.high)
    faster = env.envs[1].observation_space["humans"].high.max()
    assert env.observation_space["humans"].high.max() == faster > env.envs[0].observation_space["humans"].high.max()


def test_the_robust_preset_and_the_world_contract():
    env = gym.make("CrowdNavWorlds-v0", worlds="robust", num_humans=(0, 10)).unwrapped
    assert len(env.envs) == len(ROBUST_WORLDS) and env.world == gym.make("CrowdNav-v0").unwrapped.world
    assert [e.scene.crowd for e in env.envs] == ["orca", "orca", "social_force"]
    assert {e.scene.num_humans for e in env.envs} == {(0, 10)}


@pytest.mark.parametrize(("kwargs", "error", "message"), [
    ({"worlds": "nope"}, ValueError, "worlds"),
    ({"worlds": []}, ValueError, "at least one world"),
    ({"worlds": [{"time_step": 0.5}]}, ValueError, "worlds\\[0\\] sets \\['time_step'\\]"),
    ({"worlds": ["orca"]}, TypeError, "worlds\\[0\\]"),
    ({"worlds": TWO, "weights": [1.0]}, ValueError, "one number per world"),
    ({"worlds": TWO, "weights": [1.0, -1.0]}, ValueError, "weights\\[1\\]"),
    ({"worlds": TWO, "weights": [0, 0]}, ValueError, "not all be 0"),
    ({"worlds": TWO, "base_env": "CartPole-v1"}, ValueError, "base_env"),
    ({"worlds": TWO, "crowd": "social_force"}, ValueError, "crowd='social_force' has no effect"),
    ({"worlds": [{"crowd": "orca"}, {"crowd": "replay"}]}, (TypeError, ValueError), "path|replay"),
])
def test_bad_worlds_are_refused_naming_the_parameter(kwargs, error, message):
    with pytest.raises(error, match=message):
        CrowdNavWorldsEnv(**kwargs)


def test_apg_robust_brings_its_worlds_and_people_and_a_run_overrides_them():
    robust = ScheduleConfig(variant="apg_robust")
    assert robust.num_humans == (0, 10) and ScheduleConfig(variant="apg_rl").num_humans == 6
    assert robust.training_env_kwargs["worlds"] == "robust" and robust.train_freq == 8
    # a robot that can stop, and a finished model that caps V; the paper's variants keep the 80 actions
    assert robust.training_env_kwargs["actions"] == "with_stop" and robust.cap_values is True
    assert "actions" not in ScheduleConfig(variant="apg_rl").training_env_kwargs
    assert ScheduleConfig(variant="apg_rl").cap_values is None
    assert ScheduleConfig(variant="apg_robust", env_kwargs={"actions": "paper"}).training_env_kwargs["actions"] == "paper"
    # the schedule that fits an hour on 2 cores; the paper's variants keep theirs, and a run's own value wins
    assert (robust.rl_episodes, robust.exploration_episodes, robust.imitation_epochs, robust.checkpoint_episodes) \
        == (3_000, 1_500, 3, 750)
    paper = ScheduleConfig(variant="apg_rl")
    assert (paper.rl_episodes, paper.exploration_episodes, paper.imitation_epochs, paper.checkpoint_episodes) \
        == (10_000, 5_000, 10, 500)
    assert ScheduleConfig(variant="apg_robust", checkpoint_episodes=100).checkpoint_episodes == 100
    assert ScheduleConfig(variant="apg_robust", imitation_epochs=7, rl_episodes=4).imitation_epochs == 7
    assert ScheduleConfig(variant="apg_robust", num_humans=(2, 8)).training_env_kwargs["num_humans"] == (2, 8)


@pytest.mark.slow  # a training run: make slow
def test_apg_robust_short_run(tmp_path, monkeypatch):
    out = tmp_path / "robust"
    assert main(["train", "--variant", "apg_robust", "--out", str(out), "--il-episodes", "3", "--il-epochs", "1",
                 "--rl-episodes", "3", "--checkpoint-episodes", "3", "--eval-episodes", "2", "--overlap", "off"]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["env_id"] == "CrowdNavWorlds-v0" and config["training_env_kwargs"]["num_humans"] == [0, 10]
    model = APGValue.load(out / "final.zip")
    assert model.episodes_done == 3 and model.policy.world == gym.make("CrowdNav-v0", actions="with_stop").unwrapped.world
    env = gym.make("CrowdNav-v0", num_humans=0, actions="with_stop")  # and it acts on the open floor, empty included
    obs, _ = env.reset(seed=0)
    assert 0 <= int(model.predict(obs, deterministic=True)[0]) < 81


def test_a_recorded_world_leaves_to_its_recording_what_it_decides(tmp_path):
    from tests.test_replay import _walkers

    path = str(_walkers(tmp_path / "street.csv"))
    recorded = {"crowd": "replay", "crowd_kwargs": {"path": path}}
    env = gym.make("CrowdNavWorlds-v0", worlds=[{"crowd": "orca"}, recorded], num_humans=(0, 3), human_speed="measured")
    orca, replay = env.unwrapped.envs
    # the shared people settings reach the simulated world and not the recording, which walks its own people
    assert orca.scene.num_humans == (0, 3) and orca.scene.human_speed == "measured"
    assert replay.scene.crowd == "replay" and replay.scene.num_humans == 6 and replay.scene.human_speed == "fixed"
    seen = set()
    for seed in range(12):
        env.reset(seed=seed)
        seen.add(env.unwrapped.current)
        for _ in range(5):
            env.step(0)
    assert seen == {0, 1}
    # a setting that only recorded worlds would receive has no effect: refused
    with pytest.raises(ValueError, match=r"num_humans=.* has no effect.*recording"):
        gym.make("CrowdNavWorlds-v0", worlds=[recorded], num_humans=(0, 3))


def test_recordings_join_the_variants_worlds_and_are_refused_elsewhere(tmp_path):
    from tests.test_replay import _walkers

    path = str(_walkers(tmp_path / "street.csv"))
    config = ScheduleConfig(variant="apg_robust", recordings=(path, f"{path},tracked=all,crossing_length=6"))
    worlds = config.training_env_kwargs["worlds"]
    assert worlds[:3] == [dict(world) for world in ROBUST_WORLDS] and len(worlds) == 5
    # the defaults of a training scene (the nearest tracked, present 1 s early), and a scene's own settings win
    assert worlds[3] == {"crowd": "replay", "crowd_kwargs": {"tracked": "nearest", "lead_in": 1, "path": path}}
    assert worlds[4]["crowd_kwargs"] == {"tracked": "all", "lead_in": 1, "path": path, "crossing_length": 6}
    env = gym.make("CrowdNavWorlds-v0", **config.training_env_kwargs)
    assert {env.unwrapped.envs[i].scene.crowd for i in (3, 4)} == {"replay"}
    assert ScheduleConfig(variant="apg_robust").recordings == ()
    for variant in ("apg_rl", "apg_warehouse"):
        with pytest.raises(ValueError, match="recordings: variant"):
            ScheduleConfig(variant=variant, recordings=(path,))
    with pytest.raises(ValueError, match=r"recordings\[0\]"):
        ScheduleConfig(variant="apg_robust", recordings=(f"{path},frame_rate",))
    with pytest.raises(TypeError, match="recordings"):
        ScheduleConfig(variant="apg_robust", recordings=path)


def test_the_cli_refuses_a_recording_it_cannot_train_among_with_one_line(tmp_path, capsys):
    for argv, fragment in ((["--variant", "apg_rl", "--recording", "x.txt"], "recordings: variant 'apg_rl'"),
                           (["--variant", "apg_robust", "--recording", str(tmp_path / "none.txt")], "no file at"),
                           (["--algo", "dqn", "--hyperparams", "zoo_hyperparams/dqn.yml", "--recording", "x.txt"],
                            "--recording is not used with --hyperparams")):
        with pytest.raises(SystemExit) as exc:
            main(["train", *argv, "--out", str(tmp_path / "run")])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and fragment in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "run").exists()


@pytest.mark.slow  # a training run: make slow
def test_apg_robust_short_run_among_a_recording(tmp_path):
    from tests.test_replay import _walkers

    path = str(_walkers(tmp_path / "street.csv"))
    out = tmp_path / "robust"
    assert main(["train", "--variant", "apg_robust", "--recording", path, "--out", str(out), "--il-episodes", "6",
                 "--il-epochs", "1", "--rl-episodes", "8", "--checkpoint-episodes", "8", "--eval-episodes", "4",
                 "--overlap", "off"]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["recordings"] == [path] and config["training_env_kwargs"]["worlds"][-1]["crowd"] == "replay"
    assert APGValue.load(out / "final.zip").episodes_done == 8
