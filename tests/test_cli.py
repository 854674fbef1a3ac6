"""Smoke tests of the ``sb3-crowdnav`` command line (in-process, plus one real subprocess)."""

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from sb3_crowdnav.cli import main

torch.set_num_threads(1)
FAST = ["--human-policy", "linear", "--humans", "3", "--no-progress"]


def _nonempty(path: Path) -> bool:
    return path.is_file() and path.stat().st_size > 0


def test_console_script_help():
    exe = shutil.which("sb3-crowdnav", path=str(Path(sys.executable).parent))
    cmd = [exe] if exe else [sys.executable, "-m", "sb3_crowdnav.cli"]
    out = subprocess.run([*cmd, "--help"], capture_output=True, text=True, timeout=60, check=True).stdout
    for command in ("evaluate", "benchmark", "render", "train"):
        assert command in out


@pytest.mark.parametrize("command", ["evaluate", "benchmark", "render", "train"])
def test_subcommand_help(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    assert "--policy" in capsys.readouterr().out or command == "train"


@pytest.mark.parametrize("command", ["aggregate", "sweep", "train"])
def test_a_commands_help_describes_it_with_its_modules_docstring_as_plain_text(command, capsys):
    import importlib

    doc = importlib.import_module(f"sb3_crowdnav.cli.{command}").__doc__
    with pytest.raises(SystemExit):
        main([command, "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert f"sb3-crowdnav {command}" in out and "``" not in out and ":mod:" not in out
    last_words = " ".join(doc.replace("``", "").split()[-6:])  # the docstring's end, markup taken out
    assert last_words in out


def test_evaluate_prints_table_and_writes_files(tmp_path, capsys):
    assert main(["evaluate", "--policy", "orca", "--episodes", "3", *FAST, "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("| method | success | collision | time (s) | return |")
    assert "| ORCA |" in out
    for name in ("results.md", "results.csv", "episodes.csv", "meta.json"):
        assert _nonempty(tmp_path / name)
    rows = list(csv.DictReader((tmp_path / "episodes.csv").open()))
    assert [int(r["seed"]) for r in rows] == [1_000_000, 1_000_001, 1_000_002]
    assert json.loads((tmp_path / "meta.json").read_text())["env_kwargs"]["num_humans"] == 3


def test_env_kwargs_set_the_goal_progress_shaping(tmp_path, capsys):
    """``--env-kwargs "dict(progress_reward=0.1)"`` reaches the env: the same episodes (outcomes, times), the returns
    with the shaping (an ORCA robot gains on its goal)."""
    runs = {}
    for name, extra in (("paper", []), ("shaped", ["--env-kwargs", "dict(progress_reward=0.1)"])):
        assert main(["evaluate", "--policy", "orca", "--episodes", "2", *FAST, *extra, "--out", str(tmp_path / name)]) == 0
        runs[name] = list(csv.DictReader((tmp_path / name / "episodes.csv").open()))
    capsys.readouterr()
    assert [(r["outcome"], r["navigation_time"]) for r in runs["paper"]] == \
        [(r["outcome"], r["navigation_time"]) for r in runs["shaped"]]
    assert all(float(s["discounted_return"]) > float(p["discounted_return"])
               for p, s in zip(runs["paper"], runs["shaped"], strict=True))
    assert json.loads((tmp_path / "shaped" / "meta.json").read_text())["env_kwargs"]["progress_reward"] == 0.1


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_benchmark_writes_table_and_figures(tmp_path, capsys):
    argv = ["benchmark", "--policy", "orca", "--policy", "random", "--episodes", "2", "--out", str(tmp_path),
            "--sweep", "1", "2", *FAST]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "| ORCA |" in out and "| Random |" in out and "| humans |" in out
    for name in ("results.md", "results.csv", "episodes_ORCA.csv", "episodes_Random.csv", "trajectories.png",
                 "episode_ORCA.gif", "episode_Random.gif", "sweep.md", "sweep.csv", "meta.json"):
        assert _nonempty(tmp_path / name), name
    sweep_rows = list(csv.DictReader((tmp_path / "sweep.csv").open()))
    assert [r["humans"] for r in sweep_rows] == ["1", "2"]


@pytest.mark.parametrize("suffix", [".gif", ".png"])
def test_render(tmp_path, suffix, capsys):
    out = tmp_path / f"episode{suffix}"
    assert main(["render", "--policy", "orca", "--seed", "3", "--out", str(out), *FAST]) == 0
    assert _nonempty(out)
    assert "seed 3" in capsys.readouterr().out


def test_train_then_evaluate_the_model(tmp_path, capsys):
    yml = tmp_path / "ppo.yml"
    yml.write_text(
        "CrowdNav-v0:\n"
        "  n_timesteps: 100000\n"
        "  policy: MultiInputPolicy\n"
        "  policy_kwargs: \"dict(net_arch=[16], activation_fn=nn.Tanh)\"\n"
        "  env_kwargs: {human_policy: linear, num_humans: 2}\n"
        "  n_envs: 1\n"
        "  n_steps: 64\n"
        "  batch_size: 32\n"
        "  n_epochs: 1\n"
        "  learning_rate: lin_3e-4\n"
    )
    out = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--hyperparams", str(yml), "--timesteps", "256", "--out", str(out),
                 "--no-progress"]) == 0
    assert _nonempty(out / "ppo.zip") and _nonempty(out / "config.json")
    assert list((out / "tb").rglob("events.out.tfevents*"))
    capsys.readouterr()
    assert main(["evaluate", "--policy", str(out / "ppo.zip"), "--episodes", "2", *FAST]) == 0
    assert "| ppo |" in capsys.readouterr().out

    from sb3_crowdnav.evaluation import plot_learning_curves

    assert _nonempty(plot_learning_curves(out / "tb", tmp_path / "curves.png", tags=("time/fps", "train/loss")))


def test_train_dqn(tmp_path):
    yml = tmp_path / "dqn.yml"
    yml.write_text("CrowdNav-v0:\n  policy_kwargs: 'dict(net_arch=[16])'\n  learning_starts: 50\n  buffer_size: 1000\n"
                   "  train_freq: [4, step]\n")
    assert main(["train", "--algo", "dqn", "--hyperparams", str(yml), "--timesteps", "200", "--out", str(tmp_path),
                 *FAST]) == 0
    assert _nonempty(tmp_path / "dqn.zip")


@pytest.mark.parametrize("argv, fragment", [
    (["evaluate"], "--policy"),
    (["evaluate", "--policy", "orca", "--episodes", "0"], "--episodes"),
    (["evaluate", "--policy", "orca", "--episodes", "two"], "--episodes"),
    (["evaluate", "--policy", "missing.zip", "--episodes", "1"], "missing.zip"),
    (["evaluate", "--policy", "random:x", "--episodes", "1"], "random"),
    (["evaluate", "--policy", "orca", "--humans", "20"], "max_humans"),
    (["evaluate", "--policy", "orca", "--reward", "nice"], "--reward"),
    (["evaluate", "--policy", "orca", "--env-kwargs", "dict(time_limit=__import__('os'))"], "--env-kwargs"),
    (["evaluate", "--policy", "orca", "--env-kwargs", "dict(colour=1)"], "colour"),
    (["evaluate", "--policy", "orca", "--env", "NoSuchEnv-v0"], "NoSuchEnv"),
    (["benchmark", "--policy", "orca"], "--out"),
    (["render", "--policy", "orca", "--out", "episode.avi"], ".gif"),
    (["train", "--algo", "sac", "--hyperparams", "x.yml", "--out", "d"], "--algo"),
    (["train", "--algo", "ppo", "--hyperparams", "missing.yml", "--out", "d"], "missing.yml"),
    (["frobnicate"], "invalid choice"),
    ([], "command"),
])
def test_bad_arguments_exit_2_with_one_line(argv, fragment, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err and "Traceback" not in err
    assert fragment in err


def test_train_rejects_bad_yaml(tmp_path, capsys):
    yml = tmp_path / "bad.yml"
    yml.write_text("OtherEnv-v0:\n  n_timesteps: 10\n")
    with pytest.raises(SystemExit) as exc:
        main(["train", "--algo", "ppo", "--hyperparams", str(yml), "--out", str(tmp_path)])
    assert exc.value.code == 2 and "CrowdNav-v0" in capsys.readouterr().err
    yml.write_text("CrowdNav-v0:\n  policy_kwargs: 'dict(x=open(\"f\"))'\n")
    with pytest.raises(SystemExit) as exc:
        main(["train", "--algo", "ppo", "--hyperparams", str(yml), "--timesteps", "10", "--out", str(tmp_path)])
    assert exc.value.code == 2 and "not allowed" in capsys.readouterr().err


def test_train_with_imitation_and_checkpoints(tmp_path, capsys):
    yml = tmp_path / "ppo.yml"
    yml.write_text("CrowdNav-v0:\n  policy: ApgPolicy\n  policy_kwargs: 'dict(net_arch=[16])'\n  n_steps: 64\n"
                   "  batch_size: 32\n  n_epochs: 1\n")
    out = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--hyperparams", str(yml), "--timesteps", "128", "--out", str(out),
                 "--imitation-episodes", "2", "--imitation-epochs", "1", "--checkpoint-freq", "64", "--verbose", "1",
                 *FAST]) == 0
    assert "imitation:" in capsys.readouterr().out
    # 0: after the imitation; 64: at the start of the second rollout (the run ends at 128 with the final model)
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["ppo_0_steps.zip", "ppo_64_steps.zip"]
    config = json.loads((out / "config.json").read_text())
    assert config["imitation_episodes"] == 2
    progress = json.loads((out / "progress.json").read_text())
    assert progress["finished"] and progress["timesteps"] == 128 and progress["wall_time_s"] == config["wall_time_s"]
    written = (out / "ppo.zip").stat().st_mtime_ns
    argv = ["train", "--algo", "ppo", "--hyperparams", str(yml), "--timesteps", "128", "--out", str(out),
            "--imitation-episodes", "2", "--imitation-epochs", "1", "--checkpoint-freq", "64", *FAST]
    assert main(argv) == 0  # a finished run run again: nothing trained, nothing written
    assert (out / "ppo.zip").stat().st_mtime_ns == written and "imitation:" not in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:  # another run in the same folder: refused, naming what differs
        main([*argv, "--seed", "3"])
    assert exc.value.code == 2
    assert "holds another run (seed differ" in capsys.readouterr().err


def test_a_wall_time_budget_stops_training_before_its_timesteps(tmp_path):
    yml = tmp_path / "ppo.yml"
    yml.write_text("CrowdNav-v0:\n  policy: ApgPolicy\n  policy_kwargs: 'dict(net_arch=[16])'\n  n_steps: 32\n"
                   "  batch_size: 32\n  n_epochs: 1\n")
    out = tmp_path / "run"  # 0.001 min: the budget is spent before the first step ends, so one rollout is collected
    assert main(["train", "--algo", "ppo", "--hyperparams", str(yml), "--timesteps", "100000", "--out", str(out),
                 "--wall-time", "0.001", *FAST]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["timesteps"] < 100 and config["timesteps_asked"] == 100000 and config["wall_time_budget_s"] == 0.06
    from stable_baselines3 import PPO

    assert PPO.load(out / "ppo.zip").num_timesteps == config["timesteps"]


def test_imitation_flag_is_refused_for_apg_value(tmp_path, capsys):
    yml = tmp_path / "apg.yml"
    yml.write_text("CrowdNav-v0:\n  imitation_episodes: 0\n")
    with pytest.raises(SystemExit) as exc:
        main(["train", "--algo", "apg_value", "--hyperparams", str(yml), "--timesteps", "8", "--out", str(tmp_path),
              "--imitation-episodes", "2"])
    assert exc.value.code == 2
    assert "--imitation-episodes" in capsys.readouterr().err


def test_train_dqfd_keeps_demonstrations_and_saves_a_dqn(tmp_path, capsys):
    from stable_baselines3 import DQN

    yml = tmp_path / "dqfd.yml"
    yml.write_text("CrowdNav-v0:\n  policy: ApgPolicy\n  policy_kwargs: 'dict(net_arch=[16])'\n  buffer_size: 500\n"
                   "  learning_starts: 0\n  demo_batch_size: 8\n  margin: 0.2\n")
    with pytest.raises(SystemExit) as exc:  # DQfD without demonstrations is refused
        main(["train", "--algo", "dqfd", "--hyperparams", str(yml), "--timesteps", "8", "--out", str(tmp_path)])
    assert exc.value.code == 2 and "--imitation-episodes" in capsys.readouterr().err
    out = tmp_path / "run"
    assert main(["train", "--algo", "dqfd", "--hyperparams", str(yml), "--timesteps", "32", "--out", str(out),
                 "--imitation-episodes", "2", "--imitation-epochs", "1", *FAST]) == 0
    model = DQN.load(out / "dqfd.zip")
    assert model.num_timesteps == 32 and model.margin == 0.2
    from sb3_crowdnav.training import train_from_hyperparams as train

    trained, _ = train("dqfd", {"policy": "ApgPolicy", "policy_kwargs": "dict(net_arch=[16])", "buffer_size": 500,
                                "learning_starts": 0}, tmp_path / "api", timesteps=16, imitation_episodes=2,
                       imitation_epochs=1, env_overrides={"num_humans": 3, "human_policy": "linear"})
    assert trained.replay_buffer.size() == 16  # the demonstrations stay beside the buffer
    assert len(trained.demonstrations) > 16
