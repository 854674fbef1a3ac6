"""A hyperparameter-file run stopped by SIGTERM or SIGINT writes a checkpoint of the step it stopped at and resumes
from it; a resumed replay buffer never chains an n-step return across the interruption."""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.buffers import NStepReplayBuffer

from sb3_crowdnav.training import zoo_run
from sb3_crowdnav.training.hyperparams import train_from_hyperparams

HP = {"policy": "ApgPolicy", "policy_kwargs": "dict(net_arch=[16])", "buffer_size": 1000, "learning_starts": 16,
      "batch_size": 16, "exploration_fraction": 0.5}
ENV = {"human_policy": "linear", "num_humans": 2}


def _signal_at(monkeypatch, steps: int, signum: int) -> None:
    """Make the checkpoint callback raise ``signum`` in this process when the run reaches ``steps``."""
    original = zoo_run.ZooCheckpoint._on_step

    def on_step(self):
        if self.model.num_timesteps == steps and self.stopped_by is None:
            signal.raise_signal(signum)
        return original(self)

    monkeypatch.setattr(zoo_run.ZooCheckpoint, "_on_step", on_step)


def test_a_signal_writes_the_checkpoint_of_its_step_and_the_run_resumes_from_it(tmp_path, monkeypatch):
    signum = signal.SIGTERM  # (SIGINT: the PPO test below)
    out, before = tmp_path / "run", signal.getsignal(signum)
    _signal_at(monkeypatch, 50, signum)
    with pytest.raises(zoo_run.TrainingInterrupted) as stopped:
        train_from_hyperparams("dqn", HP, out, timesteps=96, checkpoint_freq=32, eval_episodes=2, env_overrides=ENV)
    assert (stopped.value.signum, stopped.value.steps) == (signum, 50)
    assert stopped.value.checkpoint == zoo_run.checkpoint_file(out, "dqn", 50) and stopped.value.checkpoint.is_file()
    assert signal.getsignal(signum) == before  # the run's handlers are gone with it
    progress = json.loads((out / "progress.json").read_text())
    assert (progress["timesteps"], progress["finished"], progress["checkpoint"]) == (50, False, "dqn_50_steps.zip")
    with np.load(zoo_run.buffer_file(out, "dqn", 50)) as saved:
        assert int(saved["meta.pos"]) == 49  # every transition but the one of the step that stopped
    assert not (out / "dqn.zip").exists() and not (out / "run.lock").exists()
    validated = [json.loads(line)["timesteps"] for line in (out / "eval_curve.jsonl").read_text().splitlines()]
    assert 50 not in validated  # not validated on the way out

    monkeypatch.undo()
    model = train_from_hyperparams("dqn", HP, out, timesteps=96, checkpoint_freq=32, eval_episodes=2,
                                   env_overrides=ENV)[0]
    # (DQN collects train_freq = 4 steps per rollout: from 50, the run ends within one rollout past 96)
    assert 96 <= model.num_timesteps < 96 + 4
    progress = json.loads((out / "progress.json").read_text())
    assert progress["finished"] and progress["timesteps"] == model.num_timesteps
    validated = [json.loads(line)["timesteps"] for line in (out / "eval_curve.jsonl").read_text().splitlines()]
    # the stopped checkpoint validated when the run resumed
    assert validated.count(50) == 1 and validated[-1] == model.num_timesteps


def test_without_checkpoints_a_run_installs_no_handler(tmp_path, monkeypatch):
    seen = []
    original = zoo_run.ZooCheckpoint.__init__
    monkeypatch.setattr(zoo_run.ZooCheckpoint, "__init__", lambda self, *a, **k: seen.append(1) or original(self, *a, **k))
    before = signal.getsignal(signal.SIGTERM)
    train_from_hyperparams("dqn", HP, tmp_path / "run", timesteps=8, env_overrides=ENV)
    assert seen == [] and signal.getsignal(signal.SIGTERM) == before


def _buffer(n_envs: int = 2, size: int = 8) -> NStepReplayBuffer:
    return NStepReplayBuffer(size, spaces.Box(-1, 1, (1,)), spaces.Discrete(2), n_envs=n_envs, n_steps=3, gamma=0.5)


