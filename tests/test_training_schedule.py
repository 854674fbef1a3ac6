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
from sb3_crowdnav.training.run_folder import sha256
from sb3_crowdnav.training.schedule import ScheduleConfig

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "train_paper.py"
CLI = [sys.executable, "-u", "-m", "sb3_crowdnav.cli", "train"]


def _run(monkeypatch, *argv: str) -> None:
    """``sb3-crowdnav train ARGV`` (``--variant apg_rl`` unless a variant is given); it must exit 0."""
    variant = [] if "--variant" in argv else ["--variant", "apg_rl"]
    assert main(["train", *variant, *argv]) == 0


@pytest.mark.slow  # a training run or a full CLI run: make slow
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
    for name in ("imitation.zip", "checkpoint_2.zip", "checkpoint_4.zip", "best.zip", "final.zip", "replay_buffer_4.npz"):
        assert (out / name).is_file(), name
    capsys.readouterr()
    assert not (out / "replay_buffer_2.npz").exists()  # only the newest buffer is kept
    _run(monkeypatch, *common, "--rl-episodes", "6", "--overlap")  # resumes from checkpoint_4.zip, now overlapping
    assert "resuming from" in capsys.readouterr().out
    rows = [json.loads(line) for line in (out / "eval_curve.jsonl").read_text().splitlines()]
    assert [r["episodes"] for r in rows] == [2, 4, 6]
    assert APGValue.load(out / "final.zip").policy.lookahead_dtype == "float32"
    _run(monkeypatch, *common, "--rl-episodes", "8", "--overlap", "process")  # and with a learner process
    rows = [json.loads(line) for line in (out / "eval_curve.jsonl").read_text().splitlines()]
    assert [r["episodes"] for r in rows] == [2, 4, 6, 8]
    final = APGValue.load(out / "final.zip")
    assert final.overlap_training == "process" and int(final.policy.optimizer.state_dict()["state"][0]["step"]) > 0
    with pytest.raises(ValueError, match="overlap must be a bool or one of"):
        ScheduleConfig(overlap="fork")


@pytest.mark.skipif(not bfloat16_supported(), reason="no native bfloat16 kernels on this CPU")
def test_bfloat16_lookahead_is_saved(tmp_path, monkeypatch):
    out = tmp_path / "run"
    _run(monkeypatch, "--out", str(out), "--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2",
         "--checkpoint-episodes", "2", "--eval-episodes", "0", "--rl-episodes", "2", "--lookahead-dtype", "bfloat16")
    assert APGValue.load(out / "final.zip").policy.lookahead_dtype == "bfloat16"


@pytest.mark.slow  # a training run or a full CLI run: make slow
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
    saved = APGValue.load(out / progress["checkpoint"])
    assert progress["episodes"] == saved._episode_num >= 2
    assert progress["timesteps"] == saved.num_timesteps
    assert 0 < progress["wall_time_s"] < 120  # imitation and RL up to the checkpoint
    # the resumed segment adds its time to what the run had used (a large stand-in, to tell a sum from a restart)
    (out / "progress.json").write_text(json.dumps({**progress, "wall_time_s": 1e6}))
    capsys.readouterr()
    before = signal.getsignal(signal.SIGTERM)  # (not always SIG_DFL: ray.init, in an earlier test, leaves its own)
    began = time.perf_counter()
    _run(monkeypatch, *common, "--rl-episodes", str(progress["episodes"] + 2))
    segment = time.perf_counter() - began
    checkpoint = out / progress["checkpoint"]
    assert f"resuming from {checkpoint} at episode {progress['episodes']}," in capsys.readouterr().out
    assert APGValue.load(out / "final.zip")._episode_num == progress["episodes"] + 2
    finished = json.loads((out / "progress.json").read_text())
    assert finished["finished"] and 1e6 < finished["wall_time_s"] <= 1e6 + segment + 0.1
    assert signal.getsignal(signal.SIGTERM) is before  # the handler the process had is restored after training


