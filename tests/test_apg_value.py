"""APGValue: propagation model vs the env, lookahead, learning smoke tests, save/load, refusals."""

from __future__ import annotations

import itertools

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium.wrappers import FlattenObservation
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack, VecNormalize
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.apg_value import APGValue, ValueLookaheadPolicy
from sb3_crowdnav.nn.layers import bfloat16_supported
from sb3_crowdnav.sim.actions import N_ACTIONS, wrap_angle
from sb3_crowdnav.sim.observation import Robot

TINY = dict(imitation_episodes=2, imitation_epochs=1, batch_size=16, buffer_size=2_000)


def _replay(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    for a in actions:
        obs, *_ = env.step(a)
    return obs


def _batched(obs):
    return {k: v[None] for k, v in obs.items()}


@pytest.mark.parametrize("kinematics", ["unicycle", "holonomic"])
def test_propagated_robot_equals_env_for_every_action(kinematics):
    env = gym.make("CrowdNav-v0", human_policy="linear", kinematics=kinematics, rotation_range=np.pi)
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0)
    prefix = [3, 17, 40]
    obs = _replay(env, 7, prefix)
    _, prop = model.policy.lookahead(_batched(obs))
    for a in range(N_ACTIONS):
        nxt = _replay(env, 7, [*prefix, a])
        diff = prop.robot[0, a] - nxt["robot"]
        diff[Robot.HEADING] = wrap_angle(diff[Robot.HEADING])
        np.testing.assert_allclose(diff, 0.0, atol=2e-5, err_msg=f"action {a}")
        # pedestrians move at constant velocity in the linear scene: the propagated history matches too
        np.testing.assert_allclose(prop.humans[0], nxt["humans"], atol=2e-5)


@pytest.mark.parametrize("reward", ["crowdnav", "comfort", "comfort_angular"])
@pytest.mark.parametrize("kinematics", ["unicycle", "holonomic"])
def test_reward_model_equals_env_reward(reward, kinematics):
    # a small circle crowded with 10 pedestrians walking at constant velocity: the robot meets them at the centre
    env = gym.make("CrowdNav-v0", human_policy="linear", reward=reward, kinematics=kinematics, num_humans=10,
                   circle_radius=3.0)
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0)
    rng = np.random.default_rng(0)
    checked = nonzero = terminal = 0
    for seed in range(12):
        obs, _ = env.reset(seed=seed)
        for t in range(13):  # linear pedestrians keep a constant velocity until ~1 m from their goals (t >= 14)
            _, prop = model.policy.lookahead(_batched(obs))
            a = int(rng.integers(5)) * 16 + int(rng.choice([0, 0, 1, 15, 8]))  # mostly ahead, sometimes turning
            obs2, r, terminated, truncated, _ = env.step(a)
            if t >= 1:  # at t = 0 the observed velocities are still zero while the pedestrians already walk
                assert prop.reward[0, a] == pytest.approx(r, abs=1e-6)
                assert bool(prop.terminal[0, a]) == terminated
                checked += 1
                nonzero += r != 0
                terminal += terminated
            if terminated or truncated:
                break
            obs = obs2
    assert checked > 50 and nonzero > 0, "the scenes never exercised a non-zero reward"


def test_lookahead_terminal_successor_has_no_future_value():
    env = gym.make("CrowdNav-v0", num_humans=0)
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0)
    obs, _ = env.reset(seed=0)
    obs["robot"][Robot.POS] = obs["robot"][Robot.GOAL] - np.array([0.0, 0.5], dtype=np.float32)  # 0.5 m below the goal
    q, prop = model.policy.lookahead(_batched(obs))
    straight_full_speed = 4 * 16  # speed index 4 (v_pref), direction index 0 (keep heading +y)
    assert prop.terminal[0, straight_full_speed]
    assert q[0, straight_full_speed] == pytest.approx(1.0)
    # every successful action scores exactly the success reward; the others R + γ V, with V untrained
    np.testing.assert_allclose(q[0, prop.terminal[0]], 1.0)
    assert prop.terminal[0, 3 * 16] and not prop.terminal[0, 16]  # 0.2 m short of the goal is a success, 0.4 m not
    assert prop.terminal[0, np.argmax(q[0])]
    assert (~prop.terminal[0]).sum() > 0