def _add(buffer: NStepReplayBuffer, rewards, dones) -> None:
    n = buffer.n_envs
    buffer.add(np.zeros((n, 1)), np.zeros((n, 1)), np.zeros((n, 1)), np.asarray(rewards, dtype=np.float32),
               np.asarray(dones, dtype=np.float32), [{} for _ in range(n)])


def test_the_last_transition_before_a_resume_is_truncated_where_it_is_not_terminal():
    buffer = _buffer()
    zoo_run.truncate_last(buffer)  # empty: nothing to mark
    assert not buffer.timeouts.any()
    _add(buffer, [1.0, 1.0], [False, False])
    _add(buffer, [1.0, 1.0], [False, True])  # env 1's episode ended here by itself
    zoo_run.truncate_last(buffer)
    assert buffer.timeouts[1].tolist() == [True, False] and buffer.dones[1].tolist() == [False, True]
    assert not buffer.timeouts[0].any()
    # the resumed run's first transitions (other episodes): an n-step return from index 0 stops at index 1
    _add(buffer, [100.0, 100.0], [False, False])
    _add(buffer, [100.0, 100.0], [False, False])
    np.random.seed(0)
    samples = buffer._get_samples(np.zeros(16, dtype=np.int64))
    assert np.allclose(samples.rewards.numpy(), 1.0 + 0.5 * 1.0)  # two steps of the interrupted episode, none after
    # a full buffer whose position wrapped to 0: its last transition is the array's last row
    full = _buffer(n_envs=1, size=2)
    for _ in range(2):
        _add(full, [0.0], [False])
    assert full.full and full.pos == 0
    zoo_run.truncate_last(full)
    assert full.timeouts[1].tolist() == [True] and not full.timeouts[0].any()


def test_the_cli_exits_with_128_plus_the_signal_and_says_how_to_resume(tmp_path, monkeypatch, capsys):
    from sb3_crowdnav.cli import main

    yml = tmp_path / "dqn.yml"
    yml.write_text("CrowdNav-v0:\n  policy: ApgPolicy\n  policy_kwargs: 'dict(net_arch=[16])'\n  buffer_size: 1000\n"
                   "  learning_starts: 16\n  batch_size: 16\n")
    _signal_at(monkeypatch, 40, signal.SIGTERM)
    argv = ["train", "--algo", "dqn", "--hyperparams", str(yml), "--timesteps", "64", "--checkpoint-freq", "32",
            "--out", str(tmp_path / "run"), "--human-policy", "linear", "--humans", "2", "--no-progress"]
    assert main(argv) == 128 + signal.SIGTERM
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1].startswith("stopped by signal 15 after 40 steps; checkpoint ") and "run the same command" in out[-1]
    assert not (tmp_path / "run" / "config.json").exists()  # written by a finished run only
    monkeypatch.undo()
    assert main(argv) == 0
    assert json.loads((tmp_path / "run" / "config.json").read_text())["timesteps"] >= 64


def test_a_stopped_ppo_run_keeps_its_last_update_and_resumes(tmp_path, monkeypatch):
    hp = {"policy": "ApgPolicy", "policy_kwargs": "dict(net_arch=[16])", "n_steps": 16, "batch_size": 16, "n_epochs": 1}
    out, before = tmp_path / "run", signal.getsignal(signal.SIGINT)
    _signal_at(monkeypatch, 40, signal.SIGINT)  # Ctrl-C in the third rollout (16 steps each)
    with pytest.raises(zoo_run.TrainingInterrupted) as stopped:
        train_from_hyperparams("ppo", hp, out, timesteps=80, checkpoint_freq=32, env_overrides=ENV)
    assert (stopped.value.signum, stopped.value.steps) == (signal.SIGINT, 40) and stopped.value.checkpoint.is_file()
    assert signal.getsignal(signal.SIGINT) == before
    assert not list((out / "checkpoints").glob("*.npz"))  # on-policy: no replay buffer
    monkeypatch.undo()
    model = train_from_hyperparams("ppo", hp, out, timesteps=80, checkpoint_freq=32, env_overrides=ENV)[0]
    assert 80 <= model.num_timesteps < 80 + 16 and json.loads((out / "progress.json").read_text())["finished"]
