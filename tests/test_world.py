"""The world contract: its plain form, its checks, the converter of older model files, and the one comparison used by
every loader, the runner and the CLI."""

from __future__ import annotations

import base64
import dataclasses
import json
import math
import zipfile

import gymnasium as gym
import pytest

import sb3_crowdnav
from sb3_crowdnav.serialization import decode, read_world, write_spaces
from sb3_crowdnav.sim.config import RewardConfig
from sb3_crowdnav.sim.warehouse.config import PAPER_ROBOT, ROBOT_DEFAULTS
from sb3_crowdnav.sim.world import MOTION_FIELDS, World, compare_worlds, upgrade_policy_kwargs

# the shipped apg_warehouse_paper's world (the paper's robot) and the default warehouse's (a warehouse AMR)
WAREHOUSE = World(obstacle_collision_penalty=-0.25, waypoint_radius=0.6, progress_reward=0.1)
WAREHOUSE_AMR = dataclasses.replace(WAREHOUSE, **ROBOT_DEFAULTS)
SHAPED_OPEN_FLOOR = World(progress_reward=0.1)  # the open floor with goal-progress shaping


@pytest.mark.parametrize("world", [World(), WAREHOUSE, SHAPED_OPEN_FLOOR,
                                   World(time_step=0.5, kinematics="holonomic", rotation_range=1.5,
                                         reward=RewardConfig(name="comfort_angular"))])
def test_the_plain_form_round_trips_through_json(world):
    data = json.loads(json.dumps(world.to_dict()))
    assert World.from_dict(data) == world
    assert data["reward"]["name"] == world.reward.name
    assert {f.name for f in dataclasses.fields(World)} == set(data)


def test_each_env_publishes_its_world():
    assert gym.make("CrowdNav-v0").unwrapped.world == World()
    comfort = gym.make("CrowdNav-v0", reward="comfort", time_step=0.5, kinematics="holonomic").unwrapped.world
    assert (comfort.reward.name, comfort.time_step, comfort.kinematics) == ("comfort", 0.5, "holonomic")
    shaped = gym.make("CrowdNavWarehouse-v0", progress_reward=0.1, waypoint_radius=0.8).unwrapped.world
    assert shaped == dataclasses.replace(WAREHOUSE_AMR, waypoint_radius=0.8) and shaped.has_static_world
    assert gym.make("CrowdNavWarehouse-v0", progress_reward=0.1, **PAPER_ROBOT).unwrapped.world == WAREHOUSE
    for env_id in ("CrowdNav-v0", "CrowdNavSquare-v0", "CrowdNavWorlds-v0"):  # the open floor and what builds on it
        open_floor = gym.make(env_id, progress_reward=0.1).unwrapped.world
        assert open_floor == SHAPED_OPEN_FLOOR and not open_floor.has_static_world and open_floor.has_value_ceiling
    comfort = gym.make("CrowdNavComfortAngular-v0", progress_reward=0.1).unwrapped.world
    assert comfort == dataclasses.replace(SHAPED_OPEN_FLOOR, reward=RewardConfig(name="comfort_angular"))
    assert not World().has_value_ceiling and WAREHOUSE.has_value_ceiling


