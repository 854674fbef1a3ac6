"""sb3-contrib baselines: QRDQN, RecurrentPPO and MaskablePPO with the APG extractor; MaskablePPO's wall masks."""

from __future__ import annotations

import itertools
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from sb3_contrib import QRDQN, MaskablePPO, RecurrentPPO
from stable_baselines3.common.env_util import make_vec_env

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.apg_value.action_masks import WallActionMasker, WallMaskedPolicy, wall_action_masks
from sb3_crowdnav.apg_value.propagation import wall_hits
from sb3_crowdnav.cli import main
from sb3_crowdnav.evaluation.runner import make_policy, run_episode
from sb3_crowdnav.models import detect_algorithm, load_model
from sb3_crowdnav.nn import ApgExtractor, ApgMaskablePolicy, ApgQRDQNPolicy, ApgRecurrentPolicy
from sb3_crowdnav.serialization import write_spaces
from sb3_crowdnav.sim.observation import Robot
from sb3_crowdnav.training.hyperparams import env_wrapper_class, prepare

HYPER = Path(__file__).resolve().parents[1] / "zoo_hyperparams"
WAREHOUSE = "CrowdNavWarehouse-v0"
CONTRIB = {"qrdqn": (QRDQN, ApgQRDQNPolicy, "CrowdNav-v0"), "recurrentppo": (RecurrentPPO, ApgRecurrentPolicy, WAREHOUSE),
           "maskableppo": (MaskablePPO, ApgMaskablePolicy, WAREHOUSE)}
SMALL = {"qrdqn": dict(buffer_size=500, learning_starts=50, batch_size=32, policy_kwargs=dict(n_quantiles=8)),
         "recurrentppo": dict(n_steps=32, batch_size=32, n_epochs=1, policy_kwargs=dict(lstm_hidden_size=16)),
         "maskableppo": dict(n_steps=32, batch_size=32, n_epochs=1)}


def _partly_masked_state(max_seeds: int = 10):
    """(seed, actions so far, observation) of the first warehouse state where some but not all actions are masked,
    reached by uniformly random actions."""
    env = WallActionMasker(gym.make(WAREHOUSE))
    for seed in range(max_seeds):
        rng = np.random.default_rng(seed)
        obs, _ = env.reset(seed=seed)
        actions: list[int] = []
        while True:
            masks = env.action_masks()
            if 0 < masks.sum() < masks.size:
                return env, seed, actions, obs, masks
            actions.append(int(rng.integers(masks.size)))
            obs, _, terminated, truncated, _ = env.step(actions[-1])
            if terminated or truncated:
                break
    raise AssertionError("no partly masked state found")


def _step_after(env: gym.Env, seed: int, actions: list[int], action: int) -> dict:
    env.reset(seed=seed)
    for a in actions:
        env.step(a)
    return env.step(action)[4]


