"""Weight averaging over checkpoints (``sb3_crowdnav.training.average_checkpoints``)."""

from __future__ import annotations

import pytest
import torch as th

from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.training import average_checkpoints


def _saved(tmp_path, name, seed, policy="ApgPolicy", **kwargs):
    model = APGValue(policy, "CrowdNav-v0", imitation_episodes=0, seed=seed, **kwargs)
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