def test_from_dict_refuses_unknown_and_missing_keys():
    data = World().to_dict()
    with pytest.raises(ValueError, match=r"unknown \['crowd_model'\]"):
        World.from_dict({**data, "crowd_model": "orca"})
    with pytest.raises(ValueError, match=r"missing \['progress_reward'\]"):
        World.from_dict({k: v for k, v in data.items() if k != "progress_reward"})
    with pytest.raises(ValueError, match=r"reward has the keys .*unknown \['bonus'\]"):
        World.from_dict({**data, "reward": {**data["reward"], "bonus": 1.0}})
    with pytest.raises(TypeError, match="mapping"):
        World.from_dict([("time_step", 0.25)])


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    ({"time_step": 0.0}, ValueError, "time_step must be > 0"),
    ({"time_step": 3.0}, ValueError, "time_step must be <= 2.0"),
    ({"time_step": "0.25"}, TypeError, "time_step must be a real number"),
    ({"kinematics": "car"}, ValueError, "kinematics must be one of"),
    ({"rotation_range": 7.0}, ValueError, r"rotation_range must be in \(0, 2π\]"),
    ({"max_acceleration": 0.0}, ValueError, "max_acceleration must be > 0"),
    ({"max_acceleration": -1.0}, ValueError, "max_acceleration must be > 0"),
    ({"max_turn_rate": "1.5"}, TypeError, "max_turn_rate must be a real number"),
    ({"max_turn_rate": 1.5, "kinematics": "holonomic"}, ValueError, "max_turn_rate must be None with kinematics"),
    ({"actions": "stop"}, ValueError, "actions must be one of"),
    ({"n_speeds": 6}, ValueError, "n_speeds must be 5"),
    ({"n_directions": 16.0}, TypeError, "n_directions must be an int"),
    ({"reward": {"name": "crowdnav"}}, TypeError, "reward must be a RewardConfig"),
    ({"waypoint_radius": 0.6}, ValueError, "must both be set"),
    ({"obstacle_collision_penalty": 0.5, "waypoint_radius": 0.6}, ValueError, "obstacle_collision_penalty must be <= 0"),
    ({"obstacle_collision_penalty": -0.25, "waypoint_radius": -1.0}, ValueError, "waypoint_radius must be > 0"),
    ({"progress_reward": -0.1}, ValueError, "progress_reward must be >= 0"),
    ({"progress_reward": math.nan}, ValueError, "progress_reward must be finite"),
    ({"progress_reward": "0.1"}, TypeError, "progress_reward must be a real number"),
])
def test_bad_values_are_refused_naming_the_field(kwargs, error, match):
    with pytest.raises(error, match=match):
        World(**kwargs)


def test_numpy_and_int_values_become_plain_floats():
    import numpy as np

    world = World(time_step=np.float32(0.5), rotation_range=3)
    assert type(world.time_step) is float and type(world.rotation_range) is float
    json.dumps(world.to_dict())


# ------------------------------------------------------------------ the converter of older files
REWARD = dataclasses.asdict(RewardConfig(name="comfort"))


@pytest.mark.parametrize(("legacy", "expected"), [
    # an open-floor APGValue file (apg_rl, ..., lm_rl): the settings as separate policy kwargs
    ({"time_step": 0.25, "kinematics": "unicycle", "rotation_range": 2 * math.pi, "reward": REWARD},
     World(reward=RewardConfig(name="comfort"))),
    # a warehouse file with route shaping (apg_warehouse_paper)
    ({"time_step": 0.25, "kinematics": "unicycle", "rotation_range": 2 * math.pi, "reward": {"name": "crowdnav"},
      "obstacles": {"penalty": -0.25, "waypoint_radius": 0.6, "progress_reward": 0.1}}, WAREHOUSE),
    # a warehouse file saved before route shaping existed: no progress_reward, which was 0 then
    ({"time_step": 0.25, "obstacles": {"penalty": -0.5, "waypoint_radius": 0.6}},
     World(obstacle_collision_penalty=-0.5, waypoint_radius=0.6)),
    # the member world of SB3 algorithms' files (ppo_apg, dqn_apg, ppo_warehouse): three entries
    ({"time_step": 0.5, "kinematics": "holonomic", "rotation_range": 1.5},
     World(time_step=0.5, kinematics="holonomic", rotation_range=1.5)),
    # a file from before any of them was stored: the policy's defaults of that time
    ({}, World()),
])
def test_the_converter_reads_every_legacy_shape(legacy, expected):
    assert World.from_legacy(legacy) == expected
    kwargs = upgrade_policy_kwargs({**legacy, "gamma": 0.9, "net_arch": [150, 100, 100]})
    if legacy:
        assert kwargs == {"gamma": 0.9, "net_arch": [150, 100, 100], "world": expected.to_dict()}
    else:
        assert "world" not in kwargs  # nothing to convert: the caller's world (the env's) is used


