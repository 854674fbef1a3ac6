"""n-step returns on Dict observations: NStepDictReplayBuffer against SB3's NStepReplayBuffer and a reference written
here, its refusals, the demonstrations in it, and DQN / QR-DQN trained with n_steps: 3 by every road the package has."""

from __future__ import annotations

import json
import warnings
import zipfile

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from sb3_contrib import QRDQN
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.buffers import DictReplayBuffer, NStepReplayBuffer
from stable_baselines3.common.env_util import make_vec_env

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.cli import main
from sb3_crowdnav.imitation import Demonstrations, DQfD, add_to_replay_buffer
from sb3_crowdnav.models import load_model
from sb3_crowdnav.nn import ApgDQNPolicy, NStepDictReplayBuffer, dict_n_step_kwargs

BOX = spaces.Box(-1e6, 1e6, (3,), np.float32)
DICT = spaces.Dict({"a": BOX, "b": spaces.Box(-1e6, 1e6, (2, 2), np.float32)})
ACTIONS = spaces.Discrete(5)
ENV_KWARGS = {"num_humans": 2, "human_policy": "linear"}
SMALL = dict(policy_kwargs=dict(net_arch=[16]), buffer_size=400, learning_starts=20, batch_size=16)


def _transitions(steps: int, n_envs: int, seed: int) -> list[dict]:
    """Random transitions with terminations and timeouts (a timeout is done and TimeLimit.truncated, as a VecEnv
    reports it)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        done = rng.random(n_envs) < 0.3
        timeout = done & (rng.random(n_envs) < 0.5)
        out.append({"obs": rng.normal(size=(n_envs, 3)).astype(np.float32),
                    "next_obs": rng.normal(size=(n_envs, 3)).astype(np.float32),
                    "action": rng.integers(0, ACTIONS.n, n_envs), "reward": rng.normal(size=n_envs).astype(np.float32),
                    "done": done, "infos": [{"TimeLimit.truncated": bool(t)} for t in timeout]})
    return out


def _as_dict(obs: np.ndarray) -> dict[str, np.ndarray]:
    """The Box observation as the "a" key, and a "b" key made from it (so a wrong row shows in both)."""
    return {"a": obs, "b": np.repeat(obs[:, :2, None], 2, axis=2)}


def _filled(transitions: list[dict], n_envs: int, n_steps: int, gamma: float, timeouts: bool):
    size = 8 * n_envs
    box = NStepReplayBuffer(size, BOX, ACTIONS, device="cpu", n_envs=n_envs, n_steps=n_steps, gamma=gamma,
                            handle_timeout_termination=timeouts)
    dct = NStepDictReplayBuffer(size, DICT, ACTIONS, device="cpu", n_envs=n_envs, n_steps=n_steps, gamma=gamma,
                                handle_timeout_termination=timeouts)
    for t in transitions:
        box.add(t["obs"], t["next_obs"], t["action"], t["reward"], t["done"], t["infos"])
        dct.add(_as_dict(t["obs"]), _as_dict(t["next_obs"]), t["action"], t["reward"], t["done"], t["infos"])
    return box, dct


@pytest.mark.parametrize("steps", [5, 13], ids=["filling", "wrapped"])
@pytest.mark.parametrize("n_steps", [1, 3, 6])
@pytest.mark.parametrize("timeouts", [True, False], ids=["timeouts", "no-timeouts"])
def test_samples_are_sb3s_n_step_samples(steps, n_steps, timeouts):
    """On the same transitions (terminations, timeouts, and a buffer written past its end), every sample of the Dict
    buffer is the Box buffer's: n-step rewards, discounts, dones, actions, observations and next observations."""
    n_envs = 2
    transitions = _transitions(steps, n_envs, seed=steps)
    kept = transitions[-8:]  # what the buffer holds (8 per env)
    timed_out = [info["TimeLimit.truncated"] for t in kept for info in t["infos"]]
    assert any(timed_out) and sum(d for t in kept for d in t["done"]) > sum(timed_out), "no timeout or no termination"
    box, dct = _filled(transitions, n_envs, n_steps, 0.9, timeouts)
    assert dct.full == box.full == (steps > 8) and dct.pos == box.pos
    indices = np.arange(box.size())
    np.random.seed(0)
    expected = box._get_samples(indices)
    np.random.seed(0)  # the same env drawn for each sample
    got = dct._get_samples(indices)
    for field in ("actions", "rewards", "dones", "discounts"):
        th.testing.assert_close(getattr(got, field), getattr(expected, field), rtol=0, atol=0)
    for name, obs in (("observations", got.observations), ("next_observations", got.next_observations)):
        th.testing.assert_close(obs["a"], getattr(expected, name), rtol=0, atol=0)
        th.testing.assert_close(obs["b"], obs["a"][:, :2, None].expand(-1, -1, 2), rtol=0, atol=0)
    assert dct.timeouts.sum() == box.timeouts.sum()  # SB3's temporary mark of the newest transition is undone