def test_action_values_shape_and_predict_batch():
    vec = make_vec_env("CrowdNav-v0", n_envs=3, seed=1)
    model = APGValue("ApgPolicy", vec, imitation_episodes=0, seed=0)
    obs = vec.reset()
    q = model.policy.action_values(obs)
    assert q.shape == (3, N_ACTIONS) and np.isfinite(q).all()
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape == (3,) and ((actions >= 0) & (actions < N_ACTIONS)).all()
    np.testing.assert_array_equal(actions, q.argmax(axis=1))
    single, _ = model.predict({k: v[0] for k, v in obs.items()}, deterministic=True)
    assert np.ndim(single) == 0 and single == actions[0]


@pytest.mark.parametrize("alias", ["ApgPolicy", "CadrlPolicy", "SfPolicy", "LmPolicy", "LstmRlPolicy", "SarlPolicy"])
def test_learn_every_alias(alias):
    model = APGValue(alias, "CrowdNav-v0", seed=0, **TINY)
    model.learn(60)
    assert model.imitation_done and model.num_timesteps == 60
    assert isinstance(model.policy, ValueLookaheadPolicy)


def test_learn_two_envs_and_save_load(tmp_path):
    vec = make_vec_env("CrowdNav-v0", n_envs=2, seed=3)
    model = APGValue("ApgPolicy", vec, seed=0, **TINY).learn(80)
    assert model.num_timesteps == 80
    obs = vec.reset()
    before, _ = model.predict(obs, deterministic=True)
    q_before = model.policy.action_values(obs)
    model.save(tmp_path / "apg")
    loaded = APGValue.load(tmp_path / "apg", env=vec)
    after, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(before, after)
    np.testing.assert_allclose(q_before, loaded.policy.action_values(obs), rtol=0, atol=1e-7)
    assert loaded.imitation_done and loaded.policy.gamma == model.policy.gamma
    assert loaded.policy.world.reward == model.policy.world.reward
    # a loaded model keeps learning without repeating imitation
    loaded.learn(20, reset_num_timesteps=False)
    assert 100 <= loaded.num_timesteps < 100 + 8  # rollouts come in train_freq (4) x n_envs (2) steps
    # and a model loaded without an env acts the same
    bare = APGValue.load(tmp_path / "apg")
    np.testing.assert_array_equal(bare.predict(obs, deterministic=True)[0], before)


def test_same_seed_same_training_run():
    def run():
        model = APGValue("ApgPolicy", "CrowdNav-v0", seed=11, **TINY).learn(120)
        return th.cat([p.detach().flatten() for p in model.policy.value_net.parameters()])

    a, b = run(), run()
    assert th.equal(a, b)


def test_epsilon_decays_by_episodes():
    env = gym.make("CrowdNav-v0", time_limit=1.0)  # 4-step episodes
    model = APGValue("ApgPolicy", env, seed=0, exploration_episodes=10, exploration_initial_eps=0.5,
                     exploration_final_eps=0.1, **TINY)
    model.learn(20)  # at most 20 RL steps = at least 5 episodes
    episodes = model._episode_num
    assert 5 <= episodes <= 20
    model.predict({k: v[0] for k, v in model.env.reset().items()}, deterministic=False)
    assert model.exploration_rate == pytest.approx(0.5 - 0.4 * min(1.0, episodes / 10))


def test_td_target_zero_future_on_terminal():
    model = APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, seed=0)
    obs = model.env.reset()
    tens = {k: th.as_tensor(v) for k, v in obs.items()}
    rewards = th.tensor([0.3])
    with th.no_grad():
        v_next = model.policy.values(tens, target=True)
    td_target = model._value_learner().td_target
    np.testing.assert_allclose(td_target(rewards, tens, tens, th.tensor([1.0])).numpy(), [0.3])
    expected = 0.3 + 0.9**0.25 * v_next
    np.testing.assert_allclose(td_target(rewards, tens, tens, th.tensor([0.0])).numpy(), expected.numpy(), rtol=1e-6)


