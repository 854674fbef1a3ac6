"""Every command, bad values of every argument: exit status 2, one line naming the argument, before any work."""

from __future__ import annotations

from pathlib import Path

import pytest

from sb3_crowdnav.cli import main

HYPER = Path(__file__).resolve().parents[1] / "zoo_hyperparams"
YAML = {
    "bad": "CrowdNav-v0: [\n",
    "hostile": 'CrowdNav-v0: !!python/object/apply:os.system ["touch pwned"]\n',
    "lr": "CrowdNav-v0:\n  n_timesteps: 10\n  learning_rate: abc\n",
    "batch": "CrowdNav-v0:\n  n_timesteps: 10\n  batch_size: -1\n",
    "unknown": "CrowdNav-v0:\n  n_timesteps: 10\n  not_a_key: 3\n",
    "no_env": "Other-v0:\n  n_timesteps: 10\n",
    "policy_kwargs": "CrowdNav-v0:\n  n_timesteps: 10\n  policy_kwargs: \"__import__('os')\"\n",
    "normalize": "CrowdNav-v0:\n  n_timesteps: 10\n  normalize: true\n",
}
ENV_CASES = [  # (arguments, what the message must say), for every command that makes an env
    (["--env", "CartPole-v1"], "is not a crowd-navigation env"),
    (["--env", "NoSuchEnv-v0"], "--env"),
    (["--humans", "-1"], "--humans"),
    (["--humans", "x"], "--humans"),
    (["--humans", "99"], "num_humans"),
    (["--max-humans", "0"], "--max-humans"),
    (["--max-humans", "1000"], "max_humans must be <= 100"),
    (["--reward", "nice"], "--reward"),
    (["--kinematics", "car"], "--kinematics"),
    (["--human-policy", "sf"], "--human-policy"),
    (["--env-kwargs", "dict(human_radius=3.0)"], "human_radius must be <= 2.0 m"),
    (["--env-kwargs", "dict(time_step=1e-7, num_humans=0)"], "steps per episode"),
    (["--env-kwargs", "{time_limit: 30}"], "dict(time_limit=30)"),
    (["--env-kwargs", "__import__('os')"], "--env-kwargs"),
    (["--env-kwargs", "[1, 2]"], "--env-kwargs must be a dict"),
    (["--env-kwargs", "dict(no_such=1)"], "no_such"),
    (["--humans", "4", "--env-kwargs", "dict(num_humans=5)"], "--humans and --env-kwargs num_humans both set"),
    (["--visible", "--env-kwargs", "dict(robot_visible=0.5)"], "--visible and --env-kwargs robot_visible"),
    (["--threads", "0"], "--threads"),
]
POLICY_CASES = [
    (["--policy", "random:-5"], "SEED >= 0"),
    (["--policy", "random:x"], "random:SEED"),
    (["--policy", "pretrained:nope"], "unknown pretrained model 'nope'"),
    (["--policy", "missing.zip"], "no saved model"),
    (["--policy", "pretrained:apg_rl", "--max-humans", "12"], "trained on observations"),
    (["--policy", "pretrained:apg_rl", "--kinematics", "holonomic"], "--allow-env-mismatch"),
]


def _commands(tmp_path: Path) -> dict[str, list[str]]:
    return {
        "evaluate": ["evaluate", "--policy", "orca", "--episodes", "1"],
        "benchmark": ["benchmark", "--policy", "orca", "--episodes", "1", "--no-gif", "--out", str(tmp_path / "b")],
        "render": ["render", "--policy", "orca", "--out", str(tmp_path / "r" / "e.gif")],
        "train": ["train", "--algo", "ppo", "--hyperparams", str(HYPER / "ppo.yml"), "--timesteps", "8",
                  "--out", str(tmp_path / "t")],
    }


def _refused(capsys, argv: list[str], fragment: str) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2, err
    assert fragment in err, err
    assert len(err.strip().splitlines()) == 1, err


def _nothing_written(tmp_path: Path) -> None:
    assert not [p for p in tmp_path.rglob("*") if p.is_file() and p.suffix != ".yml"]


@pytest.mark.parametrize("command", ["evaluate", "benchmark", "render", "train"])
@pytest.mark.parametrize(("args", "fragment"), ENV_CASES)
def test_bad_env_arguments(tmp_path, capsys, command, args, fragment):
    _refused(capsys, [*_commands(tmp_path)[command], *args], fragment)
    _nothing_written(tmp_path)


@pytest.mark.parametrize("command", ["evaluate", "benchmark", "render"])
@pytest.mark.parametrize(("args", "fragment"), POLICY_CASES)
def test_bad_policies(tmp_path, capsys, command, args, fragment):
    argv = _commands(tmp_path)[command]
    at = argv.index("--policy")
    _refused(capsys, [*argv[:at], *argv[at + 2:], *args], fragment)
    _nothing_written(tmp_path)