def test_an_action_predicted_to_hit_a_wall_is_masked_and_hits_it_in_the_env():
    env, seed, actions, obs, masks = _partly_masked_state()
    masked = np.flatnonzero(~masks)
    allowed = np.flatnonzero(masks)
    for action in masked[:: max(1, len(masked) // 8)]:  # the env agrees: a masked action ends the episode on a wall
        info = _step_after(env, seed, actions, int(action))
        assert info["outcome"] == "collision" and info["collision_with"] == "obstacle", (action, info["outcome"])
    for action in allowed[:: max(1, len(allowed) // 8)]:  # and allowed ones do not touch one
        info = _step_after(env, seed, actions, int(action))
        assert info.get("collision_with") != "obstacle", action
    # the masks are the propagation model's prediction on the observation, batched or not
    static = {k: obs[k][None] for k in ("obstacles", "obstacles_mask")}
    np.testing.assert_array_equal(~wall_hits(env.unwrapped.world, obs["robot"][None], static)[0], masks)
    batch = {k: np.stack([v, v]) for k, v in obs.items()}
    np.testing.assert_array_equal(wall_action_masks(env.unwrapped.world, batch), np.stack([masks, masks]))


def test_never_every_action_masked():
    """A robot already touching a wall hits it under every action: then none is masked."""
    env = gym.make(WAREHOUSE)
    obs, _ = env.reset(seed=0)
    world = env.unwrapped.world
    obs = {k: v.copy() for k, v in obs.items()}
    x, y = obs["robot"][Robot.POS]
    radius = obs["robot"][Robot.RADIUS]
    obs["obstacles"][:] = 0.0
    obs["obstacles_mask"][:] = 0.0
    obs["obstacles"][:4] = [x + 0.5 * radius, y - 5.0, x + 0.5 * radius, y + 5.0]  # a wall through the robot's disc
    obs["obstacles_mask"][0] = 1.0
    static = {k: obs[k][None] for k in ("obstacles", "obstacles_mask")}
    assert wall_hits(world, obs["robot"][None], static).all()
    assert wall_action_masks(world, obs).all()
    obs["obstacles_mask"][0] = 0.0  # and with no wall in sight, nothing is masked either
    assert wall_action_masks(world, obs).all()


def test_wall_masks_are_refused_without_walls():
    env = gym.make("CrowdNav-v0")
    with pytest.raises(ValueError, match=r"need a world of racks and walls.*CrowdNav-v0 has none"):
        WallActionMasker(env)
    obs, _ = env.reset(seed=0)
    with pytest.raises(ValueError, match="racks and walls"):
        wall_action_masks(env.unwrapped.world, obs)
    warehouse = gym.make(WAREHOUSE)
    with pytest.raises(ValueError, match=r"no \['obstacles', 'obstacles_mask'\]"):
        wall_action_masks(warehouse.unwrapped.world, obs)
    with pytest.raises(RuntimeError, match="before reset"):
        WallActionMasker(warehouse).action_masks()


def test_maskableppo_on_the_open_floor_is_refused_by_the_cli(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["train", "--algo", "maskableppo", "--hyperparams", str(HYPER / "ppo.yml"), "--env", "CrowdNav-v0",
              "--timesteps", "8", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "CrowdNav-v0 has none" in err, err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("algo", sorted(CONTRIB))
def test_apg_policy_names_the_contrib_policies(algo):
    """"ApgPolicy" in a file gives each algorithm its APG policy; rl-zoo3's file entries are accepted."""
    cls, policy_cls, env_id = CONTRIB[algo]
    section = yaml.safe_load((HYPER / f"{algo}.yml").read_text())[env_id]
    assert section["policy"] == "ApgPolicy"
    cfg = prepare(algo, section)
    assert cfg["policy"] is policy_cls and "env_wrapper" not in cfg["kwargs"]
    kwargs = {**SMALL[algo]}
    env = make_vec_env(env_id, n_envs=1, env_kwargs={"num_humans": 2}, wrapper_class=env_wrapper_class(algo))
    model = cls(cfg["policy"], env, **kwargs)
    assert isinstance(model.policy, policy_cls)
    extractor = model.policy.quantile_net.features_extractor if algo == "qrdqn" else model.policy.features_extractor
    assert isinstance(extractor, ApgExtractor)


def test_a_wrapper_other_than_the_masks_is_refused():
    with pytest.raises(ValueError, match="env_wrapper"):
        prepare("ppo", {"env_wrapper": "sb3_crowdnav.apg_value.action_masks.WallActionMasker"})
    with pytest.raises(ValueError, match="env_wrapper"):
        prepare("maskableppo", {"env_wrapper": "gymnasium.wrappers.TimeLimit"})


def test_recurrent_state_is_carried_across_the_episode_by_the_runner():
    """The runner hands RecurrentPPO's LSTM state back at every step and flags only the first as an episode start."""
    env = gym.make("CrowdNav-v0", num_humans=2)
    model = RecurrentPPO(ApgRecurrentPolicy, env, **SMALL["recurrentppo"])
    calls = []

    class Spy:
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            action, new_state = model.predict(observation, state, episode_start, deterministic)
            calls.append((state, bool(episode_start[0]), new_state))
            return action, new_state

    record = run_episode(env, Spy(), seed=3)
    assert record.steps == len(calls) > 1
    assert calls[0][0] is None and calls[0][1]
    for (_, _, returned), (given, start, _) in itertools.pairwise(calls):
        assert given is returned and not start
    assert not np.allclose(calls[0][2][0], calls[-1][2][0])  # the memory moves along the episode


def test_a_saved_maskable_model_acts_within_its_masks_at_evaluation(tmp_path):
    env = make_vec_env(WAREHOUSE, n_envs=1, wrapper_class=WallActionMasker)
    model = MaskablePPO(ApgMaskablePolicy, env, seed=0, **SMALL["maskableppo"])
    path = tmp_path / "maskableppo.zip"
    model.save(path)
    write_spaces(path, model.observation_space, model.action_space, env)
    assert detect_algorithm(path) == "maskableppo"
    assert isinstance(load_model(path), MaskablePPO)
    masker, _, _, obs, masks = _partly_masked_state()
    policy = make_policy(str(path), masker.unwrapped)
    assert isinstance(policy, WallMaskedPolicy) and policy.observation_space == model.observation_space
    policy.set_random_seed(0)
    actions = {int(policy.predict(obs, deterministic=False)[0]) for _ in range(200)}
    assert actions <= set(np.flatnonzero(masks).tolist())
    assert len(actions) > 1


@pytest.mark.slow  # three short trainings and evaluations through the CLI (about 15 s each)
@pytest.mark.parametrize("algo", sorted(CONTRIB))
def test_cli_trains_saves_loads_and_evaluates(algo, tmp_path, capsys):
    cls, policy_cls, env_id = CONTRIB[algo]
    section = yaml.safe_load((HYPER / f"{algo}.yml").read_text())[env_id]
    section.update(n_envs=1, **{k: v for k, v in SMALL[algo].items() if k != "policy_kwargs"})
    section["policy_kwargs"] = {**(SMALL[algo].get("policy_kwargs") or {})}
    small = tmp_path / f"{algo}.yml"
    small.write_text(yaml.safe_dump({env_id: section}))
    out = tmp_path / "run"
    assert main(["train", "--algo", algo, "--hyperparams", str(small), "--env", env_id, "--timesteps", "200",
                 "--humans", "2", "--out", str(out)]) == 0
    path = out / f"{algo}.zip"
    model = load_model(path)
    assert type(model) is cls and isinstance(model.policy, policy_cls)
    assert model.num_timesteps >= 200
    capsys.readouterr()
    assert main(["evaluate", "--policy", str(path), "--env", env_id, "--humans", "2", "--episodes", "2",
                 "--no-progress"]) == 0
    assert "2 episodes" in capsys.readouterr().out


@pytest.mark.slow  # an rl-zoo3 training run in a subprocess (about 20 s)
def test_rl_zoo3_trains_maskableppo_from_its_file(tmp_path):
    """sb3-crowdnav-zoo reads the file's env_wrapper (the wall masks) and "ApgPolicy"; the file loads safely."""
    import subprocess
    import sys

    subprocess.run([sys.executable, "-m", "sb3_crowdnav.training.zoo", "train", "--algo", "maskableppo", "--env",
                    WAREHOUSE, "-conf", str(HYPER / "maskableppo.yml"), "-n", "64", "-f", str(tmp_path), "--eval-freq",
                    "-1", "--seed", "0", "-params", "n_envs:1", "n_steps:32", "batch_size:32", "n_epochs:1"],
                   check=True, capture_output=True, timeout=300)
    saved = tmp_path / "maskableppo" / f"{WAREHOUSE}_1" / f"{WAREHOUSE}.zip"
    assert detect_algorithm(saved) == "maskableppo"
    model = load_model(saved, spaces_from=gym.make(WAREHOUSE))
    assert isinstance(model, MaskablePPO) and isinstance(model.policy, ApgMaskablePolicy)


@pytest.mark.parametrize("algo", sorted(CONTRIB))
@pytest.mark.parametrize("policy", ["ApgPolicy", "sb3-contrib's"])
def test_save_detect_and_load_without_unpickling(algo, policy, tmp_path):
    """Our aliases and sb3-contrib's own MultiInput policies: detected, loaded safely, the same deterministic actions."""
    cls, policy_cls, _ = CONTRIB[algo]
    env = gym.make("CrowdNav-v0", num_humans=2)
    name = policy_cls if policy == "ApgPolicy" else prepare(algo, {})["policy"]
    kwargs = {**SMALL[algo], "policy_kwargs": {**SMALL[algo].get("policy_kwargs", {}), "net_arch": [16]}}
    model = cls(name, env, seed=0, **kwargs)
    path = tmp_path / f"{algo}.zip"
    model.save(path)
    write_spaces(path, model.observation_space, model.action_space, env)
    assert detect_algorithm(path) == algo
    loaded = load_model(path)
    assert type(loaded) is cls and type(loaded.policy) is type(model.policy)
    obs, _ = env.reset(seed=1)
    state = None
    for _ in range(3):
        action, state_model = model.predict(obs, state, deterministic=True)
        assert loaded.predict(obs, state, deterministic=True)[0] == action
        state = state_model
        obs = env.step(int(action))[0]