def test_refusals():
    with pytest.raises(ValueError, match="VecNormalize"):
        APGValue("ApgPolicy", VecNormalize(make_vec_env("CrowdNav-v0", n_envs=1)), imitation_episodes=0)
    with pytest.raises(ValueError, match="VecFrameStack"):
        APGValue("ApgPolicy", VecFrameStack(make_vec_env("CrowdNav-v0", n_envs=1), 2), imitation_episodes=0)
    with pytest.raises(ValueError, match="HerReplayBuffer"):
        APGValue("ApgPolicy", "CrowdNav-v0", replay_buffer_class=HerReplayBuffer)
    with pytest.raises(ValueError, match="Dict observation"):
        APGValue("ApgPolicy", DummyVecEnv([lambda: FlattenObservation(gym.make("CrowdNav-v0"))]), imitation_episodes=0)
    with pytest.raises(ValueError, match="does not match the env"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, policy_kwargs=dict(time_step=0.1))
    for bad in (dict(exploration_initial_eps=1.5), dict(imitation_episodes=-1), dict(exploration_episodes=0),
                dict(imitation_learning_rate=0.0), dict(gamma=0.0)):
        name = next(iter(bad))
        with pytest.raises(ValueError, match=name):
            APGValue("ApgPolicy", "CrowdNav-v0", **{"imitation_episodes": 0, **bad})


def test_tensorboard_scalars_and_progress_bar(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    env = gym.make("CrowdNav-v0", time_limit=2.0)  # 8-step episodes: several rollouts get logged
    model = APGValue("ApgPolicy", env, seed=0, tensorboard_log=str(tmp_path), **TINY)
    model.learn(120, log_interval=2, progress_bar=True)
    (run,) = list(tmp_path.iterdir())
    acc = EventAccumulator(str(run))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    expected = {"train/imitation_loss", "train/loss", "train/learning_rate", "rollout/exploration_rate",
                "rollout/success_rate", "rollout/collision_rate", "rollout/timeout_rate", "rollout/min_separation"}
    assert expected <= tags, expected - tags
    eps = [e.value for e in acc.Scalars("rollout/exploration_rate")]
    assert eps[0] <= 0.5 and all(b <= a for a, b in itertools.pairwise(eps))


@pytest.mark.parametrize("bootstrap", [False, True])
def test_timeouts_are_terminal_unless_bootstrapped(bootstrap):
    env = gym.make("CrowdNav-v0", num_humans=0, time_limit=1.0)  # nobody around: every episode times out after 4 steps
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0, bootstrap_timeouts=bootstrap, buffer_size=100,
                     learning_starts=100)
    model.learn(8)
    samples = model.replay_buffer._get_samples(np.arange(8))
    done = samples.dones.flatten().numpy()
    expected_last = 0.0 if bootstrap else 1.0
    np.testing.assert_array_equal(done, [0, 0, 0, expected_last] * 2)


def test_warm_up_before_learning_starts_acts_with_the_lookahead():
    # SB3 draws uniform actions before learning_starts; APGValue's warm-up (and a refill) is its ε-greedy lookahead
    env = gym.make("CrowdNav-v0")
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0, learning_starts=1_000, buffer_size=200,
                     exploration_initial_eps=0.0, exploration_final_eps=0.0)
    model.learn(40)
    n = model.replay_buffer.pos
    assert n == 40
    obs = {k: v[:n, 0] for k, v in model.replay_buffer.observations.items()}
    greedy = model.policy.action_values(obs).argmax(axis=1)
    np.testing.assert_array_equal(model.replay_buffer.actions[:n, 0, 0], greedy)


def test_loaded_buffer_follows_bootstrap_setting(tmp_path):
    env = gym.make("CrowdNav-v0", num_humans=0, time_limit=1.0)
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0, bootstrap_timeouts=True, learning_starts=100)
    model.learn(8)
    model.save(tmp_path / "m")
    model.save_replay_buffer(tmp_path / "rb")
    loaded = APGValue.load(tmp_path / "m", env=env, bootstrap_timeouts=False)
    loaded.load_replay_buffer(tmp_path / "rb")
    loaded.learn(4, reset_num_timesteps=False)
    done = loaded.replay_buffer._get_samples(np.arange(12)).dones.flatten().numpy()
    np.testing.assert_array_equal(done, [0, 0, 0, 1] * 3)


