"""The lookahead's planning_width: a deeper search of the best k actions of each step only (a beam), the same in numpy,
in the graph, in the file and on the command line."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from lookahead_helpers import assert_graph_decides_as_policy, random_observations, value_policy

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import APGValue
from sb3_crowdnav.apg_value.search import best_actions
from sb3_crowdnav.deploy.metadata import GraphMetadata
from sb3_crowdnav.evaluation.runner import with_lookahead

WORLDS = {
    "warehouse": ("CrowdNavWarehouse-v0", {"stopping_check": True}),
    "open floor": ("CrowdNav-v0", {}),
}


class CountingNet(th.nn.Module):
    """V, counting the states it is asked for."""

    def __init__(self, net: th.nn.Module) -> None:
        super().__init__()
        self.net, self.states = net, 0

    def forward(self, observation):
        self.states += len(observation["robot"])
        return self.net(observation)


def test_best_actions_are_the_largest_values_ties_to_the_lower_index():
    q = np.array([[0.1, 0.5, 0.5, -1.0, 0.5], [3.0, 2.0, 1.0, 0.0, -1.0]])
    np.testing.assert_array_equal(best_actions(q, 3), [[1, 2, 4], [0, 1, 2]])
    np.testing.assert_array_equal(best_actions(q, 9), np.argsort(-q, axis=1, kind="stable"))


@pytest.mark.parametrize("case", list(WORLDS))
def test_a_beam_searches_its_best_actions_deeper_and_keeps_the_one_step_q_of_the_rest(case):
    env_id, policy_kwargs = WORLDS[case]
    env = gym.make(env_id)
    policy = value_policy(env, **policy_kwargs)
    obs = random_observations(env, 6 if env.unwrapped.world.has_limits else 3, seed=4)
    one = policy.action_values(obs)
    policy.set_planning_depth(2)
    every = policy.action_values(obs)
    policy.set_planning_width(5)
    beam = policy.action_values(obs)
    top = best_actions(one, 5)
    expanded = np.zeros(one.shape, dtype=bool)
    np.put_along_axis(expanded, top, True, axis=1)
    np.testing.assert_allclose(beam[expanded], every[expanded], rtol=0, atol=1e-6)  # searched as deep as every one
    np.testing.assert_array_equal(beam[~expanded], one[~expanded])  # the rest keep their one-step Q
    assert not np.allclose(beam, one, atol=1e-4) and not np.allclose(beam, every, atol=1e-4)
    policy.set_planning_width(env.action_space.n)  # as wide as the actions: every successor
    np.testing.assert_array_equal(policy.action_values(obs), every)


def test_a_beam_asks_v_for_its_actions_successors_only():
    env = gym.make("CrowdNav-v0")  # every action reaches its own state
    policy = value_policy(env, planning_depth=2, planning_width=3)
    obs = random_observations(env, 4, seed=2)
    b, n_actions = 4, env.action_space.n
    counting = CountingNet(policy.value_net)
    policy.lookahead(obs, net=counting)
    assert counting.states == b * n_actions + b * 3 * n_actions
    policy.set_planning(3, 2)
    counting.states = 0
    policy.lookahead(obs, net=counting)
    assert counting.states == b * n_actions * (1 + 2 + 2 * 2)


class LargestBatchNet(CountingNet):
    """V, keeping the most states it was asked for in one call."""

    def forward(self, observation):
        self.states = max(self.states, len(observation["robot"]))
        return self.net(observation)


def test_a_large_batch_is_searched_in_chunks_with_the_values_of_each_observation_alone():
    env = gym.make("CrowdNav-v0")
    policy = value_policy(env, planning_depth=2, planning_width=3)
    chunk = policy.ACTION_VALUE_CHUNK
    b, n_actions = 2 * chunk + 3, env.action_space.n  # two full chunks and a short one
    obs = random_observations(env, b, seed=3)
    largest = LargestBatchNet(policy.value_net)
    values = policy.action_values(obs, net=largest)
    assert values.shape == (b, n_actions)
    # V never sees more than a chunk's expansion (its deeper step: chunk x 3 x n_actions states), not the batch's
    assert largest.states == chunk * 3 * n_actions
    alone = np.concatenate([policy.action_values({k: v[i: i + 1] for k, v in obs.items()}) for i in range(b)])
    np.testing.assert_allclose(values, alone, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(values.argmax(axis=1), alone.argmax(axis=1))


def test_planning_width_is_refused_unless_an_int_of_one_or_more_with_a_deeper_search():
    env = gym.make("CrowdNav-v0")
    for bad, error in ((0, ValueError), (-1, ValueError), (1.5, TypeError), (True, TypeError), ("2", TypeError)):
        with pytest.raises(error, match="planning_width"):
            value_policy(env, planning_depth=2, planning_width=bad)
        with pytest.raises(error, match="planning_width"):
            value_policy(env, planning_depth=2).set_planning_width(bad)
    with pytest.raises(ValueError, match="planning_width=4 needs planning_depth > 1"):
        value_policy(env, planning_width=4)
    with pytest.raises(ValueError, match="needs planning_depth > 1"):
        value_policy(env).set_planning_width(4)
    policy = value_policy(env, planning_depth=2, planning_width=4)
    with pytest.raises(ValueError, match="needs planning_depth > 1"):
        policy.set_planning_depth(1)
    assert (policy.planning_depth, policy.planning_width) == (2, 4)  # a refused switch leaves the search as it was


def test_with_lookahead_sets_the_width_and_a_depth_of_one_drops_it(tmp_path):
    env = gym.make("CrowdNav-v0")
    model = APGValue("ApgPolicy", env, learning_starts=0, seed=0)
    with_lookahead(model, {"planning_depth": 2, "planning_width": 6})
    assert (model.policy.planning_depth, model.policy.planning_width) == (2, 6)
    with_lookahead(model, {"planning_depth": 3})  # the width stays with a deeper depth
    assert (model.policy.planning_depth, model.policy.planning_width) == (3, 6)
    with_lookahead(model, {"planning_depth": 1})
    assert (model.policy.planning_depth, model.policy.planning_width) == (1, None)
    with pytest.raises(ValueError, match="needs planning_depth > 1"):
        with_lookahead(model, {"planning_depth": 1, "planning_width": 6})


def test_the_width_travels_in_the_model_file_and_only_when_set(tmp_path):
    env = gym.make("CrowdNav-v0")
    model = APGValue("ApgPolicy", env, learning_starts=0, seed=0)
    with_lookahead(model, {"planning_depth": 2})
    assert "planning_width" not in model.policy._get_constructor_parameters()
    with_lookahead(model, {"planning_width": 4})
    model.save(tmp_path / "beam")
    loaded = APGValue.load(tmp_path / "beam", env=env)
    assert (loaded.policy.planning_depth, loaded.policy.planning_width) == (2, 4)
    obs = random_observations(env, 3)
    np.testing.assert_array_equal(loaded.policy.action_values(obs), model.policy.action_values(obs))
    with_lookahead(loaded, {"planning_depth": 1})
    loaded.save(tmp_path / "one")
    assert APGValue.load(tmp_path / "one", env=env).policy.planning_width is None


@pytest.mark.parametrize("case", list(WORLDS))
def test_the_graph_expands_the_same_actions_as_the_policy(case):
    env_id, policy_kwargs = WORLDS[case]
    env = gym.make(env_id)
    policy = value_policy(env, planning_depth=2, planning_width=4, **policy_kwargs)
    assert_graph_decides_as_policy(policy, random_observations(env, 6, seed=5))


def test_the_graph_contract_records_the_width_and_reads_older_formats_as_every_successor():
    from sb3_crowdnav.deploy.metadata import PREFIX
    from sb3_crowdnav.sim.observation import ObservationSchema
    from sb3_crowdnav.sim.world import World

    common = dict(kind="lookahead", world=World(), schema=ObservationSchema(5, 10), robot_radius=0.3,
                  robot_v_pref=1.0, policy="ValueLookaheadPolicy", extractor="ApgExtractor", gamma=0.9,
                  pedestrian_model="constant_velocity")
    meta = GraphMetadata(planning_depth=2, planning_width=8, **common)
    assert GraphMetadata.from_props(meta.props()).planning_width == 8
    props = meta.props()
    import json

    decision = json.loads(props[PREFIX + "decision"])
    del decision["planning_width"]
    older = {**props, PREFIX + "decision": json.dumps(decision), PREFIX + "format": "3"}
    assert GraphMetadata.from_props(older).planning_width is None
    with pytest.raises(ValueError, match="planning_width is set for a lookahead of planning_depth > 1"):
        GraphMetadata(planning_depth=1, planning_width=8, **common)


def test_the_cli_refuses_a_width_without_a_deeper_search_with_one_line():
    # apg_rl acts with one step; apg_robust ships searching two, so a width is refused once --planning-depth 1 is asked
    stop = ["--env-kwargs", "{'actions': 'with_stop'}"]  # apg_robust's robot
    for args in (["--policy", "pretrained:apg_rl"], ["--policy", "pretrained:apg_robust", "--planning-depth", "1", *stop]):
        out = subprocess.run([sys.executable, "-m", "sb3_crowdnav.cli", "evaluate", *args, "--episodes", "1",
                              "--planning-width", "8"], capture_output=True, text=True)
        assert out.returncode == 2, args
        assert len(out.stderr.strip().splitlines()) == 1 and "planning_width=8 needs planning_depth > 1" in out.stderr
    out = subprocess.run([sys.executable, "-m", "sb3_crowdnav.cli", "evaluate", "--policy", "pretrained:apg_robust",
                          "--episodes", "1", "--planning-depth", "2", "--planning-width", "0", *stop],
                         capture_output=True, text=True)
    assert out.returncode == 2 and "--planning-width" in out.stderr and "positive integer" in out.stderr
