"""rl-zoo3 integration: hyperparameter files, APGValue in rl-zoo3's tables, "ApgPolicy" for SB3's algorithms."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import optuna
import pytest
import yaml
from stable_baselines3 import DQN, PPO

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.nn import ApgActorCriticPolicy, ApgDQNPolicy, ApgExtractor
from sb3_crowdnav.training.zoo import ZOO_ALGOS, register, sample_apg_value_params
from sb3_crowdnav.training.zoo import main as zoo_main

ROOT = Path(__file__).resolve().parents[1]
HYPER = ROOT / "zoo_hyperparams"


def test_hyperparameter_files_carry_the_paper_settings():
    apg = yaml.safe_load((HYPER / "apg_value.yml").read_text())["CrowdNav-v0"]
    assert apg["policy"] == "ApgPolicy"
    assert (apg["gamma"], apg["batch_size"], apg["learning_rate"]) == (0.9, 100, 1e-3)
    assert (apg["imitation_episodes"], apg["imitation_learning_rate"]) == (3000, 0.01)
    assert (apg["exploration_initial_eps"], apg["exploration_final_eps"], apg["exploration_episodes"]) == (0.5, 0.1, 5000)
    for algo in ("ppo", "dqn"):
        assert yaml.safe_load((HYPER / f"{algo}.yml").read_text())["CrowdNav-v0"]["policy"] == "ApgPolicy"
    # every key of the APGValue file is a constructor argument (rl-zoo3 passes them through)
    import inspect

    allowed = set(inspect.signature(APGValue.__init__).parameters) | {"n_timesteps", "n_envs", "env_kwargs"}
    for section in yaml.safe_load((HYPER / "apg_value.yml").read_text()).values():
        assert set(section) <= allowed


ALGO_OF_FILE = {"ppo_from_demonstrations": "ppo", "dqn_from_demonstrations": "dqn", "dqn_nstep_from_demonstrations": "dqn"}
ENTRIES = [(path.name, env_id) for path in sorted(HYPER.glob("*.yml")) for env_id in yaml.safe_load(path.read_text())]


@pytest.mark.parametrize(("name", "env_id"), ENTRIES)
def test_every_hyperparameter_entry_prepares_and_its_env_builds(name, env_id):
    import gymnasium as gym

    from sb3_crowdnav.training.hyperparams import load_hyperparams, prepare

    algo = ALGO_OF_FILE.get(name[:-4], name[:-4])
    cfg = prepare(algo, load_hyperparams(HYPER / name, env_id))  # refuses an unknown or unsupported key
    env = gym.make(env_id, **cfg["env_kwargs"])
    try:
        env.reset(seed=0)
    finally:
        env.close()


def test_register_adds_apg_value_to_rl_zoo3():
    from rl_zoo3 import hyperparams_opt, utils

    register()
    assert utils.ALGOS["apg_value"] is APGValue
    assert all(utils.ALGOS[name] is cls for name, cls in ZOO_ALGOS.items())
    params = sample_apg_value_params(optuna.trial.FixedTrial({
        "gamma": 0.9, "learning_rate": 1e-3, "batch_size": 100, "target_update_interval": 1000,
        "exploration_final_eps": 0.1, "exploration_episodes": 1000, "imitation_episodes": 0, "imitation_epochs": 5,
        "gradient_steps": 1,
    }), 80, 1, {})
    assert hyperparams_opt.HYPERPARAMS_CONVERTER["apg_value"](params) == params
    model = APGValue("ApgPolicy", "CrowdNav-v0", **params)  # the sampled values are valid arguments
    assert model.gamma == 0.9 and model.imitation_episodes == 0


def test_zoo_algorithms_keep_the_apg_extractor_when_policy_kwargs_are_replaced():
    """The zoo's ppo and dqn resolve "ApgPolicy"; SB3's own classes are not changed and refuse the name."""
    ppo = ZOO_ALGOS["ppo"]("ApgPolicy", "CrowdNav-v0", n_steps=16, batch_size=16, policy_kwargs=dict(net_arch=[32]))
    assert isinstance(ppo.policy, ApgActorCriticPolicy)
    assert isinstance(ppo.policy.features_extractor, ApgExtractor)
    dqn = ZOO_ALGOS["dqn"]("ApgPolicy", "CrowdNav-v0", buffer_size=100, policy_kwargs=dict(net_arch=[32]))
    assert isinstance(dqn.policy, ApgDQNPolicy)
    assert isinstance(dqn.policy.q_net.features_extractor, ApgExtractor)
    assert isinstance(ZOO_ALGOS["a2c"]("ApgPolicy", "CrowdNav-v0", n_steps=8).policy, ApgActorCriticPolicy)
    for algo in (PPO, DQN):
        with pytest.raises(ValueError, match="ApgPolicy"):
            algo("ApgPolicy", "CrowdNav-v0")


def test_zoo_main_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        zoo_main(["fly"])
    assert exc.value.code == 2
    assert "usage" in capsys.readouterr().err


@pytest.mark.parametrize("given", [[], ["--num-threads", "2"], ["--num-threads=3"]])
def test_zoo_commands_run_one_torch_thread_unless_told(monkeypatch, given):
    """rl-zoo3 leaves torch every core; the package's entry point gives it the training floor's one thread."""
    import rl_zoo3.train

    seen = []
    monkeypatch.setattr(rl_zoo3.train, "train", lambda: seen.append(list(sys.argv)))
    monkeypatch.setattr(sys, "argv", list(sys.argv))
    zoo_main(["train", "--algo", "ppo", "--env", "CrowdNav-v0", *given])
    threads = [a for i, a in enumerate(seen[0]) if a.startswith("--num-threads") or seen[0][i - 1] == "--num-threads"]
    assert threads == (given or ["--num-threads", "1"])


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_rl_zoo3_trains_ppo_and_apg_value(tmp_path):
    """The documented commands through the package's zoo entry point: PPO from its file ("ApgPolicy"), APGValue
    (then enjoy); the PPO file loads with SB3's own class."""
    common = ["--env", "CrowdNav-v0", "-f", str(tmp_path), "--eval-freq", "-1", "--seed", "0"]
    zoo = [sys.executable, "-m", "sb3_crowdnav.training.zoo"]
    subprocess.run([*zoo, "train", "--algo", "ppo", "-conf", str(HYPER / "ppo.yml"), "-n", "128", *common,
                    "-params", "n_envs:1", "n_steps:64", "batch_size:32", "n_epochs:1"],
                   check=True, capture_output=True, timeout=300)
    saved_ppo = tmp_path / "ppo" / "CrowdNav-v0_1" / "CrowdNav-v0.zip"
    assert isinstance(PPO.load(saved_ppo).policy, ApgActorCriticPolicy)
    subprocess.run([*zoo, "train", "--algo", "apg_value", "-conf", str(HYPER / "apg_value.yml"), "-n", "40", *common,
                    "-params", "imitation_episodes:2", "imitation_epochs:1", "buffer_size:1000"],
                   check=True, capture_output=True, timeout=300)
    saved = tmp_path / "apg_value" / "CrowdNav-v0_1" / "CrowdNav-v0.zip"
    assert saved.exists() and APGValue.load(saved).imitation_done
    out = subprocess.run([*zoo, "enjoy", "--algo", "apg_value", "--env", "CrowdNav-v0", "-f", str(tmp_path),
                          "--no-render", "-n", "120"], check=True, capture_output=True, text=True, timeout=300)
    assert "Episodes" in out.stdout or "episode" in out.stdout.lower()