# ---------------------------------------------------------------- value targets
def _value_params(model):
    return th.cat([p.detach().flatten() for p in model.policy.value_net.parameters()])


def test_buffer_stores_staged_fields_and_defaults():
    from sb3_crowdnav.apg_value.buffers import ValueReplayBuffer

    env = make_vec_env("CrowdNav-v0", n_envs=2, seed=0)
    buffer = ValueReplayBuffer(10, env.observation_space, env.action_space, n_envs=2)
    obs = env.reset()
    step = (obs, obs, np.zeros((2, 1)), np.zeros(2), np.zeros(2), [{}, {}])
    buffer.stage([True, False], [0.5, np.nan])
    buffer.add(*step)
    buffer.add(*step)  # not staged: greedy, no target
    np.testing.assert_array_equal(buffer.greedy[:2], [[True, False], [True, True]])
    np.testing.assert_array_equal(buffer.lookahead_target[:2], [[0.5, np.nan], [np.nan, np.nan]])
    samples = buffer._get_samples(np.array([0, 0, 0, 0, 0, 0, 0, 0]))
    assert set(samples.greedy.flatten().tolist()) == {0.0, 1.0}  # both envs drawn among 8 samples (p = 1 - 2/256)
    with pytest.raises(ValueError, match="one value per env"):
        buffer.stage([True], [0.1])


def test_value_target_refusals():
    from stable_baselines3.common.buffers import DictReplayBuffer

    with pytest.raises(ValueError, match="value_target"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, value_target="mc")
    with pytest.raises(ValueError, match="ValueReplayBuffer"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, value_target="greedy_td",
                 replay_buffer_class=DictReplayBuffer)
    # the paper's TD target still works with SB3's own buffer
    APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, replay_buffer_class=DictReplayBuffer,
             batch_size=8, seed=0).learn(16)


def test_greedy_td_ignores_exploratory_transitions():
    kwargs = dict(imitation_episodes=0, seed=0, batch_size=8, exploration_initial_eps=1.0, exploration_final_eps=1.0)
    model = APGValue("ApgPolicy", "CrowdNav-v0", value_target="greedy_td", **kwargs)
    before = _value_params(model)
    model.learn(40)
    assert model.replay_buffer.greedy[:40].sum() == 0  # every action was an ε draw ...
    assert th.equal(_value_params(model), before)  # ... so V did not move
    plain = APGValue("ApgPolicy", "CrowdNav-v0", value_target="td", **kwargs)
    plain.learn(40)
    assert not th.equal(_value_params(plain), before)  # the same data moves V under the paper's TD target


def test_lookahead_target_is_the_best_action_value_at_insertion():
    model = APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, seed=0, value_target="lookahead",
                     exploration_initial_eps=0.5, exploration_final_eps=0.5, gradient_steps=0)  # no training
    model.learn(30)
    buffer = model.replay_buffer
    obs = {k: v[:30, 0] for k, v in buffer.observations.items()}
    expected = model.policy.action_values(obs).max(axis=1)
    np.testing.assert_allclose(buffer.lookahead_target[:30, 0], expected, rtol=1e-5, atol=1e-6)
    greedy = model.policy.action_values(obs).argmax(axis=1) == buffer.actions[:30, 0, 0]
    np.testing.assert_array_equal(buffer.greedy[:30, 0], greedy)
    assert 0 < greedy.sum() < 30  # ε = 0.5 explores some steps, not all


@pytest.mark.parametrize("value_target", ["greedy_td", "lookahead"])
def test_value_targets_learn_and_train_on_stored_target(value_target):
    model = APGValue("ApgPolicy", "CrowdNav-v0", value_target=value_target, seed=3, **TINY)
    before = _value_params(model)
    model.learn(60)
    assert not th.equal(_value_params(model), before)
    assert np.isfinite(model.logger.name_to_value.get("train/loss", 0.0))


