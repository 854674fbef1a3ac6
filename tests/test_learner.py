"""The learner seam: serial, thread and process learners behind one protocol; no side effects on the process."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch as th
from stable_baselines3 import A2C, DQN, PPO

import sb3_crowdnav
from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.apg_value.learner import Batch, Learner, SerialLearner, ValueLearner
from sb3_crowdnav.apg_value.overlap import ProcessLearner, ThreadLearner, make_learner

PACKAGE = Path(sb3_crowdnav.__file__).resolve().parent
KINDS = (None, "thread", "process")


def _flat(tensors) -> th.Tensor:
    return th.cat([t.detach().flatten() for t in tensors])


@pytest.fixture(scope="module")
def model_and_batches():
    """A model with a filled replay buffer (no gradient step yet) and three training calls' batches."""
    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=5, imitation_episodes=0, learning_starts=10_000,
                     buffer_size=500, batch_size=16)
    model.learn(60)
    calls = [[Batch(model.replay_buffer.sample(16)) for _ in range(2)] for _ in range(3)]
    return model, calls


def _run(kind, model, calls):
    """Each training call through a learner of ``kind`` on a copy of the policy; the losses in order, the end state,
    and whether the acting net was V at each point (outside learn, during, after)."""
    policy = copy.deepcopy(model.policy)
    learner = make_learner(kind, lambda: ValueLearner(policy, model.gamma, "td", 10.0))
    assert isinstance(learner, Learner)
    acting_v = [learner.acting_net() is policy.value_net]
    learner.start()
    losses = []
    for batches in calls:
        losses += learner.submit(batches, 1e-3) or []
        acting_v.append(learner.acting_net() is policy.value_net)
    losses += learner.join() or []
    learner.update_target(0.5)
    learner.pull_optimizer()
    learner.stop()
    acting_v.append(learner.acting_net() is policy.value_net)
    optimizer = policy.optimizer.state_dict()["state"]
    state = (_flat(policy.value_net.parameters()), _flat(policy.value_net_target.parameters()),
             th.cat([optimizer[i]["exp_avg_sq"].flatten() for i in sorted(optimizer)]))
    return losses, state, acting_v


def test_every_learner_gives_the_same_losses_and_weights_on_the_same_batches(model_and_batches):
    model, calls = model_and_batches
    runs = {kind: _run(kind, model, calls) for kind in KINDS}
    serial_losses, serial_state, serial_acting = runs[None]
    assert len(serial_losses) == 6 and serial_acting == [True] * 5  # V acts itself, always
    for kind in ("thread", "process"):
        losses, state, acting = runs[kind]
        assert losses == serial_losses  # the same steps, the losses handed over one call later
        for a, b in zip(state, serial_state, strict=True):
            assert th.equal(a, b)
        assert acting == [True, False, False, False, True]  # a copy acts inside learn() only
    assert not th.equal(serial_state[0], _flat(model.policy.value_net.parameters()))  # the steps did move V


def test_serial_learner_hands_over_each_call_at_once_and_overlapping_ones_at_the_next():
    calls = []

    class Recording(ValueLearner):
        def gradient_steps(self, batches):
            calls.append(len(batches))
            return [float(len(batches))]

    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=0, imitation_episodes=0)
    serial = SerialLearner(lambda: Recording(model.policy, 0.9, "td", 10.0))
    serial.start()
    assert serial.submit([Batch(None)] * 3, 1e-3) == [3.0] and calls == [3]  # ran at once
    assert serial.join() is None and model.policy.optimizer.param_groups[0]["lr"] == 1e-3
    thread = ThreadLearner(lambda: Recording(model.policy, 0.9, "td", 10.0))
    thread.start()
    assert thread.submit([Batch(None)] * 2, 5e-4) is None  # the first call's losses come at the next hand-over
    assert thread.submit([Batch(None)], 5e-4) == [2.0]
    assert thread.join() == [1.0] and thread.join() is None
    thread.stop()


def test_the_algorithm_follows_a_replaced_policy():
    """The learner asks the algorithm for its policy at each use: a policy replaced after construction acts."""
    model = APGValue("ApgPolicy", "CrowdNav-v0", seed=0, imitation_episodes=0)
    model.policy = copy.deepcopy(model.policy)
    assert model.learner.acting_net() is model.policy.value_net


def test_construction_and_import_leave_torch_threads_and_sb3_alone():
    threads = th.get_num_threads()
    th.set_num_threads(threads + 1)
    try:
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0)
        assert th.get_num_threads() == threads + 1
    finally:
        th.set_num_threads(threads)
    for algo in (PPO, A2C, DQN):
        assert "ApgPolicy" not in algo.policy_aliases
    with pytest.raises(TypeError, match="torch_threads"):
        APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, torch_threads=1)


def test_the_imitation_does_not_import_the_algorithm():
    source = (PACKAGE / "apg_value" / "pretraining.py").read_text()
    assert "apg_value.apg_value" not in source  # no import circle with the algorithm (also tests/test_architecture.py)


UNGUARDED = """
import sb3_crowdnav
from sb3_crowdnav.apg_value import APGValue

APGValue("ApgPolicy", "CrowdNav-v0", seed=0, imitation_episodes=0, learning_starts=8, buffer_size=200,
         batch_size=8, overlap_training="process").learn(24)
"""


@pytest.mark.slow
def test_an_unguarded_script_is_told_what_to_add(tmp_path):
    script = tmp_path / "unguarded.py"
    script.write_text(textwrap.dedent(UNGUARDED))
    env = {**os.environ, "PYTHONPATH": str(PACKAGE.parent)}
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                          env=env)
    assert done.returncode != 0
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("RuntimeError: the learner process failed before it started")
    assert 'if __name__ == "__main__":' in last
    assert "can only join a started process" not in done.stderr
    assert "cannot start a learner process while this process imports the main script" in done.stderr


def test_process_learner_is_a_learner():
    assert issubclass(ProcessLearner, SerialLearner)
    assert all(isinstance(make_learner(kind, lambda: None), Learner) for kind in KINDS)