def test_zoo_evaluations_play_validation_episodes(tmp_path):
    """rl-zoo3 seeds its eval envs as its training envs; the package's zoo seeds them at the validation offset, so
    that --eval-freq's best model and every Optuna trial are scored on validation episodes, never training ones."""
    import argparse

    import gymnasium as gym
    import numpy as np

    from sb3_crowdnav.training import VALIDATION_SEED_OFFSET
    from sb3_crowdnav.training.zoo import experiment_manager

    manager = experiment_manager()(argparse.Namespace(), "ppo", "CrowdNav-v0", str(tmp_path), seed=7)
    assert experiment_manager() is type(manager)

    def first_people(vec_env) -> np.ndarray:  # the people of the first episode (the robot always starts alike)
        people = vec_env.reset()["humans"][0]
        vec_env.close()
        return people

    def seeded_people(seed: int) -> np.ndarray:
        return gym.make("CrowdNav-v0").reset(seed=seed)[0]["humans"]

    evaluation, training = first_people(manager.create_envs(1, eval_env=True)), first_people(manager.create_envs(1))
    np.testing.assert_array_equal(evaluation, seeded_people(VALIDATION_SEED_OFFSET))
    np.testing.assert_array_equal(training, seeded_people(7))
    assert not np.array_equal(evaluation, training)
    assert manager.seed == 7  # the training seed is restored


