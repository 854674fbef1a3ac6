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
    # every shipped model acts in the world it was trained in (pretrained_env): the paper-world warehouse models'
    # robot has 80 actions and no limits
    from sb3_crowdnav.models import pretrained_env

    for name in sb3_crowdnav.available_pretrained():
        model = sb3_crowdnav.pretrained(name)
        env_id, kwargs = pretrained_env(name)
        env = gym.make(env_id, **kwargs)
        obs, _ = env.reset(seed=1_000_000)
        assert ("obstacles" in model.observation_space.spaces) == (env_id == "CrowdNavWarehouse-v0") == ("warehouse" in name)
        action, _ = model.predict(obs, deterministic=True)
        assert env.action_space.contains(int(action))
        assert policy_label(f"pretrained:{name}") == name.upper()
        assert make_policy(f"pretrained:{name}", env).predict(obs, deterministic=True)[0] == action


def test_a_shipped_warehouse_model_in_the_default_warehouse_is_told_its_world():
    """The default warehouse robot (a stop, limits) is not the one the shipped models learnt: refused, naming the
    keywords that give them their world."""
    with pytest.raises(ValueError, match="make the env with actions='paper', max_acceleration=None, max_turn_rate=None"):
        make_policy("pretrained:apg_warehouse_paper", gym.make("CrowdNavWarehouse-v0"))


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
def test_shipped_apg_warehouse_paper_is_the_documented_cautious_value_ensemble_and_navigates():
    """apg_warehouse_paper: V the mean of two networks, the cautious lookahead; it drives test episodes home."""
    import torch as th

    from sb3_crowdnav.apg_value.policies import ValueEnsemble
    from sb3_crowdnav.evaluation import run_episodes

    model = sb3_crowdnav.pretrained("apg_warehouse_paper")
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
    records = run_episodes("pretrained:apg_warehouse_paper", 10, env_id="CrowdNavWarehouse-v0",
                           env_kwargs=PAPER_WAREHOUSE)
    assert sum(r.outcome == "success" for r in records) >= 8


def test_every_shipped_model_names_the_env_it_was_trained_for():
    from sb3_crowdnav.models import PRETRAINED, pretrained_env, world_mismatch

    for name in ("apg_rl", "apg_warehouse_paper", "ppo_warehouse"):
        env_id, kwargs = pretrained_env(name)
        env = gym.make(env_id, **kwargs)
        assert world_mismatch(sb3_crowdnav.models.check_pretrained(name), env) is None, name
        env.close()
    assert pretrained_env("apg_warehouse_paper")[1]["actions"] == "paper"
    assert {pretrained_env(name)[0] for name in PRETRAINED} <= {"CrowdNav-v0", "CrowdNavWarehouse-v0"}
    with pytest.raises(ValueError, match="unknown pretrained model 'nope'"):
        pretrained_env("nope")