def test_old_dict_buffer_is_wrapped_on_load(tmp_path):
    from stable_baselines3.common.buffers import DictReplayBuffer

    from sb3_crowdnav.apg_value.buffers import ValueReplayBuffer

    old = APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, seed=0, replay_buffer_class=DictReplayBuffer,
                   learning_starts=100)
    old.learn(10)
    old.save_replay_buffer(tmp_path / "rb.npz")
    from stable_baselines3.common.save_util import save_to_pkl

    save_to_pkl(tmp_path / "rb.pkl", old.replay_buffer)  # as SB3 and earlier versions wrote it
    for path, kw in ((tmp_path / "rb.npz", {}), (tmp_path / "rb.pkl", {"trusted": True})):
        model = APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, seed=0, value_target="greedy_td",
                         batch_size=8)
        model.load_replay_buffer(path, **kw)
        assert isinstance(model.replay_buffer, ValueReplayBuffer) and model.replay_buffer.pos == old.replay_buffer.pos
        assert model.replay_buffer.greedy[:10].all() and np.isnan(model.replay_buffer.lookahead_target[:10]).all()
        np.testing.assert_array_equal(model.replay_buffer.actions[:10], old.replay_buffer.actions[:10])
        model.learn(10, reset_num_timesteps=False)
    from sb3_crowdnav.serialization import UnsafeModelFileError

    with pytest.raises(UnsafeModelFileError, match="is a pickle"):  # never unpickled unless trusted
        model.load_replay_buffer(tmp_path / "rb.pkl")


# ---------------------------------------------------------------- bfloat16 lookahead
needs_bf16 = pytest.mark.skipif(not __import__("sb3_crowdnav.nn.layers", fromlist=["x"]).bfloat16_supported(),
                                reason="no native bfloat16 kernels on this CPU")


@needs_bf16
def test_bfloat16_lookahead_agrees_with_float32(tmp_path):
    env = make_vec_env("CrowdNav-v0", n_envs=4, seed=0)
    model = APGValue("ApgPolicy", env, imitation_episodes=0, seed=0)
    obs = env.reset()
    batches = []
    for _ in range(10):
        batches.append(obs)
        obs, *_ = env.step(np.random.default_rng(0).integers(0, N_ACTIONS, 4))
    q32 = np.concatenate([model.policy.action_values(o) for o in batches])
    model.policy.set_lookahead_dtype("bfloat16")
    q16 = np.concatenate([model.policy.action_values(o) for o in batches])
    assert not np.array_equal(q16, q32)  # the bfloat16 path did run
    np.testing.assert_allclose(q16, q32, atol=2e-3)
    assert (q16.argmax(1) == q32.argmax(1)).mean() >= 0.8
    # gradient passes stay float32 and untouched by the setting
    tens = {k: th.as_tensor(v) for k, v in batches[0].items()}
    v16 = model.policy.values(tens)
    model.policy.set_lookahead_dtype("float32")
    assert v16.dtype == th.float32 and th.equal(v16, model.policy.values(tens))
    model.policy.set_lookahead_dtype("bfloat16")
    model.save(tmp_path / "m")
    assert APGValue.load(tmp_path / "m").policy.lookahead_dtype == "bfloat16"


def test_lookahead_dtype_refusals():
    with pytest.raises(ValueError, match="lookahead_dtype"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, policy_kwargs=dict(lookahead_dtype="float16"))
    with pytest.raises(ValueError, match="APG encoder only"):
        APGValue("CadrlPolicy", "CrowdNav-v0", imitation_episodes=0, policy_kwargs=dict(lookahead_dtype="bfloat16"))


def test_default_optimisers_adam_for_rl_sgd_for_imitation(tmp_path):
    built = []

    class RecordingSGD(th.optim.SGD):
        def __init__(self, params, **kwargs):
            built.append(kwargs)
            super().__init__(params, **kwargs)

    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=0, imitation_optimizer_class=RecordingSGD, **TINY)
    assert isinstance(model.policy.optimizer, th.optim.Adam)
    model.learn(20)
    assert built == [{"lr": 0.01, "momentum": 0.9}]  # the imitation regression ran on it, at Table 1's rate
    assert isinstance(model.policy.optimizer, th.optim.Adam)
    model.save(tmp_path / "m")
    from sb3_crowdnav.serialization import UnsafeModelFileError

    with pytest.raises(UnsafeModelFileError, match="entry 'imitation_optimizer_class'"):  # a class defined in a test
        APGValue.load(tmp_path / "m", env=model.env)
    loaded = APGValue.load(tmp_path / "m", env=model.env, trusted=True)  # the user's own file: they may trust it
    assert isinstance(loaded.policy.optimizer, th.optim.Adam)
    loaded.learn(10, reset_num_timesteps=False)  # the saved Adam state loads and steps
    sgd = APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, policy_kwargs=dict(optimizer_class=th.optim.SGD))
    assert isinstance(sgd.policy.optimizer, th.optim.SGD) and sgd.policy.optimizer.defaults["momentum"] == 0.9
    with pytest.raises(TypeError, match="imitation_optimizer_class"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, imitation_optimizer_class="sgd")