def _reference(buffer, i: int, n_steps: int, gamma: float) -> tuple[float, float, int, float]:
    """(return, discount, index of the next observation, done) of sample ``i`` of a single-env buffer, walked by hand:
    sum gamma**k r over the next transitions in writing order until n_steps, a done, or the newest transition."""
    size, newest = buffer.buffer_size, (buffer.pos - 1) % buffer.buffer_size
    ret, k, j = 0.0, 0, i
    while True:
        ret += gamma**k * float(buffer.rewards[j, 0])
        k += 1
        if buffer.dones[j, 0] or k == n_steps or j == newest:
            break
        j = (j + 1) % size
    done = float(buffer.dones[j, 0] and not buffer.timeouts[j, 0])
    return ret, gamma**k, j, done


@pytest.mark.parametrize("steps", [6, 11])
def test_samples_match_a_hand_written_reference(steps):
    n_steps, gamma = 4, 0.8
    transitions = _transitions(steps, 1, seed=10 + steps)
    for t in transitions:
        t["done"][:] = False
    for step, timeout in ((steps - 5, True), (steps - 3, False)):  # a timeout, then a termination
        transitions[step].update(done=np.array([True]), infos=[{"TimeLimit.truncated": timeout}])
    _, dct = _filled(transitions, 1, n_steps, gamma, timeouts=True)
    got = dct._get_samples(np.arange(dct.size()))
    for i in range(dct.size()):
        ret, discount, j, done = _reference(dct, i, n_steps, gamma)
        assert got.rewards[i, 0].item() == pytest.approx(ret, rel=1e-6)
        assert got.discounts[i, 0].item() == pytest.approx(discount, rel=1e-6)
        assert got.dones[i, 0].item() == done
        np.testing.assert_array_equal(got.next_observations["a"][i].numpy(), dct.next_observations["a"][j, 0])
    assert got.dones.sum() > 0 and (got.discounts > gamma**n_steps + 1e-6).sum() > 2  # the ends cut sums short


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    ({"n_steps": 0, "gamma": 0.9}, ValueError, "n_steps must be >= 1"),
    ({"n_steps": 2.5, "gamma": 0.9}, TypeError, "n_steps must be an int"),
    ({"n_steps": True, "gamma": 0.9}, TypeError, "n_steps must be an int"),
    ({"n_steps": 3, "gamma": 0.0}, ValueError, r"gamma must be in \(0, 1\]"),
    ({"n_steps": 3, "gamma": 1.01}, ValueError, r"gamma must be in \(0, 1\]"),
    ({"n_steps": 3, "gamma": "0.9"}, TypeError, "gamma must be a real number"),
    ({"n_steps": 3}, TypeError, "gamma"),  # no silent default: the algorithm's gamma must be given
])
def test_bad_n_steps_or_gamma_is_refused(kwargs, error, match):
    with pytest.raises(error, match=match):
        NStepDictReplayBuffer(16, DICT, ACTIONS, **kwargs)
    assert NStepDictReplayBuffer(16, DICT, ACTIONS, n_steps=1, gamma=1.0).gamma == 1.0


def test_dict_n_step_kwargs():
    wanted = {"replay_buffer_class": NStepDictReplayBuffer, "replay_buffer_kwargs": {"n_steps": 3, "gamma": 0.98}}
    assert dict_n_step_kwargs(DQN, DICT, {"n_steps": 3, "gamma": 0.98}) == {"gamma": 0.98, **wanted}
    assert dict_n_step_kwargs(QRDQN, DICT, {"n_steps": 3})["replay_buffer_kwargs"] == {"n_steps": 3, "gamma": 0.99}
    assert dict_n_step_kwargs(DQfD, DICT, {"n_steps": 2})["replay_buffer_kwargs"] == {"n_steps": 2, "gamma": 0.99}
    by_hand = {"gamma": 0.9, "replay_buffer_class": NStepDictReplayBuffer, "replay_buffer_kwargs": {"n_steps": 5}}
    assert dict_n_step_kwargs(DQN, DICT, by_hand)["replay_buffer_kwargs"] == {"n_steps": 5, "gamma": 0.9}
    for unchanged in ((DQN, DICT, {"n_steps": 1}), (DQN, BOX, {"n_steps": 3}), (PPO, DICT, {"n_steps": 64})):
        assert dict_n_step_kwargs(*unchanged) == unchanged[2]
    with pytest.raises(ValueError, match="needs replay_buffer_class NStepDictReplayBuffer"):
        dict_n_step_kwargs(DQN, DICT, {"n_steps": 3, "replay_buffer_class": DictReplayBuffer})
    with pytest.raises(ValueError, match=r"replay_buffer_kwargs\['gamma'\] = 0.9 contradicts gamma = 0.98"):
        dict_n_step_kwargs(DQN, DICT, {"n_steps": 3, "gamma": 0.98, "replay_buffer_kwargs": {"gamma": 0.9}})
    with pytest.raises(ValueError, match=r"\['n_steps'\] = 5 contradicts n_steps = 3"):
        dict_n_step_kwargs(DQN, DICT, {"n_steps": 3, "replay_buffer_kwargs": {"n_steps": 5}})
    with pytest.raises(TypeError, match="n_steps must be an int"):
        dict_n_step_kwargs(DQN, DICT, {"n_steps": "3"})


