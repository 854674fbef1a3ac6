"""A hyperparameter-file run that validates its checkpoints (``train --hyperparams --checkpoint-freq N
--eval-episodes K``): one row per checkpoint on the validation seeds, the best kept as ``best.zip``, and the same
training as without validation."""

from __future__ import annotations

import json
import textwrap

import pytest
import torch

from sb3_crowdnav.cli import main
from sb3_crowdnav.training.hyperparams import train_from_hyperparams
from sb3_crowdnav.training.run_folder import sha256
from sb3_crowdnav.training.zoo_run import checkpoint_file

HP = {"policy": "ApgPolicy", "policy_kwargs": "dict(net_arch=[16])", "buffer_size": 1000, "learning_starts": 16,
      "batch_size": 16, "exploration_fraction": 0.5}
ENV = {"human_policy": "linear", "num_humans": 2}


def _train(out, eval_episodes):
    return train_from_hyperparams("dqn", HP, out, timesteps=96, checkpoint_freq=32, eval_episodes=eval_episodes,
                                  env_overrides=ENV)[0]


def test_every_checkpoint_is_validated_and_the_best_kept(tmp_path):
    out = tmp_path / "run"
    validated = _train(out, eval_episodes=3)
    rows = [json.loads(line) for line in (out / "eval_curve.jsonl").read_text().splitlines()]
    steps = [r["timesteps"] for r in rows]
    assert steps[0] == 0 and steps[-1] == 96 and len(steps) == len(set(steps)) >= 4  # 0, ~32, ~64 and the final model
    assert all(0.0 <= r["success"] <= 1.0 and r["success"] + r["collision"] + r["timeout"] == pytest.approx(1.0)
               for r in rows)
    best = json.loads((out / "best.json").read_text())
    top = max(rows, key=lambda r: (r["success"], -r["time"] if r["time"] == r["time"] else 0.0))
    assert best["timesteps"] == top["timesteps"]  # the first of the best: a later tie does not replace it
    source = out / "dqn.zip" if top["timesteps"] == 96 else checkpoint_file(out, "dqn", top["timesteps"])
    assert best["sha256"] == sha256(out / "best.zip") == sha256(source)

    # validation does not change training: the same weights as a run that never validates
    plain = _train(tmp_path / "plain", eval_episodes=0)
    assert not (tmp_path / "plain" / "best.zip").exists()
    for a, b in zip(validated.policy.parameters(), plain.policy.parameters(), strict=True):
        assert torch.equal(a, b)

    # a rerun of the finished command reuses everything; a resumed one reuses the rows it finds
    before = (out / "eval_curve.jsonl").read_text()
    _train(out, eval_episodes=3)
    assert (out / "eval_curve.jsonl").read_text() == before


def test_validation_needs_checkpoints(tmp_path, capsys):
    with pytest.raises(ValueError, match="give checkpoint_freq > 0 too"):
        train_from_hyperparams("dqn", HP, tmp_path / "r", timesteps=8, eval_episodes=2, env_overrides=ENV)
    yml = tmp_path / "dqn.yml"
    yml.write_text("CrowdNav-v0:\n  policy: ApgPolicy\n")
    with pytest.raises(SystemExit) as exc:
        main(["train", "--algo", "dqn", "--hyperparams", str(yml), "--timesteps", "8", "--eval-episodes", "2",
              "--out", str(tmp_path / "r")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--eval-episodes with --hyperparams validates every checkpoint: give --checkpoint-freq" in err
    assert not (tmp_path / "r").exists()


def test_a_grid_evaluates_the_best_model_of_a_validating_hyperparams_run(tmp_path, capsys):
    from sb3_crowdnav.cli.grid import cells, load_grid

    ppo = (tmp_path / "ppo.yml")
    ppo.write_text("CrowdNav-v0:\n  policy: ApgPolicy\n")
    grid = tmp_path / "grid.yaml"
    text = textwrap.dedent("""\
        seeds: [0]
        methods:
          PPO: {hyperparams: ppo.yml, algo: ppo, model: best, train: {timesteps: 64, eval_episodes: 5}}
          PPO_FINAL: {hyperparams: ppo.yml, algo: ppo, train: {timesteps: 64}}
        """)
    grid.write_text(text)
    best, final = cells(load_grid(grid), tmp_path / "out")
    assert best.model_path.name == "best.zip" and final.model_path.name == "ppo.zip"
    assert "--eval-episodes" in best.train_argv() and "--checkpoint-freq" in best.train_argv()
    grid.write_text(text.replace("train: {timesteps: 64, eval_episodes: 5}", "train: {timesteps: 64}"))
    with pytest.raises(SystemExit) as exc:
        main(["sweep", str(grid), "--out", str(tmp_path / "out"), "--dry-run"])
    assert exc.value.code == 2
    assert "keeps a best model only when it validates its checkpoints" in capsys.readouterr().err
