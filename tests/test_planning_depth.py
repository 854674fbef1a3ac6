"""The lookahead's planning_depth: a d-step search before V, the same in numpy, in the graph, in the file and on the
command line."""

from __future__ import annotations

import functools
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from lookahead_helpers import assert_graph_decides_as_policy, random_observations, value_policy

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import APGValue
from sb3_crowdnav.apg_value.policies import STATIC_KEYS, ValueLookaheadPolicy
from sb3_crowdnav.deploy.graph import LookaheadDecision
from sb3_crowdnav.evaluation.runner import with_lookahead
from sb3_crowdnav.sim.observation import OBS_KEYS

WORLDS = {
    "warehouse": ("CrowdNavWarehouse-v0", {}, {"stopping_check": True}),
    "open floor": ("CrowdNav-v0", {}, {}),
    "limits and a stop, cautious": ("CrowdNav-v0", {"actions": "with_stop", "max_acceleration": 1.0,
                                                    "max_turn_rate": 2.0}, {"pedestrian_model": "cautious"}),
}


def _brute_force(policy: ValueLookaheadPolicy, obs: dict[str, np.ndarray], depth: int) -> np.ndarray:
    """Q of a depth-d search written out: every (observation, action) successor on its own, one step less deep."""
    policy.set_planning_depth(1)
    q1 = policy.action_values(obs)
    if depth == 1:
        return q1
    prop = policy.propagation(obs["robot"], obs["humans"], obs["humans_mask"],
                              {k: obs[k] for k in STATIC_KEYS if k in obs})
    b, n_actions = prop.reward.shape
    q = np.empty((b, n_actions))
    for i in range(b):
        successor = {"robot": prop.robot[i].astype(np.float32),
                     "humans": np.repeat(prop.humans[i:i + 1].astype(np.float32), n_actions, axis=0),
                     "humans_mask": np.repeat(prop.humans_mask[i:i + 1], n_actions, axis=0)}
        for key, value in prop.static.items():
            successor[key] = value[i].astype(np.float32) if value.ndim == 3 else \
                np.repeat(np.asarray(value[i:i + 1], dtype=np.float32), n_actions, axis=0)
        best = _brute_force(policy, successor, depth - 1).max(axis=1)
        q[i] = prop.reward[i] + prop.discount[i] * np.where(prop.terminal[i], 0.0, best)
    return q


@pytest.mark.parametrize("case", list(WORLDS))
def test_a_two_step_search_backs_up_the_best_successor(case):
    env_id, env_kwargs, policy_kwargs = WORLDS[case]
    env = gym.make(env_id, **env_kwargs)
    policy = value_policy(env, planning_depth=2, **policy_kwargs)
    obs = random_observations(env, 6 if env.unwrapped.world.has_limits else 2)  # 80 successors each on the open floor
    q2 = policy.action_values(obs)
    q, prop = policy.lookahead(obs)
    np.testing.assert_array_equal(q, q2)
    np.testing.assert_array_equal(q2[prop.terminal], prop.reward[prop.terminal])  # an episode's end has no future
    expected = _brute_force(policy, obs, 2)
    np.testing.assert_allclose(q2, expected, rtol=0, atol=1e-6)
    assert not np.allclose(q2, policy.action_values(obs), atol=1e-4)  # depth 1 (set by the brute force) differs
    if env.unwrapped.world.has_limits:  # each distinct successor searched once: the same as every one on its own
        policy.set_planning_depth(2)
        policy.lookahead_inputs = functools.partial(policy.lookahead_inputs, distinct=False)
        np.testing.assert_allclose(policy.action_values(obs), q2, rtol=0, atol=1e-6)


def test_planning_depth_is_refused_unless_an_int_of_one_or_more():
    env = gym.make("CrowdNav-v0")
    for bad, error in ((0, ValueError), (-1, ValueError), (1.5, TypeError), (True, TypeError), ("2", TypeError)):
        with pytest.raises(error, match="planning_depth"):
            value_policy(env, planning_depth=bad)
        with pytest.raises(error, match="planning_depth"):
            value_policy(env).set_planning_depth(bad)
    with pytest.raises(ValueError, match="planning_depth"):
        with_lookahead(APGValue("ApgPolicy", env, learning_starts=0), {"planning_depth": 0})


def test_the_depth_travels_in_the_model_file_and_only_when_deeper(tmp_path):
    env = gym.make("CrowdNavWarehouse-v0")
    model = APGValue("ApgPolicy", env, learning_starts=0, seed=0)
    assert "planning_depth" not in model.policy._get_constructor_parameters()
    model.save(tmp_path / "one")
    assert APGValue.load(tmp_path / "one", env=env).policy.planning_depth == 1
    with_lookahead(model, {"planning_depth": 2})
    model.save(tmp_path / "two")
    loaded = APGValue.load(tmp_path / "two", env=env)
    assert loaded.policy.planning_depth == 2
    obs = random_observations(env, 3)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])


def test_the_graph_searches_as_deep_as_the_policy():
    env = gym.make("CrowdNavWarehouse-v0")
    policy = value_policy(env, planning_depth=2, stopping_check=True)
    obs = random_observations(env, 4, seed=1)
    values = assert_graph_decides_as_policy(policy, obs)
    policy.set_planning_depth(1)
    with th.no_grad():
        one = LookaheadDecision(policy).eval()({k: th.as_tensor(v) for k, v in obs.items()})[1]
    np.testing.assert_allclose(one.numpy(), policy.action_values(obs), rtol=0, atol=1e-6)
    assert not np.allclose(one.numpy(), values, atol=1e-4)


@pytest.mark.parametrize("value", ["0", "two"])
def test_the_cli_refuses_a_bad_depth_with_one_line(value):
    out = subprocess.run([sys.executable, "-m", "sb3_crowdnav.cli", "evaluate", "--policy", "pretrained:apg_warehouse",
                          "--env", "CrowdNavWarehouse-v0", "--episodes", "1", "--planning-depth", value],
                         capture_output=True, text=True)
    assert out.returncode == 2
    assert "--planning-depth" in out.stderr and "positive integer" in out.stderr


def test_the_cli_refuses_a_depth_without_a_value_model():
    out = subprocess.run([sys.executable, "-m", "sb3_crowdnav.cli", "evaluate", "--policy", "orca", "--episodes", "1",
                          "--planning-depth", "2"], capture_output=True, text=True)
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1 and "--planning-depth" in out.stderr


def test_observation_keys_are_what_the_search_propagates():
    env = gym.make("CrowdNavWarehouse-v0")
    policy = value_policy(env)
    obs = random_observations(env, 2)
    prop = policy.propagation(obs["robot"], obs["humans"], obs["humans_mask"], {k: obs[k] for k in STATIC_KEYS})
    states, inverse = policy.successors(prop)
    assert set(states) == set(obs) and set(OBS_KEYS) <= set(states)
    assert all(v.dtype == np.float32 for v in states.values())
    rows = prop.robot.reshape(-1, prop.robot.shape[-1]).astype(np.float32)
    np.testing.assert_array_equal(states["robot"][inverse], rows)  # every pair finds its own state
    assert len(states["robot"]) < len(rows)  # under the limits, fewer distinct states than actions