def test_the_converter_refuses_what_it_cannot_read():
    with pytest.raises(ValueError, match=r"unknown \['max_speed'\]"):
        World.from_legacy({"time_step": 0.25, "max_speed": 2.0})
    with pytest.raises(ValueError, match="legacy obstacles must be"):
        World.from_legacy({"obstacles": {"penalty": -0.25}})
    with pytest.raises(ValueError, match="legacy obstacles must be"):
        World.from_legacy({"obstacles": {"penalty": -0.25, "waypoint_radius": 0.6, "sensor_range": 4.0}})
    with pytest.raises(ValueError, match=r"has a 'world' and also \['time_step'\]"):
        upgrade_policy_kwargs({"world": World().to_dict(), "time_step": 0.25})
    assert upgrade_policy_kwargs({"world": World().to_dict()}) == {"world": World().to_dict()}


@pytest.mark.parametrize(("name", "env_id", "env_kwargs"), [
    ("apg_rl", "CrowdNav-v0", {}),
    ("apg_carl", "CrowdNav-v0", {"reward": "comfort_angular"}),
    ("apg_warehouse_paper", "CrowdNavWarehouse-v0", {"progress_reward": 0.1, **PAPER_ROBOT}),
])
def test_shipped_value_files_hold_their_envs_world_in_the_legacy_form(name, env_id, env_kwargs):
    path = sb3_crowdnav.models.check_pretrained(name)
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    stored = decode(base64.b64decode(data["policy_kwargs"][":serialized:"]))
    assert "world" not in stored and "time_step" in stored  # the form the converter exists for
    world = gym.make(env_id, **env_kwargs).unwrapped.world
    assert World.from_dict(upgrade_policy_kwargs(stored)["world"]) == world
    assert read_world(path) == world
    assert sb3_crowdnav.pretrained(name).policy.world == world


def test_shipped_sb3_files_agree_with_their_env_in_the_motion_fields():
    for name, env_id in (("ppo_apg", "CrowdNav-v0"), ("dqn_apg", "CrowdNav-v0"),
                         ("ppo_warehouse", "CrowdNavWarehouse-v0")):
        world = read_world(sb3_crowdnav.models.check_pretrained(name))
        kwargs = PAPER_ROBOT if env_id == "CrowdNavWarehouse-v0" else {}  # the warehouse robot they learnt
        assert compare_worlds(world, gym.make(env_id, **kwargs).unwrapped.world, MOTION_FIELDS) is None


# ------------------------------------------------------------------ the one comparison
def test_the_comparison_lists_each_differing_field():
    trained = World(time_step=0.5, reward=RewardConfig(name="comfort", social_penalty=0.05))
    assert compare_worlds(trained, World()) == (
        "the model was trained with time_step=0.5 (the env has 0.25), reward.name='comfort' (the env has 'crowdnav'), "
        "reward.social_penalty=0.05 (the env has 0.02)")
    assert compare_worlds(trained, World(), MOTION_FIELDS) == "the model was trained with time_step=0.5 (the env has 0.25)"
    assert compare_worlds(trained, World(), ["reward"], against="b.zip").endswith("(b.zip has 0.02)")
    assert compare_worlds(World(rotation_range=2 * math.pi * (1 + 1e-12)), World()) is None  # last bits of text
    assert compare_worlds(WAREHOUSE, World(), ["waypoint_radius"]) == \
        "the model was trained with waypoint_radius=0.6 (the env has None)"
    with pytest.raises(ValueError, match=r"unknown \['speed'\]"):
        compare_worlds(World(), World(), ["speed"])


def test_a_saved_value_model_stores_its_world_as_plain_json_and_loading_refuses_another_world(tmp_path):
    from sb3_crowdnav import APGValue

    env = gym.make("CrowdNav-v0", reward="comfort")
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0)
    model.save(tmp_path / "m.zip")
    with zipfile.ZipFile(tmp_path / "m.zip") as archive:
        kwargs = json.loads(archive.read("data"))["policy_kwargs"]
    assert kwargs["world"] == env.unwrapped.world.to_dict() and "reward" not in kwargs
    assert APGValue.load(tmp_path / "m.zip").policy.world == env.unwrapped.world
    assert APGValue.load(tmp_path / "m.zip", env=env).policy.world == env.unwrapped.world
    with pytest.raises(ValueError, match=r"does not match the env's world: .*reward.name='comfort'"):
        APGValue.load(tmp_path / "m.zip", env=gym.make("CrowdNav-v0"))
    with pytest.raises(ValueError, match=r"policy_kwargs\['world'\] does not match the env's world: .*time_step=0.5"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, policy_kwargs={"world": World(time_step=0.5)})


