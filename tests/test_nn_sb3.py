"""The crowd encoders inside SB3's stock DQN and PPO: learn, save, load, same actions."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3 import DQN, PPO

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.nn import EXTRACTORS, ApgActorCriticPolicy, ApgDQNPolicy, ApgExtractor

DQN_KWARGS = dict(learning_starts=50, buffer_size=1000, batch_size=32, train_freq=4, target_update_interval=100)
PPO_KWARGS = dict(n_steps=64, batch_size=32, n_epochs=2)


def make_env():
    return gym.make("CrowdNav-v0")


def sample_observations(env, count: int = 8) -> dict[str, np.ndarray]:
    obs_list = []
    obs, _ = env.reset(seed=123)
    for _ in range(count):
        obs_list.append(obs)
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            obs, _ = env.reset()
    return {k: np.stack([o[k] for o in obs_list]) for k in obs_list[0]}


def check_save_load(model, algo, tmp_path, env) -> None:
    obs = sample_observations(env)
    actions, _ = model.predict(obs, deterministic=True)
    path = tmp_path / "model.zip"
    model.save(path)
    loaded = algo.load(path, device="cpu")
    reloaded_actions, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(actions, reloaded_actions)
    assert type(loaded.policy.features_extractor) is type(model.policy.features_extractor)


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_dqn_learns_saves_and_loads(name, tmp_path):
    env = make_env()
    model = DQN(
        "MultiInputPolicy", env, policy_kwargs=dict(features_extractor_class=EXTRACTORS[name]), seed=0, **DQN_KWARGS
    )
    model.learn(300)
    assert model.num_timesteps == 300
    check_save_load(model, DQN, tmp_path, env)


@pytest.mark.parametrize("name", list(EXTRACTORS))
def test_ppo_learns_saves_and_loads(name, tmp_path):
    env = make_env()
    model = PPO(
        "MultiInputPolicy", env, policy_kwargs=dict(features_extractor_class=EXTRACTORS[name]), seed=0, **PPO_KWARGS
    )
    model.learn(256)
    assert model.num_timesteps == 256
    check_save_load(model, PPO, tmp_path, env)


def test_apg_dqn_policy_class_without_policy_kwargs(tmp_path):
    env = make_env()
    model = DQN(ApgDQNPolicy, env, seed=0, **DQN_KWARGS)
    assert isinstance(model.policy.q_net.features_extractor, ApgExtractor)
    linear = [m for m in model.policy.q_net.q_net if isinstance(m, th.nn.Linear)]
    assert [m.out_features for m in linear] == [150, 100, 100, 80]
    model.learn(100)
    check_save_load(model, DQN, tmp_path, env)


def test_apg_actor_critic_policy_class_without_policy_kwargs(tmp_path):
    env = make_env()
    model = PPO(ApgActorCriticPolicy, env, seed=0, **PPO_KWARGS)
    assert isinstance(model.policy.features_extractor, ApgExtractor)
    model.learn(64)
    check_save_load(model, PPO, tmp_path, env)


def test_policy_classes_accept_extractor_kwargs_and_overrides():
    env = make_env()
    model = DQN(ApgDQNPolicy, env, policy_kwargs=dict(net_arch=[32], features_extractor_kwargs=dict(lstm_hidden_size=20)),
                **DQN_KWARGS)
    assert model.policy.q_net.features_extractor.features_dim == 27
    model = PPO(ApgActorCriticPolicy, env, policy_kwargs=dict(features_extractor_class=EXTRACTORS["sarl"]), **PPO_KWARGS)
    assert type(model.policy.features_extractor) is EXTRACTORS["sarl"]
