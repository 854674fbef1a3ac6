"""Loading a model never runs code from the file; shipped weights are checked by SHA-256."""

from __future__ import annotations

import base64
import json
import pickle
import shutil
import zipfile
from pathlib import Path

import gymnasium as gym
import pytest

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav import models
from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.cli import main
from sb3_crowdnav.evaluation.runner import make_policy
from sb3_crowdnav.models import load_model, pretrained
from sb3_crowdnav.serialization import SPACES_MEMBER, UnsafeModelFileError, decode


class _Payload:
    """Unpickling this writes a marker file: the kind of thing a hostile model file can do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "pwned"))


def _hostile_copy(tmp_path: Path, entry: str, name: str = "apg_rl") -> tuple[Path, Path]:
    """A copy of a shipped model whose ``entry`` holds a pickle that writes ``marker`` when unpickled."""
    marker = tmp_path / f"marker_{entry}"
    source = models.WEIGHTS_DIR / f"{name}.zip"
    target = tmp_path / f"hostile_{entry}.zip"
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(target, "w") as dst:
        for item in src.namelist():
            content = src.read(item)
            if item == "data":
                data = json.loads(content)
                data[entry] = {":type:": "<class 'type'>",
                               ":serialized:": base64.b64encode(pickle.dumps(_Payload(marker))).decode()}
                content = json.dumps(data).encode()
            dst.writestr(item, content)
    return target, marker


@pytest.mark.parametrize("entry", ["policy_class", "policy_kwargs", "train_freq", "replay_buffer_class",
                                   "imitation_optimizer_class", "unknown_entry"])
def test_no_loader_runs_a_hostile_entry(tmp_path, capsys, entry):
    path, marker = _hostile_copy(tmp_path, entry)
    env = gym.make("CrowdNav-v0")
    for load in (lambda: APGValue.load(path), lambda: APGValue.load(path, env=env), lambda: load_model(path),
                 lambda: make_policy(str(path), env)):
        with pytest.raises(UnsafeModelFileError, match=f"entry '{entry}'"):
            load()
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--policy", str(path), "--episodes", "1"])
    assert exc.value.code == 2 and f"entry '{entry}'" in capsys.readouterr().err
    assert not marker.exists()


def test_the_threat_is_real_with_trusted(tmp_path):
    """The same file does run its payload through SB3's own load (trusted=True): the refusal above matters."""
    path, marker = _hostile_copy(tmp_path, "unknown_entry")
    APGValue.load(path, trusted=True)
    assert marker.read_text() == "pwned"


def test_spaces_without_the_plain_member_need_the_env(tmp_path):
    source = models.WEIGHTS_DIR / "apg_rl.zip"
    stripped = tmp_path / "stripped.zip"
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(stripped, "w") as dst:
        for item in src.namelist():
            if item != SPACES_MEMBER:
                dst.writestr(item, src.read(item))
    with pytest.raises(UnsafeModelFileError, match="entry 'observation_space'"):
        APGValue.load(stripped)
    env = gym.make("CrowdNav-v0")
    model = APGValue.load(stripped, env=env)  # the env's spaces, after the file's shapes are checked against them
    assert model.observation_space == env.observation_space
    with pytest.raises(UnsafeModelFileError, match="max_humans"):
        APGValue.load(stripped, env=gym.make("CrowdNav-v0", max_humans=5, num_humans=5))


def test_decode_reads_data_and_allowed_classes_only():
    import torch as th
    from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit

    value = {"optimizer_class": th.optim.Adam, "net_arch": [150, 100], "gamma": 0.9, "flag": True, "none": None,
             "pair": (1, "a")}
    assert decode(pickle.dumps(value, protocol=5)) == value
    assert decode(pickle.dumps(TrainFreq(4, TrainFrequencyUnit.STEP), protocol=5)) == TrainFreq(4, TrainFrequencyUnit.STEP)
    for hostile in (pickle.dumps(print), pickle.dumps(Path("x")), pickle.dumps(_Payload(Path("never")))):
        with pytest.raises(UnsafeModelFileError):
            decode(hostile)


def test_a_tampered_shipped_weight_is_refused(tmp_path, monkeypatch):
    weights = tmp_path / "weights"
    shutil.copytree(models.WEIGHTS_DIR, weights)
    with zipfile.ZipFile(weights / "apg_rl.zip", "a") as archive:
        archive.writestr("extra.txt", "changed")
    monkeypatch.setattr(models, "WEIGHTS_DIR", weights)
    with pytest.raises(ValueError, match=r"apg_rl\.zip does not match the SHA-256 pinned for .apg_rl."):
        pretrained("apg_rl")
    with pytest.raises(ValueError, match="SHA-256"):
        make_policy("pretrained:apg_rl")
    assert pretrained("cadrl").policy is not None  # the untouched ones still load


def test_every_shipped_model_loads_safely_without_an_env():
    for name in models.available_pretrained():
        model = pretrained(name)
        assert model.observation_space is not None


@pytest.mark.parametrize(("option", "value", "name", "env_kwargs"), [
    ("--kinematics", "holonomic", "kinematics", {"kinematics": "holonomic"}),
    ("--env-kwargs", "dict(time_step=0.5)", "time_step", {"time_step": 0.5}),
    ("--env-kwargs", "dict(rotation_range=1.5)", "rotation_range", {"rotation_range": 1.5}),
])
@pytest.mark.parametrize("policy", ["pretrained:apg_rl", "pretrained:ppo_apg"])
def test_a_model_is_never_silently_evaluated_in_another_world(tmp_path, capsys, option, value, name, env_kwargs,
                                                                policy):
    for command in (["evaluate"], ["benchmark", "--out", str(tmp_path / "b"), "--no-gif"],
                    ["render", "--out", str(tmp_path / "e.png")]):
        with pytest.raises(SystemExit) as exc:
            main([*command, "--policy", policy, option, value, "--episodes", "1"][: None if command[0] != "render"
                                                                                   else -2])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and f"trained with {name}=" in err and "--allow-env-mismatch" in err
        assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "b").exists()  # refused before any work
    assert main(["evaluate", "--policy", policy, option, value, "--episodes", "1", "--allow-env-mismatch"]) == 0
    env = gym.make("CrowdNav-v0", **env_kwargs)
    with pytest.raises(ValueError, match=f"trained with {name}="):
        make_policy(policy, env)
    assert make_policy(policy, env, allow_env_mismatch=True) is not None


def test_a_model_takes_the_env_bounds_when_only_the_bounds_differ():
    """A faster crowd widens the env's observation bounds (the shapes stay): a shipped model loads there and acts as in
    its own env on the same observation; another layout (max_humans) is still refused."""
    from sb3_crowdnav.models import pretrained
    from sb3_crowdnav.serialization import same_layout

    own, fast = gym.make("CrowdNav-v0"), gym.make("CrowdNav-v0", human_speed="measured")
    assert own.observation_space != fast.observation_space and same_layout(own.observation_space,
                                                                            fast.observation_space)
    a, b = pretrained("apg_rl", env=own), pretrained("apg_rl", env=fast)
    assert b.observation_space == fast.observation_space
    obs, _ = own.reset(seed=3)
    assert a.predict(obs, deterministic=True)[0] == b.predict(obs, deterministic=True)[0]
    other = gym.make("CrowdNav-v0", max_humans=7, num_humans=5)
    assert not same_layout(own.observation_space, other.observation_space)
    with pytest.raises(ValueError):
        pretrained("apg_rl", env=other)