def test_by_hand_and_through_the_package_the_algorithms_get_the_same_buffer():
    """DQN built by hand with the buffer, and the package's classes given n_steps, end alike and warn about nothing
    (SB3 warns when n_steps is ignored for a custom buffer, and refuses n_steps > 1 on Dict observations)."""
    from sb3_crowdnav.training.zoo import ZOO_ALGOS

    env = make_vec_env("CrowdNav-v0", env_kwargs=ENV_KWARGS)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        by_hand = DQN(ApgDQNPolicy, env, gamma=0.95, replay_buffer_class=NStepDictReplayBuffer,
                      replay_buffer_kwargs={"n_steps": 3, "gamma": 0.95}, **SMALL)
        models = [by_hand, ZOO_ALGOS["dqn"]("ApgPolicy", env, gamma=0.95, n_steps=3, **SMALL),
                  ZOO_ALGOS["qrdqn"]("ApgPolicy", env, gamma=0.95, n_steps=3, **SMALL),
                  DQfD("ApgPolicy", env, gamma=0.95, n_steps=3, **SMALL),
                  ZOO_ALGOS["dqn"]("ApgPolicy", "CrowdNav-v0", gamma=0.95, n_steps=3, **SMALL)]  # an env id too
    for model in models:
        assert type(model.replay_buffer) is NStepDictReplayBuffer
        assert (model.replay_buffer.n_steps, model.replay_buffer.gamma) == (3, 0.95)
        assert model.replay_buffer_kwargs == {"n_steps": 3, "gamma": 0.95} and model.n_steps == 1
    with pytest.raises(AssertionError, match="not supported for Dict"):  # SB3's own class, with n_steps, still refuses
        DQN(ApgDQNPolicy, env, n_steps=3, **SMALL)
    env.close()


def test_demonstrations_end_their_episodes_in_the_buffer():
    """A demonstration episode ended by the time limit is a timeout in the buffer (a one-step target bootstraps there,
    as before), one ended by a collision a termination; n-step sums stop at both, never reaching the next episode."""
    n = 9
    obs = {"a": np.arange(n * 3, dtype=np.float32).reshape(n, 3), "b": np.zeros((n, 2, 2), np.float32)}
    nxt = {k: v + 100 for k, v in obs.items()}
    episode_end = np.zeros(n, bool)
    episode_end[[2, 5, 8]] = True
    terminated = np.zeros(n, bool)
    terminated[[5, 8]] = True  # episode 0 (steps 0-2) timed out, episodes 1 and 2 terminated
    demos = Demonstrations(obs, nxt, np.arange(n) % ACTIONS.n, np.arange(1, n + 1, dtype=np.float32), terminated,
                           episode_end, {"success": 2, "collision": 0, "timeout": 1})
    buffer = NStepDictReplayBuffer(32, DICT, ACTIONS, device="cpu", n_steps=3, gamma=0.5)
    add_to_replay_buffer(buffer, demos)
    np.testing.assert_array_equal(buffer.dones[:n, 0], episode_end)
    np.testing.assert_array_equal(buffer.timeouts[:n, 0], episode_end & ~terminated)
    got = buffer._get_samples(np.arange(n))
    # step 1 sums r1 + 0.5 r2 and stops at the timeout (bootstrapped: not done); step 3 sums three rewards of episode 1
    np.testing.assert_allclose(got.rewards[:, 0].numpy(), [1 + 1 + 0.75, 2 + 1.5, 3, 4 + 2.5 + 1.5, 5 + 3, 6,
                                                           7 + 4 + 2.25, 8 + 4.5, 9])
    np.testing.assert_allclose(got.discounts[:, 0].numpy(), [0.125, 0.25, 0.5, 0.125, 0.25, 0.5, 0.125, 0.25, 0.5])
    np.testing.assert_array_equal(got.dones[:, 0].numpy(), [0, 0, 0, 1, 1, 1, 1, 1, 1])
    one_step = DictReplayBuffer(32, DICT, ACTIONS, device="cpu")
    add_to_replay_buffer(one_step, demos)
    np.testing.assert_array_equal(one_step._get_samples(np.arange(n)).dones[:, 0].numpy(), terminated)


