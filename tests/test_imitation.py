"""Imitation of the ORCA robot for SB3's PPO/A2C/DQN (sb3_crowdnav.imitation)."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from sb3_contrib import QRDQN
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.env_util import make_vec_env

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.imitation import Demonstrations, DQfD, collect_demonstrations, pretrain_actor_critic, pretrain_dqn
from sb3_crowdnav.nn import ApgActorCriticPolicy, ApgDQNPolicy, ApgQRDQNPolicy

th.set_num_threads(1)
ENV_KWARGS = dict(num_humans=3)
SMALL = dict(net_arch=[32])


@pytest.fixture(scope="module")
def demos():
    env = make_vec_env("CrowdNav-v0", n_envs=2, seed=0, env_kwargs=ENV_KWARGS)
    return collect_demonstrations(env, 12)


def test_demonstrations_are_whole_consistent_episodes(demos):
    assert sum(demos.outcomes.values()) == 12 == demos.episode_end.sum()
    assert demos.outcomes["success"] >= 8  # the constrained ORCA robot succeeds most of the time with 3 pedestrians
    assert demos.episode_end[-1]
    assert not demos.terminated[~demos.episode_end].any()  # only an episode's last step can terminate
    inside = np.flatnonzero(~demos.episode_end)  # next observation = the following step's observation
    for key in demos.observations:
        np.testing.assert_array_equal(demos.next_observations[key][inside], demos.observations[key][inside + 1])
    success_ends = demos.rewards[demos.episode_end & demos.terminated]
    assert (success_ends != 0).all()


def test_discounted_returns_restart_at_episode_ends():
    demo = Demonstrations({}, {}, np.zeros(4, dtype=np.int64), np.array([0.0, 1.0, 0.0, 2.0], dtype=np.float32),
                          np.array([0, 1, 0, 1], bool), np.array([0, 1, 0, 1], bool), {})
    np.testing.assert_allclose(demo.discounted_returns(0.5), [0.5, 1.0, 1.0, 2.0])


def test_collect_refuses_bad_episode_count():
    env = make_vec_env("CrowdNav-v0", n_envs=1, env_kwargs=ENV_KWARGS)
    with pytest.raises(ValueError, match="episodes"):
        collect_demonstrations(env, 0)


def _agreement(actions_fn, demos):
    obs = {k: th.as_tensor(v, dtype=th.float32) for k, v in demos.observations.items()}
    with th.no_grad():
        return float((actions_fn(obs) == th.as_tensor(demos.actions)).float().mean())


def test_behaviour_cloning_makes_ppo_imitate(demos):
    model = PPO(ApgActorCriticPolicy, make_vec_env("CrowdNav-v0", env_kwargs=ENV_KWARGS), seed=0, policy_kwargs=SMALL)

    def greedy(obs):
        return model.policy.get_distribution(obs).distribution.probs.argmax(dim=1)

    before = _agreement(greedy, demos)
    # 60 epochs: over seeds 0-4 the agreement is 0.55-0.80 on either matrix library (30: 0.46-0.65, too close to 0.5)
    losses = pretrain_actor_critic(model, demos, epochs=60, learning_rate=3e-3, batch_size=64)
    after = _agreement(greedy, demos)
    assert losses[-1] < losses[0]
    assert after > max(0.5, before + 0.3), (before, after)
    with pytest.raises(TypeError, match="actor-critic"):
        pretrain_actor_critic(DQN(ApgDQNPolicy, make_vec_env("CrowdNav-v0", env_kwargs=ENV_KWARGS)), demos)
    with pytest.raises(ValueError, match="epochs"):
        pretrain_actor_critic(model, demos, epochs=0)


@pytest.mark.parametrize("algo", ["dqn", "qrdqn"])
def test_dqn_pretraining_fills_buffer_and_ranks_demonstrated_actions_first(demos, algo):
    """DQN, and QR-DQN by the largest mean over its quantiles (what its predict acts on): the greedy action becomes the
    demonstrated one, the replay buffer holds the demonstrations, and the target network is the trained one."""
    env = make_vec_env("CrowdNav-v0", env_kwargs=ENV_KWARGS)
    if algo == "dqn":
        model = DQN(ApgDQNPolicy, env, seed=0, policy_kwargs=SMALL, buffer_size=5_000)
        online, target = model.q_net, model.q_net_target
    else:
        model = QRDQN(ApgQRDQNPolicy, env, seed=0, policy_kwargs=dict(SMALL, n_quantiles=8), buffer_size=5_000)
        online, target = model.quantile_net, model.quantile_net_target

    def greedy(obs):
        return model.q_net(obs).argmax(dim=1) if algo == "dqn" else model.quantile_net(obs).mean(dim=1).argmax(dim=1)

    before = _agreement(greedy, demos)
    losses = pretrain_dqn(model, demos, epochs=15, learning_rate=3e-3, batch_size=64)
    after = _agreement(greedy, demos)
    assert losses[-1] < losses[0]
    assert after > before + 0.3, (before, after)
    assert model.replay_buffer.size() == len(demos)
    np.testing.assert_array_equal(model.replay_buffer.actions[: len(demos), 0, 0], demos.actions)
    for mine, its in zip(online.parameters(), target.parameters(), strict=True):
        assert th.equal(mine, its)
    obs = {k: v[:50] for k, v in demos.observations.items()}
    with th.no_grad():
        np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0],
                                      greedy({k: th.as_tensor(v) for k, v in obs.items()}).numpy())


def test_dqn_pretraining_refusals(demos):
    two = DQN(ApgDQNPolicy, make_vec_env("CrowdNav-v0", n_envs=2, env_kwargs=ENV_KWARGS), policy_kwargs=SMALL)
    with pytest.raises(ValueError, match="single-env"):
        pretrain_dqn(two, demos)
    with pytest.raises(TypeError, match="DQN or QR-DQN model, got PPO"):
        pretrain_dqn(PPO(ApgActorCriticPolicy, make_vec_env("CrowdNav-v0", env_kwargs=ENV_KWARGS)), demos)


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_dqfd_keeps_the_demonstrated_actions_on_top_while_learning(demos, tmp_path):
    """With a learning rate large enough to wreck the ranking, DQfD's demonstration steps keep it; plain DQN loses it."""
    def run(cls, keep):
        env = make_vec_env("CrowdNav-v0", env_kwargs=ENV_KWARGS, seed=1)
        model = cls(ApgDQNPolicy, env, seed=0, policy_kwargs=SMALL, buffer_size=5_000, learning_starts=0,
                    learning_rate=3e-3, exploration_initial_eps=1.0, exploration_final_eps=1.0, target_update_interval=50)
        pretrain_dqn(model, demos, epochs=15, learning_rate=3e-3, batch_size=64, fill_buffer=False)
        if keep:
            model.set_demonstrations(demos)
        model.learn(600)
        return model, _agreement(lambda obs: model.q_net(obs).argmax(dim=1), demos)

    kept, with_demos = run(DQfD, True)
    _, without = run(DQN, False)
    assert with_demos > without + 0.2, (with_demos, without)
    assert with_demos > 0.6
    # saved without the demonstrations, loadable by plain DQN with the same greedy actions
    kept.save(tmp_path / "dqfd")
    obs = {k: v[:20] for k, v in demos.observations.items()}
    loaded = DQN.load(tmp_path / "dqfd")
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], kept.predict(obs, deterministic=True)[0])
    again = DQfD.load(tmp_path / "dqfd")
    assert again.demonstrations is None and again.margin == kept.margin


def test_dqfd_refusals(demos):
    env = make_vec_env("CrowdNav-v0", env_kwargs=ENV_KWARGS)
    for kwargs, match in ((dict(demo_batch_size=0), "demo_batch_size"), (dict(margin=-1.0), "margin"),
                          (dict(margin_coef=float("nan")), "margin_coef")):
        with pytest.raises(ValueError, match=match):
            DQfD("ApgPolicy", env, policy_kwargs=SMALL, **kwargs)
    model = DQfD("ApgPolicy", env, policy_kwargs=SMALL, buffer_size=100)
    with pytest.raises(TypeError, match="Demonstrations"):
        model.set_demonstrations({"actions": []})