@pytest.mark.parametrize("given, people", [(None, 2), ({"num_humans": 4}, 4)])
def test_zoo_evaluations_play_the_files_world(tmp_path, given, people):
    """A file's env_kwargs reach the eval envs as well as the training envs (rl-zoo3 2.9 gives its eval envs only
    the command line's, so a study of the warehouse worlds of CrowdNavWorlds-v0 was scored on the open floor); an
    explicit --eval-env-kwargs still decides."""
    import argparse

    from stable_baselines3.common.callbacks import EvalCallback

    from sb3_crowdnav.training.zoo import experiment_manager

    register()  # "ApgPolicy" for SB3's algorithms, as the zoo's entry point does
    config = tmp_path / "ppo.yml"
    config.write_text(yaml.safe_dump({"CrowdNav-v0": {"policy": "ApgPolicy", "n_envs": 1, "n_timesteps": 64,
                                                      "n_steps": 32, "batch_size": 32, "env_kwargs": {"num_humans": 2}}}))
    manager = experiment_manager()(argparse.Namespace(), "ppo", "CrowdNav-v0", str(tmp_path / "logs"),
                                   config=str(config), eval_freq=32, n_eval_episodes=1, eval_env_kwargs=given, verbose=0)
    manager.setup_experiment()
    (evaluation,) = [c for c in manager.callbacks if isinstance(c, EvalCallback)]
    assert int(evaluation.eval_env.reset()["humans_mask"][0].sum()) == people
    assert manager.eval_env_kwargs == (given or {})  # (restored: rl-zoo3's own record is left as it was)
    training = manager.create_envs(1)
    assert int(training.reset()["humans_mask"][0].sum()) == 2


def test_imitation_settings_come_from_the_file_or_the_caller_once():
    """A hyperparameter file's imitation_* keys are what the command line's --imitation-* give; both at once must
    agree; APGValue keeps its own imitation_* hyperparameters; an algorithm without imitation refuses them."""
    from sb3_crowdnav.training.hyperparams import imitation_settings, prepare

    cfg = prepare("dqn", {"policy": "ApgPolicy", "imitation_episodes": 30, "imitation_epochs": 2})
    assert "imitation_episodes" not in cfg["kwargs"]
    assert imitation_settings("dqn", cfg) == {"imitation_episodes": 30, "imitation_epochs": 2,
                                              "imitation_learning_rate": 1e-3}
    assert imitation_settings("dqn", cfg, imitation_episodes=30)["imitation_episodes"] == 30
    assert imitation_settings("dqn", prepare("dqn", {}), imitation_episodes=5)["imitation_episodes"] == 5
    with pytest.raises(ValueError, match="imitation_episodes is 30 in the hyperparameter file and 5"):
        imitation_settings("dqn", cfg, imitation_episodes=5)
    with pytest.raises(ValueError, match="imitation_epochs"):
        imitation_settings("ppo", prepare("ppo", {"imitation_epochs": 0}))
    with pytest.raises(ValueError, match="dqfd"):
        imitation_settings("dqfd", prepare("dqfd", {}))
    assert prepare("apg_value", {"imitation_episodes": 7})["kwargs"]["imitation_episodes"] == 7
    with pytest.raises(ValueError, match="imitation_episodes"):
        prepare("recurrentppo", {"imitation_episodes": 7})
    # MaskablePPO clones the ORCA robot as PPO does, QR-DQN learns from it as DQN does; RecurrentPPO (an LSTM policy)
    # takes no imitation
    for algo in ("maskableppo", "qrdqn"):
        assert imitation_settings(algo, prepare(algo, {"imitation_episodes": 7}))["imitation_episodes"] == 7
    with pytest.raises(ValueError, match=r"imitation_episodes is for .*; recurrentppo takes no imitation"):
        imitation_settings("recurrentppo", prepare("recurrentppo", {}), imitation_episodes=7)