@pytest.mark.parametrize("algo", ["dqn", "qrdqn"])
def test_train_with_n_steps_records_them(algo, tmp_path):
    """A tiny ``train --hyperparams`` run with n_steps: 3 learns (gradient steps on n-step samples), and the saved
    model and config.json say n_steps 3; the model loads without unpickling."""
    yml = tmp_path / f"{algo}.yml"
    yml.write_text("CrowdNav-v0:\n  policy: ApgPolicy\n  policy_kwargs: 'dict(net_arch=[16])'\n  buffer_size: 1000\n"
                   "  learning_starts: 30\n  batch_size: 16\n  gamma: 0.95\n  n_steps: 3\n  train_freq: 4\n")
    out = tmp_path / "run"
    assert main(["train", "--algo", algo, "--hyperparams", str(yml), "--timesteps", "120", "--out", str(out),
                 "--human-policy", "linear", "--humans", "3", "--no-progress"]) == 0
    assert json.loads((out / "config.json").read_text())["hyperparams"]["n_steps"] == 3
    with zipfile.ZipFile(out / f"{algo}.zip") as archive:
        data = json.loads(archive.read("data"))
    assert data["replay_buffer_kwargs"] == {"n_steps": 3, "gamma": 0.95} and data["_n_updates"] > 0
    model = load_model(out / f"{algo}.zip")
    assert type(model).__name__ == {"dqn": "DQN", "qrdqn": "QRDQN"}[algo]
    assert model.replay_buffer_class is NStepDictReplayBuffer and model.replay_buffer.n_steps == 3


@pytest.mark.parametrize(("entry", "match"), [("n_steps: 0", "n_steps must be >= 1"),
                                              ("n_steps: 3\n  replay_buffer_kwargs: {n_steps: 2}", "contradicts")])
def test_the_cli_refuses_bad_n_steps_before_training(entry, match, tmp_path, capsys):
    yml = tmp_path / "dqn.yml"
    yml.write_text(f"CrowdNav-v0:\n  buffer_size: 100\n  {entry}\n")
    with pytest.raises(SystemExit) as exc:
        main(["train", "--algo", "dqn", "--hyperparams", str(yml), "--timesteps", "10", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and match in err, err
    assert not (tmp_path / "run").exists()


def test_zoo_tuning_samples_n_steps():
    import optuna
    from rl_zoo3 import hyperparams_opt

    from sb3_crowdnav.training.zoo import N_STEPS_CHOICES, register

    register()
    register()  # idempotent: the samplers are not wrapped twice
    fixed = {"one_minus_gamma": 0.02, "batch_size_pow": 6, "learning_rate": 1e-3, "train_freq": 4,
             "subsample_steps": 2, "exploration_final_eps": 0.05, "exploration_fraction": 0.2,
             "target_update_interval": 1000, "net_arch": "small", "n_steps": 3}
    args = {"using_her_replay_buffer": False, "her_kwargs": {}}
    for algo, extra in (("dqn", {}), ("qrdqn", {"n_quantiles": 25})):
        params = hyperparams_opt.HYPERPARAMS_SAMPLER[algo](optuna.trial.FixedTrial({**fixed, **extra}), 80, 1, dict(args))
        assert params["n_steps"] == 3 and params["gamma"] == pytest.approx(0.98)
        assert hyperparams_opt.HYPERPARAMS_CONVERTER[algo]({**fixed, **extra})["n_steps"] == 3  # a trial's best, loaded
    assert 1 in N_STEPS_CHOICES and max(N_STEPS_CHOICES) > 1


@pytest.mark.slow  # an rl-zoo3 run in a subprocess (~1 min on a busy 2-core machine)
def test_rl_zoo3_trains_qrdqn_with_n_steps(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    hyper = Path(__file__).resolve().parents[1] / "zoo_hyperparams" / "qrdqn.yml"
    subprocess.run([sys.executable, "-m", "sb3_crowdnav.training.zoo", "train", "--algo", "qrdqn", "-conf", str(hyper),
                    "-n", "200", "--env", "CrowdNav-v0", "-f", str(tmp_path), "--eval-freq", "-1", "--seed", "0",
                    "-params", "n_steps:3", "buffer_size:1000", "learning_starts:50"],
                   check=True, capture_output=True, timeout=600)
    with zipfile.ZipFile(tmp_path / "qrdqn" / "CrowdNav-v0_1" / "CrowdNav-v0.zip") as archive:
        data = json.loads(archive.read("data"))
    assert data["replay_buffer_kwargs"] == {"n_steps": 3, "gamma": 0.98} and data["_n_updates"] > 0
