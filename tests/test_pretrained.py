"""Shipped models and the policy specs of the evaluation harness."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sb3_crowdnav
from sb3_crowdnav.evaluation.runner import make_policy, policy_label
from sb3_crowdnav.models import PRETRAINED, pretrained_path
from sb3_crowdnav.sim.warehouse.config import PAPER_WAREHOUSE


def test_unknown_or_missing_pretrained_name_raises():
    with pytest.raises(ValueError, match="known"):
        sb3_crowdnav.pretrained("sarl_v9")
    missing = [n for n in PRETRAINED if n not in sb3_crowdnav.available_pretrained()]
    for name in missing:
        with pytest.raises(ValueError, match="not shipped"):
            pretrained_path(name)


def test_every_shipped_model_loads_and_drives():
    # the shipped warehouse models act in the world they were trained in: the paper's robot (80 actions, no limits)
    envs = {"CrowdNav-v0": gym.make("CrowdNav-v0"),
            "CrowdNavWarehouse-v0": gym.make("CrowdNavWarehouse-v0", **PAPER_WAREHOUSE)}
    observations = {env_id: env.reset(seed=1_000_000)[0] for env_id, env in envs.items()}
    for name in sb3_crowdnav.available_pretrained():
        model = sb3_crowdnav.pretrained(name)
        env_id = "CrowdNavWarehouse-v0" if "obstacles" in model.observation_space.spaces else "CrowdNav-v0"
        env, obs = envs[env_id], observations[env_id]
        assert (name.endswith("_warehouse")) == (env_id == "CrowdNavWarehouse-v0")
        action, _ = model.predict(obs, deterministic=True)
        assert 0 <= int(action) < 80
        assert policy_label(f"pretrained:{name}") == name.upper()
        assert make_policy(f"pretrained:{name}", env).predict(obs, deterministic=True)[0] == action


def test_a_shipped_warehouse_model_in_the_default_warehouse_is_told_its_world():
    """The default warehouse robot (a stop, limits) is not the one the shipped models learnt: refused, naming the
    keywords that give them their world."""
    with pytest.raises(ValueError, match="make the env with actions='paper', max_acceleration=None, max_turn_rate=None"):
        make_policy("pretrained:apg_warehouse", gym.make("CrowdNavWarehouse-v0"))


def test_orca_specs_pick_the_mapping():
    env = gym.make("CrowdNav-v0")
    assert make_policy("orca", env).mapping == "nearest"
    assert make_policy("orca-constrained", env).mapping == "constrained"
    assert policy_label("orca-constrained") == "ORCA-constrained"
    obs, _ = env.reset(seed=0)
    assert np.ndim(make_policy("orca-constrained", env).predict(obs)[0]) == 0


def test_shipped_apg_rl_navigates():
    """The shipped APG_RL model is a trained policy, not a placeholder: it crosses the crowd."""
    from sb3_crowdnav.evaluation import run_episodes

    assert "apg_rl" in sb3_crowdnav.available_pretrained()
    records = run_episodes("pretrained:apg_rl", 10)
    assert sum(r.outcome == "success" for r in records) >= 8


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_shipped_apg_warehouse_is_the_documented_cautious_value_ensemble_and_navigates():
    """The README's apg_warehouse: V the mean of two networks, the cautious lookahead; it drives test episodes home."""
    import torch as th

    from sb3_crowdnav.apg_value.policies import ValueEnsemble
    from sb3_crowdnav.evaluation import run_episodes

    model = sb3_crowdnav.pretrained("apg_warehouse")
    value_net = model.policy.value_net
    assert isinstance(value_net, ValueEnsemble) and len(value_net.members) == 2
    assert model.policy.pedestrian_model == "cautious"
    obs, _ = gym.make("CrowdNavWarehouse-v0", **PAPER_WAREHOUSE).reset(seed=1_000_000)
    tensors = {k: th.as_tensor(v[None], dtype=th.float32) for k, v in obs.items()}
    with th.no_grad():
        values = [member(tensors) for member in value_net.members]
        assert not th.allclose(values[0], values[1])  # two different networks
        th.testing.assert_close(value_net(tensors), (values[0] + values[1]) / 2)
    # in its own world: the paper's robot among pickers who do not see it
    records = run_episodes("pretrained:apg_warehouse", 10, env_id="CrowdNavWarehouse-v0",
                           env_kwargs=PAPER_WAREHOUSE)
    assert sum(r.outcome == "success" for r in records) >= 8