# ---------------------------------------------------------------- overlap_training
def _params(model):
    return th.cat([p.detach().flatten() for p in model.policy.value_net.parameters()])


def test_overlap_training_is_deterministic_and_not_the_sequential_run():
    def run(overlap):
        return _params(APGValue("ApgPolicy", "CrowdNav-v0", seed=11, overlap_training=overlap, **TINY).learn(120))

    a, b = run(True), run(True)
    assert th.equal(a, b)  # same seed, same run, although the steps ran in a second thread
    assert not th.equal(a, run(False))  # V is one training call stale when acting: a different run


def _state(model):
    policy = model.policy
    optimizer = policy.optimizer.state_dict()["state"]
    return (_params(model), th.cat([p.detach().flatten() for p in policy.value_net_target.parameters()]),
            th.cat([optimizer[i]["exp_avg_sq"].flatten() for i in sorted(optimizer)]))


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_overlap_training_in_a_process_is_the_thread_run(monkeypatch):
    """The learner process runs the same arithmetic on the same batches: V, V_target (updated twice here) and Adam's
    state end bit-identical to the learner thread's run, and a second learn() continues it the same way; also when
    the acting process computes every batch's targets (as it does when it waited for the learner)."""
    from sb3_crowdnav.apg_value.overlap import ProcessLearner

    runs = {}
    for kind in ("thread", "process", "process, targets in the acting process"):
        if kind.startswith("process,"):
            monkeypatch.setattr(ProcessLearner, "busy", property(lambda self: self._pending))
        model = APGValue("ApgPolicy", "CrowdNav-v0", seed=11, overlap_training=kind.split(",")[0],
                         target_update_interval=50, **TINY)
        first = _state(model.learn(120))
        runs[kind] = first, _state(model.learn(40, reset_num_timesteps=False))
        assert model.learner.acting_net() is model.policy.value_net and model._n_updates == 160 // 4
    for other in ("process", "process, targets in the acting process"):
        for a, b in zip(runs["thread"], runs[other], strict=True):
            for x, y in zip(a, b, strict=True):
                assert th.equal(x, y)
    assert not th.equal(runs["process"][0][1], runs["process"][1][1])  # V_target did move


def test_overlap_training_acts_with_the_previous_weights(monkeypatch):
    """Each training call hands the acting copy the weights of the completed previous call, not the ones in flight."""
    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=2, overlap_training=True, **TINY)
    seen = []
    from sb3_crowdnav.apg_value.overlap import ThreadLearner

    original = ThreadLearner._begin

    def begin(self, batches, learning_rate):  # the previous call is joined, the next not started yet
        seen.append((_params(model).clone(), th.cat([p.detach().flatten() for p in self.acting_net().parameters()])))
        original(self, batches, learning_rate)

    monkeypatch.setattr(ThreadLearner, "_begin", begin)
    model.learn(40)
    assert len(seen) >= 5
    for v, acting in seen:
        assert th.equal(v, acting)
    assert not th.equal(seen[1][0], seen[-1][0])  # V did change between hand-overs
    # after learn(): no thread, no copy, predict reads V itself
    assert model.learner.acting_net() is model.policy.value_net


