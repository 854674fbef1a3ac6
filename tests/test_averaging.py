"""Combining trained value models: weight averaging over checkpoints (``average_checkpoints``) and value ensembles
across runs (``ensemble_models``)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.apg_value.policies import ValueEnsemble
from sb3_crowdnav.models import load_model
from sb3_crowdnav.training import average_checkpoints, ensemble_models


def _saved(tmp_path, name, seed, policy="ApgPolicy", env_kwargs=None, **kwargs):
    model = APGValue(policy, gym.make("CrowdNav-v0", **(env_kwargs or {})), imitation_episodes=0, seed=seed, **kwargs)
    model.save(tmp_path / name)
    return model, tmp_path / f"{name}.zip"


def test_the_average_is_the_mean_of_the_weights_and_keeps_the_first_models_settings(tmp_path):
    models, paths = zip(*(_saved(tmp_path, f"m{i}", seed=i, learning_rate=1e-3 * (i + 1)) for i in range(3)), strict=True)
    average = average_checkpoints(paths)
    for name, tensor in average.policy.value_net.state_dict().items():
        expected = th.stack([m.policy.value_net.state_dict()[name] for m in models]).mean(0)
        th.testing.assert_close(tensor, expected, rtol=1e-6, atol=1e-7)
        th.testing.assert_close(average.policy.value_net_target.state_dict()[name], tensor)
        if tensor.dtype.is_floating_point and tensor.numel() > 1:  # the seeds gave different weights
            assert not th.equal(tensor, models[0].policy.value_net.state_dict()[name])
    assert average.learning_rate == models[0].learning_rate
    assert not average.policy.optimizer.state
    obs = average.observation_space.sample()
    action, _ = average.predict(obs, deterministic=True)  # a working model
    assert 0 <= int(action) < 80


def test_average_checkpoints_refuses_one_path_and_other_networks(tmp_path):
    _, apg = _saved(tmp_path, "apg", seed=0)
    _, sarl = _saved(tmp_path, "sarl", seed=0, policy="SarlPolicy")
    with pytest.raises(ValueError, match=r"paths: .*at least two"):
        average_checkpoints([apg])
    with pytest.raises(ValueError, match=r"paths: .*another value network"):
        average_checkpoints([apg, sarl])


# ----------------------------------------------------------------------------- value ensembles (ensemble_models)
def _mean_of_values(models, obs):
    tensors = {k: th.as_tensor(v[None], dtype=th.float32) for k, v in obs.items()}
    with th.no_grad():
        return th.stack([m.policy.value_net(tensors) for m in models]).mean(0)


def test_an_ensemble_acts_on_the_mean_of_its_members_values_and_saves_and_loads(tmp_path):
    models, paths = zip(*(_saved(tmp_path, f"m{i}", seed=i) for i in range(3)), strict=True)
    ensemble = ensemble_models(paths)
    assert isinstance(ensemble.policy.value_net, ValueEnsemble)
    assert ensemble.policy.ensemble_size == 3 and ensemble.policy_kwargs["ensemble_size"] == 3
    obs = ensemble.observation_space.sample()
    tensors = {k: th.as_tensor(v[None], dtype=th.float32) for k, v in obs.items()}
    with th.no_grad():
        value = ensemble.policy.value_net(tensors)
        target = ensemble.policy.value_net_target(tensors)
        single = models[0].policy.value_net(tensors)
    th.testing.assert_close(value, _mean_of_values(models, obs), rtol=1e-6, atol=1e-7)
    th.testing.assert_close(target, value)
    assert not th.allclose(value, single)  # the other members count
    # an ensemble of an ensemble and a model flattens to four members with equal weight
    ensemble.save(tmp_path / "ens")
    nested = ensemble_models([tmp_path / "ens.zip", paths[0]])
    assert nested.policy.ensemble_size == 4
    th.testing.assert_close(nested.policy.value_net(tensors).detach(),
                            _mean_of_values([*models, models[0]], obs), rtol=1e-6, atol=1e-7)
    loaded = load_model(tmp_path / "ens.zip", algo="apg_value")  # the package's loader, no unpickling
    batch = {k: v[None] for k, v in obs.items()}
    np.testing.assert_array_equal(loaded.policy.action_values(batch), ensemble.policy.action_values(batch))
    assert isinstance(loaded.policy.value_net, ValueEnsemble) and loaded.policy.ensemble_size == 3


def test_an_ensemble_keeps_the_first_models_pedestrian_model_and_trains(tmp_path):
    _, path0 = _saved(tmp_path, "a", seed=0, policy_kwargs={"pedestrian_model": "cautious"})
    _, path1 = _saved(tmp_path, "b", seed=1)
    ensemble = ensemble_models([path0, path1])
    assert ensemble.policy.pedestrian_model == "cautious"
    ensemble.set_env(gym.make("CrowdNav-v0"))
    ensemble.learning_starts = 32
    before = [p.detach().clone() for p in ensemble.policy.value_net.parameters()]
    ensemble.learn(total_timesteps=64)  # one loss on the mean: every member's weights move
    after = list(ensemble.policy.value_net.parameters())
    for member in ensemble.policy.value_net.members:
        moved = [not th.equal(b, a) for b, a in zip(before, after, strict=True)
                 if any(a is p for p in member.parameters())]
        assert any(moved)


def test_ensemble_models_refuses_one_path_other_worlds_and_other_networks(tmp_path):
    _, apg = _saved(tmp_path, "apg", seed=0)
    _, sarl = _saved(tmp_path, "sarl", seed=0, policy="SarlPolicy")
    _, wide = _saved(tmp_path, "wide", seed=0, policy_kwargs={"net_arch": [64, 64]})
    _, holonomic = _saved(tmp_path, "holo", seed=0, env_kwargs={"kinematics": "holonomic"})
    with pytest.raises(ValueError, match=r"paths: .*at least two"):
        ensemble_models([apg])
    with pytest.raises(ValueError, match=r"paths: .*features_extractor_class"):
        ensemble_models([apg, sarl])
    with pytest.raises(ValueError, match=r"paths: .*net_arch"):
        ensemble_models([apg, wide])
    with pytest.raises(ValueError, match=r"paths: .*kinematics"):
        ensemble_models([apg, holonomic])


@pytest.mark.parametrize(("size", "error", "message"), [
    (0, ValueError, "must be >= 1"), (-1, ValueError, "must be >= 1"),
    (1.5, TypeError, "must be an int"), (True, TypeError, "must be an int"), ("2", TypeError, "must be an int"),
])
def test_ensemble_size_must_be_a_positive_int(size, error, message):
    with pytest.raises(error, match=rf"ensemble_size {message}"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, policy_kwargs={"ensemble_size": size})


def test_a_value_ensemble_needs_two_members():
    model = APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0)
    with pytest.raises(ValueError, match=r"members: .*at least two"):
        ValueEnsemble([model.policy.value_net])
