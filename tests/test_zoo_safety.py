"""sb3-crowdnav-zoo never runs code from what it reads: hyperparameter files, key:value options, saved runs, models.
Each hostile input here would run its payload under plain rl-zoo3 (it writes a marker file); the zoo refuses it
with exit 2 and one line, and the marker stays absent."""

from __future__ import annotations

import io
from collections import OrderedDict
from pathlib import Path

import pytest
import yaml

from sb3_crowdnav.serialization import UnsafeModelFileError
from sb3_crowdnav.training import zoo_safety
from sb3_crowdnav.training.zoo import ZOO_ALGOS, register
from sb3_crowdnav.training.zoo import main as zoo_main

FILE = "CrowdNav-v0:\n  n_timesteps: 8\n  policy: 'ApgPolicy'\n  n_steps: 8\n  batch_size: 8\n"


def _zoo(tmp_path, capsys, *argv) -> str:
    with pytest.raises(SystemExit) as exc:
        zoo_main(["train", "--algo", "ppo", "--env", "CrowdNav-v0", "-f", str(tmp_path / "logs"), *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    return err[-1]


@pytest.mark.parametrize("line", [
    "  policy_kwargs: \"dict(net_arch=[8]) if __import__('pathlib').Path('{m}').write_text('x') else None\"\n",
    "  callback:\n    - pathlib.Path.write_text:\n        self: '{m}'\n        data: x\n",
    "  callback:\n    - subprocess.Popen:\n        args: 'touch {m}'\n        shell: true\n",
    "  env_wrapper: os.system\n",
    "  normalize: \"__import__('pathlib').Path('{m}').write_text('x')\"\n",
    "  replay_buffer_class: \"__import__('pathlib').Path('{m}').write_text('x')\"\n",
])
def test_a_hostile_hyperparameter_file_is_refused_before_it_runs(tmp_path, capsys, line):
    marker = tmp_path / "marker"
    conf = tmp_path / "hostile.yml"
    conf.write_text(FILE + line.format(m=marker))
    message = _zoo(tmp_path, capsys, "-conf", str(conf))
    assert message.startswith("sb3-crowdnav-zoo train: error: ")
    assert any(key in message for key in ("policy_kwargs", "callback", "env_wrapper", "normalize", "replay_buffer"))
    assert not marker.exists()


def test_a_python_config_is_refused_not_executed(tmp_path, capsys):
    marker = tmp_path / "marker"
    conf = tmp_path / "conf.py"
    conf.write_text(f"import pathlib\npathlib.Path({str(marker)!r}).write_text('x')\nhyperparams = {{}}\n")
    assert "reads YAML hyperparameter files only" in _zoo(tmp_path, capsys, "-conf", str(conf))
    assert not marker.exists()


def test_key_value_options_are_parsed_not_executed(tmp_path, capsys):
    marker = tmp_path / "marker"
    conf = tmp_path / "ok.yml"
    conf.write_text(FILE)
    code = f"__import__('pathlib').Path('{marker}').write_text('x')"
    for option in ("--hyperparams", "--env-kwargs"):
        with pytest.raises(SystemExit) as exc:
            zoo_main(["train", "--algo", "ppo", "--env", "CrowdNav-v0", "-conf", str(conf), option, f"n_steps:{code}"])
        assert exc.value.code == 2 and "is not allowed" in capsys.readouterr().err
    assert not marker.exists()
    parsed = {}
    zoo_safety.SafeStoreDict(["--env-kwargs"], "env_kwargs", nargs="+")(
        None, type("NS", (), {"__setattr__": lambda self, k, v: parsed.update({k: v})})(),
        ["num_humans:10", "crowd:'social_force'", "pair:dict(a=[1, 2])"])
    assert parsed["env_kwargs"] == {"num_humans": 10, "crowd": "social_force", "pair": {"a": [1, 2]}}


def test_the_files_own_wrappers_callbacks_and_buffers_pass():
    from stable_baselines3.common.callbacks import CheckpointCallback  # noqa: F401 (named below)

    from sb3_crowdnav.nn.buffers import NStepDictReplayBuffer

    hp = zoo_safety.checked_hyperparams({
        "env_wrapper": "sb3_crowdnav.apg_value.action_masks.WallActionMasker",
        "callback": [{"stable_baselines3.common.callbacks.CheckpointCallback": {"save_freq": 10, "save_path": "x"}}],
        "policy_kwargs": "dict(net_arch=[64, 64], activation_fn=nn.ReLU)",
        "normalize": "dict(norm_obs=False, norm_reward=True)",
        "replay_buffer_class": "NStepDictReplayBuffer"})
    import torch.nn as nn

    assert hp["policy_kwargs"] == {"net_arch": [64, 64], "activation_fn": nn.ReLU}
    assert hp["normalize"] == {"norm_obs": False, "norm_reward": True}
    assert hp["replay_buffer_class"] is NStepDictReplayBuffer
    assert hp["env_wrapper"] == "sb3_crowdnav.apg_value.action_masks.WallActionMasker"  # checked, left to rl-zoo3
    for key, name in (("env_wrapper", "collections.OrderedDict"), ("vec_env_wrapper", "gymnasium.Wrapper"),
                      ("callback", "sb3_crowdnav.apg_value.action_masks.WallActionMasker"), ("env_wrapper", "nowhere.X"),
                      ("env_wrapper", "antigravity.Wrapper")):
        with pytest.raises(zoo_safety.RefusedInput, match=key):
            zoo_safety.checked_hyperparams({key: name})
    import sys

    assert "antigravity" not in sys.modules  # refused before any import (importing it opens a web browser)


def test_saved_runs_are_read_as_plain_data(tmp_path):
    saved = yaml.dump(OrderedDict([("n_steps", 8), ("normalize", "dict(norm_obs=False)"), ("policy", "ApgPolicy")]))
    assert saved.startswith("!!python/object/apply:collections.OrderedDict")  # what rl-zoo3 writes
    loaded = zoo_safety.load_yaml(io.StringIO(saved), Loader=yaml.UnsafeLoader)
    assert loaded == {"n_steps": 8, "normalize": {"norm_obs": False}, "policy": "ApgPolicy"}
    marker = tmp_path / "marker"
    payload = f"!!python/object/apply:os.system ['touch {marker}']"
    for hostile in (f"{payload}\n", f"!!python/object/apply:collections.OrderedDict [[[k, {payload}]]]\n"):
        with pytest.raises(yaml.YAMLError):
            zoo_safety.load_yaml(io.StringIO(hostile), Loader=yaml.UnsafeLoader)
    with pytest.raises(zoo_safety.RefusedInput, match="normalize"):
        zoo_safety.load_yaml(io.StringIO(f"normalize: \"__import__('os').system('touch {marker}')\"\n"))
    assert not marker.exists()


def test_the_zoos_algorithms_load_without_unpickling_and_save_their_spaces(tmp_path):
    import gymnasium as gym

    from sb3_crowdnav.serialization import SPACES_MEMBER
    from tests.test_security import _hostile_copy

    path, marker = _hostile_copy(tmp_path, "policy_class", name="ppo_apg")
    with pytest.raises(UnsafeModelFileError, match="entry 'policy_class'"):
        ZOO_ALGOS["ppo"].load(path)
    assert not marker.exists()
    register()
    env = gym.make("CrowdNav-v0", human_policy="linear", num_humans=2)
    model = ZOO_ALGOS["ppo"]("ApgPolicy", env, n_steps=8, batch_size=8)
    model.save(tmp_path / "saved")  # SB3 adds .zip
    import zipfile

    assert SPACES_MEMBER in zipfile.ZipFile(tmp_path / "saved.zip").namelist()
    loaded = ZOO_ALGOS["ppo"].load(tmp_path / "saved")  # no env: the spaces come from the plain member
    assert loaded.observation_space == model.observation_space


def test_every_zoo_algorithm_can_be_tuned_and_keeps_the_files_policy_kwargs():
    from rl_zoo3 import hyperparams_opt

    from sb3_crowdnav.training.zoo import _over_policy_kwargs

    register()
    for algo in ZOO_ALGOS:
        assert algo in hyperparams_opt.HYPERPARAMS_SAMPLER and algo in hyperparams_opt.HYPERPARAMS_CONVERTER, algo
    merged = _over_policy_kwargs(lambda *a: {"gamma": 0.9, "policy_kwargs": {"net_arch": [8]}},
                                 {"lstm_hidden_size": 128, "net_arch": [64]}, None)
    assert merged == {"gamma": 0.9, "policy_kwargs": {"lstm_hidden_size": 128, "net_arch": [8]}}


@pytest.mark.parametrize("path", sorted((Path(__file__).parent.parent / "zoo_hyperparams").glob("*.yml")),
                         ids=lambda p: p.name)
def test_every_shipped_hyperparameter_file_passes(path):
    for env_id, entry in yaml.safe_load(path.read_text()).items():
        checked = zoo_safety.checked_hyperparams(dict(entry))
        assert not isinstance(checked.get("policy_kwargs"), str), (path.name, env_id)


def test_the_zoos_replay_buffers_are_plain_arrays_and_a_pickle_is_refused(tmp_path):
    import gymnasium as gym
    import numpy as np

    from tests.test_security import _Payload

    register()
    env = gym.make("CrowdNav-v0", human_policy="linear", num_humans=2)
    model = ZOO_ALGOS["dqn"]("ApgPolicy", env, buffer_size=64, learning_starts=8, batch_size=8)
    model.learn(16)
    model.save_replay_buffer(tmp_path / "replay_buffer.pkl")  # rl-zoo3's name, plain arrays inside
    again = ZOO_ALGOS["dqn"]("ApgPolicy", env, buffer_size=64)
    again.load_replay_buffer(tmp_path / "replay_buffer.pkl")
    assert again.replay_buffer.pos == model.replay_buffer.pos == 16
    assert np.array_equal(again.replay_buffer.rewards, model.replay_buffer.rewards)
    marker = tmp_path / "marker"
    (tmp_path / "hostile.pkl").write_bytes(__import__("pickle").dumps(_Payload(marker)))
    with pytest.raises(zoo_safety.RefusedInput, match="pickled replay buffer"):
        again.load_replay_buffer(tmp_path / "hostile.pkl")
    assert not marker.exists()


def test_trusted_restores_sb3s_own_loads(tmp_path):
    """trusted=True (files you made yourself) loads as SB3 does: the refusals above are what the default adds."""
    import pickle

    import gymnasium as gym
    from stable_baselines3.common.save_util import save_to_pkl

    from tests.test_security import _hostile_copy

    path, marker = _hostile_copy(tmp_path, "unknown_entry", name="ppo_apg")
    ZOO_ALGOS["ppo"].load(path, trusted=True)
    assert marker.read_text() == "pwned"
    register()
    env = gym.make("CrowdNav-v0", human_policy="linear", num_humans=2)
    model = ZOO_ALGOS["dqn"]("ApgPolicy", env, buffer_size=64, learning_starts=8, batch_size=8)
    model.learn(16)
    save_to_pkl(tmp_path / "sb3_buffer.pkl", model.replay_buffer)  # SB3's own format, a pickle
    assert pickle.loads((tmp_path / "sb3_buffer.pkl").read_bytes()).pos == 16
    again = ZOO_ALGOS["dqn"]("ApgPolicy", env, buffer_size=64)
    with pytest.raises(zoo_safety.RefusedInput):
        again.load_replay_buffer(tmp_path / "sb3_buffer.pkl")
    again.load_replay_buffer(tmp_path / "sb3_buffer.pkl", trusted=True)
    assert again.replay_buffer.pos == 16
