"""A hyperparameter-file run (``train --hyperparams --checkpoint-freq``) killed mid-run resumes from its newest
checkpoint with its replay buffer and the wall time it had used (fault injection: make slow)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

CLI = [sys.executable, "-u", "-m", "sb3_crowdnav.cli", "train"]
FAST = ["--human-policy", "linear", "--humans", "3", "--no-progress", "--verbose", "1"]


@pytest.mark.slow
def test_a_killed_dqn_run_resumes_with_its_replay_buffer(tmp_path):
    yml = tmp_path / "dqn.yml"
    yml.write_text("CrowdNav-v0:\n  policy: ApgPolicy\n  policy_kwargs: 'dict(net_arch=[16])'\n  buffer_size: 1000\n"
                   "  learning_starts: 16\n  batch_size: 16\n")
    out = tmp_path / "run"
    argv = [*CLI, "--algo", "dqn", "--hyperparams", str(yml), "--timesteps", "256", "--checkpoint-freq", "64",
            "--out", str(out), *FAST]
    killed = subprocess.run(argv, env={**os.environ, "SB3_CROWDNAV_KILL_AT": "zoo_checkpoint:3"}, capture_output=True,
                            text=True)  # killed right after the checkpoint of 128 steps (0 and 64 before it)
    assert killed.returncode == -signal.SIGKILL, killed.stdout[-2000:] + killed.stderr[-2000:]
    first = json.loads((out / "progress.json").read_text())
    assert (first["timesteps"], first["finished"]) == (128, False) and not (out / "dqn.zip").exists()
    resumed = subprocess.run(argv, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stdout[-2000:] + resumed.stderr[-2000:]
    assert "resuming from" in resumed.stdout and "dqn_128_steps.zip" in resumed.stdout
    progress = json.loads((out / "progress.json").read_text())
    assert progress["finished"] and progress["timesteps"] == 256 and progress["wall_time_s"] > first["wall_time_s"]
    with np.load(out / "checkpoints" / "dqn_replay_buffer_192_steps.npz") as buffer:
        assert int(buffer["meta.pos"]) == 192  # the 128 transitions before the kill were reloaded
    assert sorted(p.name for p in (out / "checkpoints").glob("*.npz")) == ["dqn_replay_buffer_192_steps.npz"]
    assert not (out / "run.lock").exists() and not list((out / "checkpoints").glob(".*.tmp*"))
    from sb3_crowdnav.models import load_model

    assert load_model(out / "dqn.zip").num_timesteps == 256