@pytest.mark.parametrize("kind", ["thread", "process"])
def test_overlap_training_two_envs_checkpoint_and_bfloat16(tmp_path, kind):
    from stable_baselines3.common.callbacks import CheckpointCallback

    vec = make_vec_env("CrowdNav-v0", n_envs=2, seed=3)
    kwargs = dict(TINY, policy_kwargs={"lookahead_dtype": "bfloat16"}) if bfloat16_supported() else TINY
    model = APGValue("ApgPolicy", vec, seed=0, overlap_training=kind, **kwargs)
    model.learn(80, callback=CheckpointCallback(save_freq=10, save_path=str(tmp_path), name_prefix="ck"))
    assert model.num_timesteps == 80 and model._n_updates == 80 // (4 * 2)
    saved = sorted(tmp_path.glob("ck_*.zip"))
    assert saved
    last = APGValue.load(saved[-1])
    assert last.policy.lookahead_dtype == model.policy.lookahead_dtype
    if kind == "process":  # the checkpoint saved during learn() carries the learner process's optimiser state
        steps = last.policy.optimizer.state_dict()["state"][0]["step"]
        assert int(steps) == last._n_updates > 0
    obs = vec.reset()
    model.save(tmp_path / "final")
    np.testing.assert_array_equal(APGValue.load(tmp_path / "final").predict(obs, deterministic=True)[0],
                                  model.predict(obs, deterministic=True)[0])
    if bfloat16_supported():  # V gets its acting precision back after learn()
        assert model.policy.value_net.features_extractor.bfloat16_inference


def test_overlap_training_errors_reach_the_caller(monkeypatch):
    from sb3_crowdnav.apg_value.learner import ValueLearner

    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=0, overlap_training=True, **TINY)

    def boom(self, batches):
        raise FloatingPointError("nan loss")

    monkeypatch.setattr(ValueLearner, "gradient_steps", boom)
    with pytest.raises(FloatingPointError, match="nan loss"):
        model.learn(40)
    assert model.learner.acting_net() is model.policy.value_net
    with pytest.raises(ValueError, match="overlap_training must be a bool or one of"):
        APGValue("ApgPolicy", "CrowdNav-v0", overlap_training="yes")


@pytest.mark.slow
def test_overlap_training_process_errors_and_death_reach_the_caller(monkeypatch):
    """An exception in the learner process is raised in learn(); a learner process that dies is named."""
    from sb3_crowdnav.apg_value.overlap import ProcessLearner

    original = ProcessLearner.submit
    calls = []

    def bad_command(self, batches, learning_rate):
        losses = original(self, batches, learning_rate)
        calls.append(1)
        if len(calls) == 3:
            self.join()
            self._request("bogus")
        return losses

    monkeypatch.setattr(ProcessLearner, "submit", bad_command)
    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=0, overlap_training="process", **TINY)
    with pytest.raises(ValueError, match="unknown learner command 'bogus'"):
        model.learn(40)
    assert model.learner.acting_net() is model.policy.value_net

    def killed(self, batches, learning_rate):
        losses = original(self, batches, learning_rate)
        if self._ready:  # killed once it serves (a learner that never started is told apart)
            self._process.kill()
        return losses

    monkeypatch.setattr(ProcessLearner, "submit", killed)
    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=0, overlap_training="process", **TINY)
    with pytest.raises(RuntimeError, match=r"learner process .* died \(exit code -9\)"):
        model.learn(40)
    assert model.learner.acting_net() is model.policy.value_net


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_imitation_reports_progress_and_fps_counts_rl_only(tmp_path, capsys):
    """verbose=1 prints the imitation's progress as it goes; SB3's fps is not diluted by the imitation's minutes."""
    import csv
    import time

    from stable_baselines3.common.logger import configure

    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=0, imitation_episodes=60, imitation_epochs=6, verbose=1,
                     learning_starts=50, train_freq=4)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    start = time.time()
    model.learn(300, log_interval=1)
    total = time.time() - start
    out = capsys.readouterr().out
    assert "imitation: ORCA-robot episodes, 0/60" in out and "imitation: ORCA-robot episodes, 60/60" in out
    assert "epochs, 6/6" in out and "about" in out
    with open(tmp_path / "progress.csv") as f:
        fps = [float(row["time/fps"]) for row in csv.DictReader(f) if row.get("time/fps")]
    assert fps and fps[-1] > 2 * model.num_timesteps / total  # RL steps over RL time, not over imitation + RL


def test_imitation_progress_bar(capsys):
    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=0, imitation_episodes=5, imitation_epochs=1)
    model.learn(20, progress_bar=True)
    err = capsys.readouterr().err
    assert "imitation: ORCA-robot episodes" in err and "5/5" in err