def _dqn(imitation_episodes: int, algo: str = "dqn", **kwargs):
    from stable_baselines3.common.env_util import make_vec_env

    env = make_vec_env("CrowdNav-v0", n_envs=1, seed=0, env_kwargs={"num_humans": 2})
    extra = {"policy_kwargs": {"n_quantiles": 8}} if algo == "qrdqn" else {}
    return ZOO_ALGOS[algo]("ApgPolicy", env, seed=0, buffer_size=5_000, learning_starts=10_000,
                           imitation_episodes=imitation_episodes, imitation_epochs=1, **extra, **kwargs)


@pytest.mark.parametrize("algo", ["dqn", "qrdqn"])
def test_the_zoo_dqn_imitates_once_before_its_first_learn(tmp_path, algo):
    """imitation_episodes fills the replay buffer with the ORCA robot's episodes (and trains on them) at the first
    learn() only: a second learn() and a loaded model do not imitate again (DQN and QR-DQN)."""
    plain, model = _dqn(0, algo), _dqn(3, algo)
    assert plain.imitated and not model.imitated
    plain.learn(8)
    assert plain.replay_buffer.size() == 8
    model.learn(8)
    demonstrations = model.replay_buffer.size() - 8
    assert model.imitated and demonstrations > 3  # three whole episodes, each several steps
    model.learn(8, reset_num_timesteps=False)
    assert model.replay_buffer.size() == demonstrations + 16
    model.save(tmp_path / "dqn.zip")
    loaded = ZOO_ALGOS[algo].load(tmp_path / "dqn.zip", env=model.env)
    assert loaded.imitated and loaded.imitation_episodes == 3


@pytest.mark.parametrize("algo", ["ppo", "maskableppo"])
def test_the_zoo_ppo_imitates_the_orca_robot(algo):
    """Behaviour cloning before PPO's (and MaskablePPO's, in the warehouse behind its wall masks) first update: the
    policy moves towards the demonstrated actions."""
    import torch as th
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_crowdnav.apg_value.action_masks import WallActionMasker
    from sb3_crowdnav.imitation import collect_demonstrations

    env_id, wrapper = ("CrowdNav-v0", None) if algo == "ppo" else ("CrowdNavWarehouse-v0", WallActionMasker)

    def envs(seed):
        return make_vec_env(env_id, n_envs=1, seed=seed, env_kwargs={"num_humans": 2}, wrapper_class=wrapper)

    def ppo(episodes):
        return ZOO_ALGOS[algo]("ApgPolicy", envs(0), seed=0, n_steps=64, batch_size=32, imitation_episodes=episodes,
                               imitation_epochs=3)

    demos = collect_demonstrations(envs(5), 3)

    def log_likelihood(model):
        obs, _ = model.policy.obs_to_tensor({k: v for k, v in demos.observations.items()})
        with th.no_grad():
            _, log_prob, _ = model.policy.evaluate_actions(obs, th.as_tensor(demos.actions).flatten())
        return float(log_prob.mean())

    plain, imitating = ppo(0), ppo(20)
    imitating.learn(0)  # the imitation alone (no env step)
    assert imitating.imitated and imitating.num_timesteps == 0
    assert log_likelihood(imitating) > log_likelihood(plain) + 0.5


@pytest.mark.parametrize(("kwargs", "name"), [({"imitation_episodes": -1}, "imitation_episodes"),
                                              ({"imitation_episodes": 2, "imitation_epochs": 0}, "imitation_epochs"),
                                              ({"imitation_learning_rate": 0.0}, "imitation_learning_rate")])
def test_bad_imitation_hyperparameters_are_refused_at_construction(kwargs, name):
    from stable_baselines3.common.env_util import make_vec_env

    env = make_vec_env("CrowdNav-v0", n_envs=1, seed=0)
    with pytest.raises(ValueError, match=name):
        ZOO_ALGOS["ppo"]("ApgPolicy", env, **kwargs)
