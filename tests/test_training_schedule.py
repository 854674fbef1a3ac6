"""The paper's schedule (``sb3-crowdnav train --variant``): checkpoints, validation curve, best model, resume."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.cli import main
from sb3_crowdnav.nn.layers import bfloat16_supported

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "train_paper.py"
CLI = [sys.executable, "-u", "-m", "sb3_crowdnav.cli", "train"]


def _run(monkeypatch, *argv: str) -> None:
    """``sb3-crowdnav train ARGV`` (``--variant apg_rl`` unless a variant is given); it must exit 0."""
    variant = [] if "--variant" in argv else ["--variant", "apg_rl"]
    assert main(["train", *variant, *argv]) == 0


def test_checkpoints_validation_selection_and_resume(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    common = ["--variant", "apg_crl", "--out", str(out), "--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2",
              "--checkpoint-episodes", "2", "--eval-episodes", "2", "--select-by", "return"]
    _run(monkeypatch, *common, "--rl-episodes", "4")
    rows = [json.loads(line) for line in (out / "eval_curve.jsonl").read_text().splitlines()]
    assert [r["episodes"] for r in rows] == [2, 4]
    assert all({"success", "return", "comfort_time", "heading"} <= set(r) for r in rows)
    assert all(r["eval_seconds"] > 0 for r in rows)
    best = json.loads((out / "best.json").read_text())
    assert best["select_by"] == "return"
    assert best["score"] == [max(r["return"] for r in rows)]
    for name in ("imitation.zip", "checkpoint_2.zip", "checkpoint_4.zip", "best.zip", "final.zip", "replay_buffer.pkl"):
        assert (out / name).is_file(), name
    capsys.readouterr()
    _run(monkeypatch, *common, "--rl-episodes", "6", "--overlap")  # resumes from checkpoint.zip, now overlapping
    assert "resuming from" in capsys.readouterr().out
    rows = [json.loads(line) for line in (out / "eval_curve.jsonl").read_text().splitlines()]
    assert [r["episodes"] for r in rows] == [2, 4, 6]
    assert APGValue.load(out / "final.zip").policy.lookahead_dtype == "float32"


@pytest.mark.skipif(not bfloat16_supported(), reason="no native bfloat16 kernels on this CPU")
def test_bfloat16_lookahead_is_saved(tmp_path, monkeypatch):
    out = tmp_path / "run"
    _run(monkeypatch, "--out", str(out), "--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2",
         "--checkpoint-episodes", "2", "--eval-episodes", "0", "--rl-episodes", "2", "--lookahead-dtype", "bfloat16")
    assert APGValue.load(out / "final.zip").policy.lookahead_dtype == "bfloat16"


def test_sigterm_writes_a_checkpoint_and_the_run_resumes(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    common = ["--out", str(out), "--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2",
              "--checkpoint-episodes", "2", "--eval-episodes", "0"]
    proc = subprocess.Popen([*CLI, "--variant", "apg_rl", *common, "--rl-episodes", "100000"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (out / "checkpoint_2.zip").exists():  # in the RL phase, with a first checkpoint written
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[0] if proc.poll() else ""
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        output, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, output
    assert "stopped by signal" in output
    assert not (out / "final.zip").exists()
    progress = json.loads((out / "progress.json").read_text())
    saved = APGValue.load(out / "checkpoint.zip")
    assert progress["episodes"] == saved._episode_num >= 2
    assert progress["timesteps"] == saved.num_timesteps
    capsys.readouterr()
    _run(monkeypatch, *common, "--rl-episodes", str(progress["episodes"] + 2))
    assert f"resuming from {out / 'checkpoint.zip'} at episode {progress['episodes']}," in capsys.readouterr().out
    assert APGValue.load(out / "final.zip")._episode_num == progress["episodes"] + 2
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # handlers restored after training


@pytest.mark.parametrize("refill", [0, 100_000])
def test_resume_without_replay_buffer_refills_before_training(tmp_path, monkeypatch, capsys, refill):
    """A run carried to another machine without replay_buffer.pkl: no gradient step until the buffer is refilled."""
    out = tmp_path / "run"
    common = ["--out", str(out), "--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2",
              "--checkpoint-episodes", "2", "--eval-episodes", "0"]
    _run(monkeypatch, *common, "--rl-episodes", "2")
    before = APGValue.load(out / "checkpoint.zip")
    (out / "replay_buffer.pkl").unlink()
    capsys.readouterr()
    _run(monkeypatch, *common, "--rl-episodes", "4", "--refill-steps", str(refill))
    assert f"no replay buffer in {out}: collecting {refill} transitions" in capsys.readouterr().out
    after = APGValue.load(out / "final.zip")
    assert after._episode_num == 4 and after.num_timesteps > before.num_timesteps
    if refill:  # 2 episodes are far fewer than 100,000 steps: V is untouched
        assert after._n_updates == before._n_updates
    else:
        assert after._n_updates > before._n_updates


def test_negative_refill_steps_is_rejected(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["train", "--variant", "apg_rl", "--out", str(tmp_path / "run"), "--refill-steps", "-1"])
    assert exc.value.code == 2
    assert "--refill-steps: expected an integer >= 0, got '-1'" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # refused before any work


@pytest.mark.parametrize(("argv", "message"), [
    (["--variant", "apg_rl", "--algo", "ppo"], "--algo is not used with --variant"),
    (["--variant", "apg_rl", "--timesteps", "10"], "--timesteps is not used with --variant"),
    (["--hyperparams", "zoo_hyperparams/ppo.yml", "--rl-episodes", "3"], "--rl-episodes is not used with --hyperparams"),
    (["--hyperparams", "zoo_hyperparams/ppo.yml"], "--hyperparams needs --algo"),
    (["--variant", "apg_crl", "--reward", "crowdnav"], "variant 'apg_crl' trains with reward 'comfort'"),
    (["--variant", "apg_rl", "--env", "CrowdNavSquare-v0"], "variant apg_rl trains on CrowdNav-v0"),
    (["--variant", "apg_rl", "--il-learning-rate", "0"], "expected a finite number > 0"),
    (["--variant", "nope"], "invalid choice: 'nope'"),
    ([], "one of the arguments --variant --hyperparams is required"),
])
def test_train_refuses_flags_of_the_other_mode(tmp_path, capsys, argv, message):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        main(["train", "--out", str(out), *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()  # nothing written before the arguments are known to be good


def test_python_api_and_example(tmp_path, monkeypatch, capsys):
    """train_schedule() is what the CLI runs; examples/train_paper.py calls it and resumes like the CLI."""
    from sb3_crowdnav.training import ScheduleConfig, train_schedule

    with pytest.raises(ValueError, match="variant must be one of"):
        ScheduleConfig(variant="apg")
    with pytest.raises(ValueError, match="checkpoint_episodes must be >= 1, got 0"):
        ScheduleConfig(checkpoint_episodes=0)
    out = tmp_path / "api"
    config = ScheduleConfig(rl_episodes=2, imitation_episodes=2, imitation_epochs=1, num_humans=2, checkpoint_episodes=2,
                            eval_episodes=0)
    result = train_schedule(out, config, log=lambda message: None)
    assert result.stopped_by is None and result.model._episode_num == 2
    assert APGValue.load(out / "final.zip")._episode_num == 2
    example = tmp_path / "example"
    monkeypatch.setattr(sys, "argv", [str(EXAMPLE), "--out", str(example), "--il-episodes", "2", "--rl-episodes", "2",
                                      "--checkpoint-episodes", "2", "--eval-episodes", "0"])
    import runpy

    with pytest.raises(SystemExit) as exc:
        runpy.run_path(str(EXAMPLE), run_name="__main__")
    assert exc.value.code == 0
    assert APGValue.load(example / "final.zip")._episode_num == 2