@pytest.mark.parametrize(("argv", "fragment"), [
    (["evaluate", "--policy", "orca", "--episodes", "0"], "--episodes"),
    (["evaluate", "--policy", "orca", "--workers", "0"], "--workers"),
    (["evaluate", "--policy", "orca", "--seed-offset", "-1"], "--seed-offset"),
    (["evaluate", "--policy", "orca", "--episodes", "1", "--out", "FILE"], "is a file, not a folder"),
    (["evaluate", "--policy", "orca", "--episodes", "1", "--out", "FILE/sub"], "cannot be written"),
    (["benchmark", "--policy", "orca", "--episodes", "1", "--sweep", "99", "--out", "B"], "--sweep 99"),
    (["benchmark", "--policy", "orca", "--episodes", "1", "--sweep", "-1", "--out", "B"], "--sweep"),
    (["benchmark", "--policy", "orca", "--episodes", "1", "--figure-seed", "-2", "--out", "B"], "--figure-seed"),
    (["benchmark", "--policy", "orca", "--episodes", "1"], "--out"),
    (["evaluate", "--policy", "orca", "--episodes", "1", "--pedestrian-model", "cautious"], "--pedestrian-model"),
    (["benchmark", "--policy", "orca", "--policy", "random", "--no-stopping-check", "--episodes", "1", "--out", "B"],
     "--stopping-check: set the lookahead of value models"),
    (["evaluate", "--policy", "pretrained:apg_rl", "--pedestrian-model", "psychic"], "--pedestrian-model"),
    (["evaluate", "--policy", "pretrained:apg_rl", "--episodes", "1", "--stopping-check"], "stopping"),
    (["render", "--policy", "orca", "--fps", "1e-9", "--out", "R/e.gif"], "--fps must be in [0.1, 60]"),
    (["render", "--policy", "orca", "--fps", "nan", "--out", "R/e.gif"], "--fps"),
    (["render", "--policy", "orca", "--out", "R/e.avi"], "must end in .gif, .mp4 or .png"),
    (["render", "--policy", "orca", "--seed", "-1", "--out", "R/e.gif"], "--seed"),
    (["train", "--variant", "apg_warehouse", "--env", "CrowdNav-v0", "--out", "T"], "trains on CrowdNavWorlds-v0"),
    (["train", "--variant", "apg_rl", "--checkpoint-episodes", "0", "--out", "T"], "--checkpoint-episodes"),
    (["train", "--variant", "apg_rl", "--eval-episodes", "-1", "--out", "T"], "--eval-episodes"),
    (["train", "--variant", "apg_rl", "--n-envs", "0", "--out", "T"], "--n-envs"),
    (["train", "--variant", "apg_rl", "--buffer-size", "0", "--out", "T"], "--buffer-size"),
    (["train", "--variant", "apg_rl", "--rl-episodes", "-3", "--out", "T"], "--rl-episodes"),
    (["train", "--variant", "apg_rl", "--learning-rate", "abc", "--out", "T"], "--learning-rate"),
    (["train", "--variant", "apg_rl", "--from-imitation", "missing.zip", "--out", "T"], "--from-imitation"),
    (["train", "--variant", "apg_rl", "--out", "FILE"], "is a file, not a folder"),
    (["train", "--variant", "apg_rl", "--train-freq", "0", "--out", "T"], "--train-freq"),
    (["train", "--variant", "apg_rl", "--exploration-episodes", "0", "--out", "T"], "--exploration-episodes"),
    (["train", "--variant", "apg_rl", "--select-by", "luck", "--out", "T"], "--select-by"),
    (["train", "--variant", "apg_rl", "--optimizer", "rmsprop", "--out", "T"], "--optimizer"),
    (["train", "--variant", "apg_rl", "--value-target", "mc", "--out", "T"], "--value-target"),
    (["train", "--variant", "apg_rl", "--lookahead-dtype", "int8", "--out", "T"], "--lookahead-dtype"),
    (["train", "--variant", "apg_rl", "--refill-steps", "-1", "--out", "T"], "--refill-steps"),
    (["train", "--variant", "apg_rl", "--epsilon-start", "1.5", "--out", "T"], "--epsilon-start"),
    (["train", "--variant", "apg_rl", "--epsilon-end", "-0.1", "--out", "T"], "--epsilon-end"),
    (["train", "--variant", "apg_rl", "--pedestrian-model", "psychic", "--out", "T"], "--pedestrian-model"),
    (["train", "--variant", "apg_rl", "--imitation-episodes", "-1", "--out", "T"], "--imitation-episodes"),
    (["train", "--variant", "apg_rl", "--imitation-epochs", "x", "--out", "T"], "--imitation-epochs"),
    (["train", "--variant", "apg_rl", "--imitation-learning-rate", "0", "--out", "T"], "--imitation-learning-rate"),
    (["train", "--variant", "apg_rl", "--seed", "-1", "--out", "T"], "--seed"),
    (["train", "--variant", "apg_rl", "--verbose", "5", "--out", "T"], "--verbose"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/lr.yml", "--timesteps", "0", "--out", "T"], "--timesteps"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/lr.yml", "--checkpoint-freq", "-1", "--out", "T"],
     "--checkpoint-freq"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/lr.yml", "--wall-time", "0", "--out", "T"], "--wall-time"),
    (["train", "--variant", "apg_rl", "--wall-time", "5", "--out", "T"], "--wall-time"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/bad.yml", "--out", "T"], "is not valid YAML"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/hostile.yml", "--out", "T"], "python/object/apply"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/lr.yml", "--out", "T"], "learning rate schedule"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/batch.yml", "--out", "T"], "batch_size"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/unknown.yml", "--out", "T"], "['not_a_key'] is not a hyperparameter"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/no_env.yml", "--out", "T"], "no top-level key 'CrowdNav-v0'"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/policy_kwargs.yml", "--out", "T"], "policy_kwargs"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/normalize.yml", "--out", "T"], "normalize"),
    (["train", "--algo", "ppo", "--hyperparams", "Y/missing.yml", "--out", "T"], "no hyperparameter file"),
    (["train", "--algo", "sac", "--hyperparams", "Y/lr.yml", "--out", "T"], "--algo"),
])
def test_bad_command_arguments(tmp_path, capsys, monkeypatch, argv, fragment):
    monkeypatch.chdir(tmp_path)
    Path("FILE").write_text("a file")
    Path("Y").mkdir()
    for name, text in YAML.items():
        (Path("Y") / f"{name}.yml").write_text(text)
    _refused(capsys, argv, fragment)
    assert not Path("pwned").exists()
    assert not [p for p in tmp_path.rglob("*") if p.is_file() and p.name != "FILE" and p.suffix != ".yml"]