@pytest.mark.slow  # a training run or a full CLI run: make slow
@pytest.mark.parametrize("refill", [0, 100_000])
def test_resume_without_replay_buffer_refills_before_training(tmp_path, monkeypatch, capsys, refill):
    """A run carried to another machine without its replay buffer: no gradient step until the buffer is refilled."""
    out = tmp_path / "run"
    common = ["--out", str(out), "--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2",
              "--checkpoint-episodes", "2", "--eval-episodes", "0"]
    _run(monkeypatch, *common, "--rl-episodes", "2")
    before = APGValue.load(out / "checkpoint_2.zip")
    (out / "replay_buffer_2.npz").unlink()
    capsys.readouterr()
    _run(monkeypatch, *common, "--rl-episodes", "4", "--refill-steps", str(refill))
    assert f"no replay buffer in {out}: collecting {refill} transitions" in capsys.readouterr().out
    after = APGValue.load(out / "final.zip")
    assert after._episode_num == 4 and after.num_timesteps > before.num_timesteps
    if refill:  # 2 episodes are far fewer than 100,000 steps: V is untouched
        assert after._n_updates == before._n_updates
    else:
        assert after._n_updates > before._n_updates


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_fine_tuning_a_trained_model(tmp_path, monkeypatch):
    """--from-imitation with a trained model and no demonstrations beside it: ε from --epsilon-start, the lookahead
    with --pedestrian-model, and no gradient step before --refill-steps transitions (then training resumes)."""
    first, tuned = tmp_path / "first", tmp_path / "tuned"
    common = ["--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2", "--checkpoint-episodes", "2",
              "--eval-episodes", "0"]
    _run(monkeypatch, *common, "--out", str(first), "--rl-episodes", "2", "--overlap", "off")
    assert json.loads((first / "config.json").read_text())["overlap"] is False
    source = tmp_path / "trained.zip"  # a model alone in its folder: no imitation_replay_buffer.npz beside it
    (first / "final.zip").rename(source)
    trained = APGValue.load(source)
    assert trained.policy.pedestrian_model == "constant_velocity"
    for refill, episodes in ((100_000, 2), (0, 2)):
        out = tuned / str(refill)
        _run(monkeypatch, *common, "--out", str(out), "--rl-episodes", str(episodes), "--from-imitation", str(source),
             "--epsilon-start", "0.05", "--epsilon-end", "0.02", "--exploration-episodes", "10",
             "--pedestrian-model", "cautious", "--refill-steps", str(refill))
        model = APGValue.load(out / "final.zip")
        assert (model.exploration_initial_eps, model.exploration_final_eps) == (0.05, 0.02)
        assert 0.02 < model.exploration_rate < 0.05  # 2 of 10 decay episodes
        assert model.policy.pedestrian_model == "cautious"
        assert model._episode_num == episodes
        if refill:
            assert model._n_updates == trained._n_updates  # V untouched while the buffer fills
        else:
            assert model._n_updates > trained._n_updates
    config = ScheduleConfig(exploration_initial_eps=0.2, pedestrian_model="cautious")
    assert (config.exploration_initial_eps, config.exploration_final_eps, config.pedestrian_model) == (0.2, 0.1, "cautious")
    for bad, error in ((dict(exploration_initial_eps=1.5), ValueError), (dict(exploration_final_eps=True), TypeError),
                       (dict(pedestrian_model="psychic"), ValueError)):
        with pytest.raises(error, match=next(iter(bad))):
            ScheduleConfig(**bad)


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_a_resumed_run_keeps_its_own_settings_and_says_so(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    common = ["--out", str(out), "--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2",
              "--checkpoint-episodes", "2", "--eval-episodes", "0", "--overlap", "off"]
    _run(monkeypatch, *common, "--rl-episodes", "2", "--train-freq", "4")
    capsys.readouterr()
    _run(monkeypatch, *common, "--rl-episodes", "4")  # apg_rl's default is 8: the run goes on with 4
    assert "the run keeps its own train_freq=4 (given or default: 8)" in capsys.readouterr().out
    assert APGValue.load(out / "final.zip").train_freq.frequency == 4
    assert json.loads((out / "config.json").read_text())["train_freq"] == 4


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


@pytest.mark.slow  # a training run or a full CLI run: make slow
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


TINY_RUN = ["--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2", "--checkpoint-episodes", "2"]


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_one_run_per_folder_and_a_stale_lock_is_taken_over(tmp_path, capsys):
    import os

    out = tmp_path / "run"
    out.mkdir()
    (out / "run.lock").write_text(json.dumps({"pid": os.getpid(), "host": __import__("socket").gethostname()}))
    with pytest.raises(SystemExit) as exc:  # this very process holds it: alive
        main(["train", "--variant", "apg_rl", "--out", str(out), *TINY_RUN, "--rl-episodes", "2"])
    assert exc.value.code == 2 and f"is in use by process {os.getpid()}" in capsys.readouterr().err
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (out / "run.lock").write_text(json.dumps({"pid": int(dead.stdout), "host": __import__("socket").gethostname()}))
    assert main(["train", "--variant", "apg_rl", "--out", str(out), *TINY_RUN, "--eval-episodes", "0",
                 "--rl-episodes", "2"]) == 0
    assert not (out / "run.lock").exists()  # released


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_a_finished_run_run_again_changes_nothing(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    argv = ["--out", str(out), *TINY_RUN, "--eval-episodes", "1", "--rl-episodes", "2"]
    _run(monkeypatch, *argv)
    files = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    capsys.readouterr()
    _run(monkeypatch, *argv)
    assert "nothing to do" in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == files


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_resume_validates_an_unvalidated_checkpoint_and_repairs_best(tmp_path, monkeypatch):
    out = tmp_path / "run"
    argv = ["--out", str(out), *TINY_RUN, "--eval-episodes", "2"]
    _run(monkeypatch, *argv, "--rl-episodes", "2")
    progress = json.loads((out / "progress.json").read_text())
    progress["validated"], progress["finished"] = [], False  # as if killed after saving, before validating
    (out / "progress.json").write_text(json.dumps(progress))
    (out / "eval_curve.jsonl").unlink()
    (out / "best.zip").write_bytes(b"damaged")
    _run(monkeypatch, *argv, "--rl-episodes", "4")
    rows = [json.loads(line)["episodes"] for line in (out / "eval_curve.jsonl").read_text().splitlines()]
    assert rows == [2, 4]
    best = json.loads((out / "best.json").read_text())


    assert best["sha256"] == sha256(out / "best.zip") and APGValue.load(out / "best.zip") is not None


SAVE_POINTS = ["imitation:1", "buffer:1", "checkpoint:1", "progress:1", "eval:1", "best_zip:1", "best_json:1",
               "buffer:2", "checkpoint:2", "eval:2", "final:1"]


@pytest.mark.slow
@pytest.mark.parametrize("kill_at", SAVE_POINTS)
def test_a_kill_at_any_save_point_resumes_into_a_consistent_run(tmp_path, kill_at):
    """SIGKILL at each save point in turn, resume with the same command: a complete, consistent run."""
    import os

    from sb3_crowdnav.training.run_folder import checkpoints

    out = tmp_path / "run"
    argv = [*CLI, "--variant", "apg_rl", "--out", str(out), *TINY_RUN, "--eval-episodes", "2", "--rl-episodes", "4"]
    killed = subprocess.run(argv, env={**os.environ, "SB3_CROWDNAV_KILL_AT": kill_at}, capture_output=True, text=True)
    assert killed.returncode == -signal.SIGKILL, killed.stdout[-2000:] + killed.stderr[-2000:]
    resumed = subprocess.run(argv, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stdout[-2000:] + resumed.stderr[-2000:]
    assert checkpoints(out)[-1] == 4 and APGValue.load(out / "final.zip")._episode_num == 4
    rows = [json.loads(line)["episodes"] for line in (out / "eval_curve.jsonl").read_text().splitlines()]
    assert rows == [2, 4]  # every checkpoint validated exactly once
    best = json.loads((out / "best.json").read_text())
    assert best["sha256"] == sha256(out / "best.zip")
    progress = json.loads((out / "progress.json").read_text())
    assert progress["finished"] and progress["episodes"] == 4 and progress["validated"] == [2, 4]
    assert sorted(p.name for p in out.glob("replay_buffer_*.npz")) == ["replay_buffer_4.npz"]
    assert not list(out.glob(".*.tmp*")) and not (out / "run.lock").exists()


def test_warehouse_variant_trains_in_the_warehouse(tmp_path, monkeypatch):
    out = tmp_path / "warehouse"
    _run(monkeypatch, "--variant", "apg_warehouse", "--out", str(out), "--il-episodes", "2", "--il-epochs", "1",
         "--num-humans", "2", "--rl-episodes", "2", "--checkpoint-episodes", "2", "--eval-episodes", "1")
    config = json.loads((out / "config.json").read_text())
    assert config["variant"] == "apg_warehouse"
    progress = json.loads((out / "progress.json").read_text())  # the budget a table of seeds states
    assert progress["finished"] and progress["timesteps"] > 0 and progress["wall_time_s"] > 0
    model = APGValue.load(out / "final.zip")
    assert model.policy.world.has_static_world
    assert any("static_world" in n for n, _ in model.policy.named_parameters())  # and V sees them
    # the finished run's models search two steps (the variant's depth), its checkpoints one, best.json follows the file
    assert model.policy.planning_depth == 2 and APGValue.load(out / "best.zip").policy.planning_depth == 2
    assert APGValue.load(out / "checkpoint_2.zip").policy.planning_depth == 1
    best = json.loads((out / "best.json").read_text())
    assert best["sha256"] == sha256(out / "best.zip") and best["planning_depth"] == 2
    before = {name: sha256(out / name) for name in ("best.zip", "final.zip")}
    _run(monkeypatch, "--variant", "apg_warehouse", "--out", str(out), "--il-episodes", "2", "--il-epochs", "1",
         "--num-humans", "2", "--rl-episodes", "2", "--checkpoint-episodes", "2", "--eval-episodes", "1")
    assert {name: sha256(out / name) for name in before} == before  # a finished run is left as it is


def test_finish_depth_sets_a_killed_runs_depth_on_rerun(tmp_path):
    """A run killed between final.zip and its depth gets the depth from the rerun ("nothing to do"), once."""
    import gymnasium as gym

    from sb3_crowdnav.training.callbacks import finish_depth

    env = gym.make("CrowdNavWarehouse-v0")
    model = APGValue("ApgPolicy", env, learning_starts=0, seed=0)
    model.save(tmp_path / "final.zip")
    model.save(tmp_path / "best.zip")
    (tmp_path / "best.json").write_text(json.dumps({"sha256": sha256(tmp_path / "best.zip"), "score": [1.0]}))
    said = []
    finish_depth(tmp_path, 3, said.append)
    assert len(said) == 2 and all(APGValue.load(tmp_path / n).policy.planning_depth == 3 for n in ("best.zip", "final.zip"))
    assert json.loads((tmp_path / "best.json").read_text())["sha256"] == sha256(tmp_path / "best.zip")
    finish_depth(tmp_path, 3, said.append)
    assert len(said) == 2  # already at that depth: nothing written


def test_a_variant_brings_its_env_settings_and_schedule_and_a_run_overrides_them():
    from sb3_crowdnav.training.schedule import ScheduleConfig

    paper, warehouse = ScheduleConfig(variant="apg_rl"), ScheduleConfig(variant="apg_warehouse")
    assert (paper.rl_episodes, paper.exploration_episodes) == (10_000, 5_000)
    assert (paper.train_freq, warehouse.train_freq, ScheduleConfig(variant="sarl").train_freq) == (8, 8, 4)
    assert paper.overlap == warehouse.overlap == "process"
    assert ScheduleConfig(variant="apg_rl", train_freq=4).train_freq == 4
    assert (warehouse.rl_episodes, warehouse.exploration_episodes, warehouse.imitation_epochs) == (7_000, 3_500, 5)
    assert warehouse.pedestrian_model == "cautious" and paper.pedestrian_model is None
    assert warehouse.stopping_check is True and paper.stopping_check is None  # the warehouse recipe brakes in time
    assert ScheduleConfig(variant="apg_warehouse", stopping_check=False).stopping_check is False
    assert (warehouse.planning_depth, paper.planning_depth) == (2, 1)  # the depth the finished run's models act with
    assert ScheduleConfig(variant="apg_warehouse", planning_depth=1).planning_depth == 1
    with pytest.raises(ValueError, match="planning_depth must be >= 1"):
        ScheduleConfig(planning_depth=0)
    assert warehouse.num_humans == (4, 10) and warehouse.training_env_kwargs["worlds"] == "warehouse"
    old = ScheduleConfig(variant="apg_warehouse_paper")  # the shipped apg_warehouse_paper's world
    assert old.spec.env_id == "CrowdNavWarehouse-v0" and old.training_env_kwargs["actions"] == "paper"
    assert old.training_env_kwargs["robot_visible"] is False and old.pedestrian_model is None
    assert "progress_reward" not in paper.training_env_kwargs
    assert warehouse.training_env_kwargs["progress_reward"] == 0.1
    unshaped = ScheduleConfig(variant="apg_warehouse", env_kwargs={"progress_reward": 0.0}, rl_episodes=10_000)
    assert unshaped.training_env_kwargs["progress_reward"] == 0.0 and unshaped.rl_episodes == 10_000
    assert unshaped.exploration_episodes == 3_500


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_a_run_with_the_stopping_check_acts_with_it_and_saves_it(tmp_path, monkeypatch):
    """--stopping-check: the acting lookahead charges the speeds the robot cannot brake from (a world with an
    acceleration limit), and every saved model keeps the check; --no-stopping-check switches it off when resuming."""
    out = tmp_path / "run"
    common = ["--out", str(out), "--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2",
              "--checkpoint-episodes", "2", "--eval-episodes", "0", "--overlap", "off",
              "--env-kwargs", "dict(actions='with_stop', max_acceleration=1.0, max_turn_rate=1.5)"]
    _run(monkeypatch, *common, "--rl-episodes", "2", "--stopping-check")
    assert json.loads((out / "config.json").read_text())["stopping_check"] is True
    assert APGValue.load(out / "checkpoint_2.zip").policy.stopping_check
    _run(monkeypatch, *common, "--rl-episodes", "4", "--no-stopping-check")
    assert not APGValue.load(out / "final.zip").policy.stopping_check


def test_the_stopping_check_is_refused_before_any_work(tmp_path, capsys):
    """A world without an acceleration limit (the paper's robot) refuses --stopping-check with exit 2 and one line,
    before the run folder exists; ScheduleConfig refuses a non-bool, and train_schedule a world without the limit."""
    from sb3_crowdnav.training.schedule import train_schedule

    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        main(["train", "--variant", "apg_rl", "--stopping-check", "--out", str(out)])
    assert exc.value.code == 2 and "--stopping-check" in capsys.readouterr().err and not out.exists()
    with pytest.raises(TypeError, match="stopping_check"):
        ScheduleConfig(stopping_check="yes")
    with pytest.raises(ValueError, match="max_acceleration"):
        train_schedule(out, ScheduleConfig(stopping_check=True, imitation_episodes=1, rl_episodes=1))
    assert not (out / "imitation.zip").exists()


@pytest.mark.slow  # two training runs
@pytest.mark.parametrize("overlap", ["thread", "process"])
def test_the_validation_is_of_the_saved_checkpoint(tmp_path, monkeypatch, overlap):
    """While training overlaps the acting loop, the live model acts with a copy of V one training call stale; the
    validation of a checkpoint acts with the V of its saved file (what best.zip copies)."""
    import torch as th

    from sb3_crowdnav.training import callbacks

    acted = []

    def recording(model, *args, **kwargs):  # the V that acts in the validation episodes
        acted.append({k: v.clone() for k, v in model.learner.acting_net().state_dict().items()})
        return run_episodes(model, *args, **kwargs)

    run_episodes = callbacks.run_episodes
    monkeypatch.setattr(callbacks, "run_episodes", recording)
    out = tmp_path / "run"
    _run(monkeypatch, "--out", str(out), "--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2",
         "--checkpoint-episodes", "2", "--eval-episodes", "1", "--rl-episodes", "2", "--train-freq", "1",
         "--overlap", overlap)
    saved = APGValue.load(out / "checkpoint_2.zip").policy.value_net.state_dict()
    assert len(acted) == 1 and acted[0].keys() == saved.keys()
    assert all(th.equal(acted[0][k], saved[k]) for k in saved)


@pytest.mark.parametrize("flag, key", [("--imitation-epochs", "imitation_epochs"), ("--rl-episodes", "rl_episodes"),
                                       ("--train-freq", "train_freq"), ("--checkpoint-episodes", "checkpoint_episodes"),
                                       ("--exploration-episodes", "exploration_episodes"),
                                       ("--planning-depth", "planning_depth")])
def test_train_help_states_every_variants_default(flag, key, capsys):
    """The help's "default: the variant's: X; name, name: Y" is what a run of each variant gets."""
    import re

    from sb3_crowdnav.training.schedule import VARIANTS

    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    start = re.search(rf"(?<!\[){flag} [A-Z_]+[ ,]", text).start()  # the flag's entry, not the usage line's
    stated = re.search(r"default: the variant's: ([^;)]+)((?:; [a-z_, ]+: [^;)]+)*)", text[start:])
    assert stated is not None, text[start:start + 300]
    per_name = {name: stated.group(1) for name in VARIANTS}
    for part in filter(None, stated.group(2).split("; ")):
        names, value = part.split(": ")
        for name in names.split(", "):
            assert name in VARIANTS, part
            per_name[name] = value
    for name in VARIANTS:
        assert per_name[name] == str(getattr(ScheduleConfig(variant=name), key)), (flag, name)