def test_a_model_of_the_shaped_open_floor_acts_without_the_shaping_and_trains_on_only_with_it(tmp_path):
    """The goal-progress shaping is a reward, as the warehouse's route shaping: a model trained with it acts in an
    env without it (every loader, the runner), and the shipped models (trained without it) act in a shaped env; but
    further training, an env attached to the model, needs the same shaping."""
    from sb3_crowdnav import APGValue
    from sb3_crowdnav.evaluation.runner import make_policy

    shaped, plain = gym.make("CrowdNav-v0", progress_reward=0.1), gym.make("CrowdNav-v0")
    path = tmp_path / "shaped.zip"
    APGValue("ApgPolicy", shaped, imitation_episodes=0, seed=0).save(path)
    assert read_world(path) == SHAPED_OPEN_FLOOR
    assert sb3_crowdnav.models.world_mismatch(path, plain) is None
    obs, _ = plain.reset(seed=0)
    assert plain.action_space.contains(int(make_policy(str(path), plain).predict(obs, deterministic=True)[0]))
    with pytest.raises(ValueError, match=r"trained with progress_reward=0.1 \(the env has 0.0\)"):
        APGValue.load(path, env=plain)
    assert APGValue.load(path, env=shaped).policy.world == SHAPED_OPEN_FLOOR
    shipped = sb3_crowdnav.models.check_pretrained("apg_rl")
    assert sb3_crowdnav.models.world_mismatch(shipped, shaped) is None
    with pytest.raises(ValueError, match=r"trained with progress_reward=0.0 \(the env has 0.1\)"):
        APGValue.load(shipped, env=shaped)


def test_an_sb3_model_file_stores_the_world_and_is_compared_in_the_motion_fields(tmp_path):
    from stable_baselines3 import PPO

    env = gym.make("CrowdNav-v0", reward="comfort")
    path = tmp_path / "ppo.zip"
    model = PPO("MultiInputPolicy", env, n_steps=8, batch_size=8, device="cpu")
    model.save(path)
    write_spaces(path, model.observation_space, model.action_space, env)
    assert read_world(path) == env.unwrapped.world
    # a policy acting from observations alone is not affected by the reward; the step and the kinematics are
    assert sb3_crowdnav.models.world_mismatch(path, gym.make("CrowdNav-v0")) is None
    with pytest.raises(ValueError, match=r"trained with kinematics='unicycle' \(the env has 'holonomic'\)"):
        sb3_crowdnav.models.load_model(path, env=gym.make("CrowdNav-v0", kinematics="holonomic"))


@pytest.mark.parametrize(("name", "env_id", "env_kwargs", "field"), [
    ("apg_rl", "CrowdNav-v0", {"time_step": 0.5}, "time_step"),
    ("ppo_apg", "CrowdNav-v0", {"kinematics": "holonomic"}, "kinematics"),
    ("apg_warehouse_paper", "CrowdNavWarehouse-v0", {"waypoint_radius": 1.0, "progress_reward": 0.1, **PAPER_ROBOT},
     "waypoint_radius"),
    ("ppo_warehouse", "CrowdNavWarehouse-v0", {}, "actions"),
])
def test_every_loader_refuses_a_model_of_another_world(name, env_id, env_kwargs, field, capsys):
    from sb3_crowdnav.cli import main
    from sb3_crowdnav.evaluation.runner import make_policy

    env = gym.make(env_id, **env_kwargs)
    with pytest.raises(ValueError, match=f"trained with {field}="):
        sb3_crowdnav.pretrained(name, env=env)
    with pytest.raises(ValueError, match=f"trained with {field}="):
        make_policy(f"pretrained:{name}", env)
    assert make_policy(f"pretrained:{name}", env, allow_env_mismatch=True) is not None
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--policy", f"pretrained:{name}", "--env", env_id, "--env-kwargs", repr(env_kwargs),
              "--episodes", "1"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"trained with {field}=" in err and "--allow-env-mismatch" in err