def test_a_model_of_another_env_is_refused(tmp_path, capsys):
    from stable_baselines3 import PPO

    path = tmp_path / "cartpole.zip"
    PPO("MlpPolicy", "CartPole-v1", n_steps=32, batch_size=32).save(path)
    _refused(capsys, ["evaluate", "--policy", str(path), "--episodes", "1"], "the model acts in Discrete(2)")


def test_a_damaged_checkpoint_is_reported_on_resume(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "--variant", "apg_rl", "--out", str(out), "--il-episodes", "2", "--il-epochs", "1",
            "--num-humans", "2", "--checkpoint-episodes", "2", "--eval-episodes", "0"]
    assert main([*argv, "--rl-episodes", "2"]) == 0
    (out / "checkpoint_2.zip").write_bytes(b"PK\x03\x04 truncated")
    capsys.readouterr()
    _refused(capsys, [*argv, "--rl-episodes", "4"], f"cannot resume from {out / 'checkpoint_2.zip'}")


def test_messages_that_say_what_to_do(tmp_path, capsys, monkeypatch):
    """The Python API's wrong-kind-of-thing cases name the fix."""
    import gymnasium as gym
    from stable_baselines3 import PPO

    import sb3_crowdnav
    from sb3_crowdnav.apg_value import APGValue
    from sb3_crowdnav.imitation import collect_demonstrations

    ppo = tmp_path / "ppo.zip"
    PPO("MultiInputPolicy", "CrowdNav-v0", n_steps=32, batch_size=32).save(ppo)
    with pytest.raises(TypeError, match=r"holds a PPO model, not an APGValue one: load it with PPO.load"):
        APGValue.load(ppo)
    with pytest.raises(ValueError, match=r"'MlpPolicy' is not an APGValue policy; use one of \['ApgPolicy'"):
        APGValue("MlpPolicy", "CrowdNav-v0")
    demos = collect_demonstrations(gym.make("CrowdNav-v0", num_humans=2), 2)  # a single env is wrapped
    assert demos.episodes == 2
    with pytest.raises(TypeError, match="env must be a CrowdNav env or a VecEnv"):
        collect_demonstrations(gym.make("CartPole-v1"), 2)
    # a local file named like a shipped model: loaded, and said so; without it, the shipped name is suggested
    monkeypatch.chdir(tmp_path)
    _refused(capsys, ["evaluate", "--policy", "apg_rl", "--episodes", "1"], "the shipped model is --policy pretrained:apg_rl")
    APGValue.load(sb3_crowdnav.models.check_pretrained("apg_rl")).save(tmp_path / "apg_rl")
    assert main(["evaluate", "--policy", "apg_rl", "--episodes", "1"]) == 0
    assert "loads the local file apg_rl.zip; the shipped model is --policy pretrained:apg_rl" in capsys.readouterr().err
