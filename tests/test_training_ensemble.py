"""``sb3-crowdnav train --ensemble K``: member runs from one imitation, assembled into one value ensemble."""

from __future__ import annotations

import json

import pytest
import torch as th

from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.cli import main
from sb3_crowdnav.training.schedule import ScheduleConfig

TINY = ["--il-episodes", "2", "--il-epochs", "1", "--num-humans", "2", "--checkpoint-episodes", "2",
        "--eval-episodes", "2", "--rl-episodes", "4"]


def test_an_ensemble_needs_at_least_one_member(tmp_path, capsys):
    with pytest.raises(ValueError, match="ensemble"):
        ScheduleConfig(ensemble=0)
    with pytest.raises(ValueError, match="ensemble_checkpoints"):
        ScheduleConfig(ensemble_checkpoints=0)
    with pytest.raises(ValueError, match="ensemble_checkpoints must be at most the run's validations"):
        ScheduleConfig(ensemble_checkpoints=3, rl_episodes=4, checkpoint_episodes=2)  # two validations
    with pytest.raises(ValueError, match="ensemble_checkpoints must be at most the run's validations"):
        ScheduleConfig(ensemble_checkpoints=2, rl_episodes=4, checkpoint_episodes=2, eval_episodes=0)  # none
    assert ScheduleConfig(ensemble_checkpoints=2, rl_episodes=4, checkpoint_episodes=2).ensemble_checkpoints == 2
    for flags in (["--ensemble-checkpoints", "3", "--rl-episodes", "4", "--checkpoint-episodes", "2"],):
        with pytest.raises(SystemExit) as exit_info:
            main(["train", "--variant", "apg_rl", "--out", str(tmp_path / "run"), *flags])
        assert exit_info.value.code == 2
        assert "ensemble_checkpoints" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--variant", "apg_rl", "--out", str(tmp_path / "run"), "--ensemble", "0"])
    assert exit_info.value.code == 2
    assert "--ensemble" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


@pytest.mark.slow  # three short training runs: make slow
def test_members_share_one_imitation_and_become_one_value_ensemble(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "--variant", "apg_rl", "--out", str(out), "--seed", "3", "--ensemble", "2", *TINY]) == 0
    members = [out / "member_0", out / "member_1"]
    assert (members[0] / "imitation.zip").exists() and not (members[1] / "imitation.zip").exists()
    record = json.loads((out / "ensemble.json").read_text())
    assert [m["seed"] for m in record["members"]] == [3, 1003]
    ensemble = APGValue.load(out / "best.zip")
    assert ensemble.policy_kwargs["ensemble_size"] == 2 and len(ensemble.policy.value_net.members) == 2
    assert [len(m["checkpoints"]) for m in record["members"]] == [1, 1]
    loaded = [APGValue.load(m / record["members"][k]["checkpoints"][0]["model"]) for k, m in enumerate(members)]
    assert [model.seed for model in loaded] == [3, 1003]  # each member's ε draws are its own
    for slot, member in zip(ensemble.policy.value_net.members, loaded, strict=True):  # each member's network, as saved
        for a, b in zip(slot.state_dict().values(), member.policy.value_net.state_dict().values(), strict=True):
            assert th.equal(a, b)
    first, second = (dict(m.policy.value_net.state_dict()) for m in loaded)
    assert any(not th.equal(first[k], second[k]) for k in first)  # two runs, not one network twice
    progress = json.loads((out / "progress.json").read_text())
    runs = [json.loads((m / "progress.json").read_text()) for m in members]
    assert progress["finished"] and progress["members"] == 2
    assert progress["timesteps"] == sum(r["timesteps"] for r in runs) > 0
    assert progress["episodes"] == sum(r["episodes"] for r in runs) == 8
    assert progress["wall_time_s"] >= sum(r["wall_time_s"] for r in runs)
    assert 0.0 <= record["validation"]["success"] <= 1.0
    digest = record["sha256"]
    capsys.readouterr()
    assert main(["train", "--variant", "apg_rl", "--out", str(out), "--seed", "3", "--ensemble", "2", *TINY]) == 0
    assert "nothing to do" in capsys.readouterr().out
    assert json.loads((out / "ensemble.json").read_text())["sha256"] == digest


@pytest.mark.slow  # two short training runs: make slow
def test_a_given_post_imitation_model_starts_every_member(tmp_path):
    first = tmp_path / "first"
    assert main(["train", "--variant", "apg_rl", "--out", str(first), *TINY[:6], "--rl-episodes", "2",
                 "--eval-episodes", "0"]) == 0
    out = tmp_path / "run"
    assert main(["train", "--variant", "apg_rl", "--out", str(out), "--ensemble", "2", "--from-imitation",
                 str(first / "imitation.zip"), *TINY[4:6], "--rl-episodes", "2", "--checkpoint-episodes", "2",
                 "--eval-episodes", "0"]) == 0
    for member in ("member_0", "member_1"):
        assert not (out / member / "imitation.zip").exists()  # neither imitated: both started from the given model
        assert json.loads((out / member / "progress.json").read_text())["episodes"] == 2
    record = json.loads((out / "ensemble.json").read_text())
    assert [[c["model"] for c in m["checkpoints"]] for m in record["members"]] == [["final.zip"], ["final.zip"]]
    assert record["validation"] is None


@pytest.mark.slow  # a short training run: make slow
def test_one_run_gives_its_best_validated_checkpoints(tmp_path):
    out = tmp_path / "run"
    assert main(["train", "--variant", "apg_rl", "--out", str(out), "--ensemble-checkpoints", "2", *TINY[:-2],
                 "--rl-episodes", "6"]) == 0
    rows = [json.loads(line) for line in (out / "member_0" / "eval_curve.jsonl").read_text().splitlines()]
    assert [r["episodes"] for r in rows] == [2, 4, 6]
    time = [r["time"] if r["time"] == r["time"] else 0.0 for r in rows]  # (NaN without a success: not ranked by it)
    ranked = [rows[i] for i in sorted(range(3), key=lambda i: (rows[i]["success"], -time[i], i), reverse=True)]
    record = json.loads((out / "ensemble.json").read_text())
    assert [c["model"] for c in record["members"][0]["checkpoints"]] == \
        [f"checkpoint_{r['episodes']}.zip" for r in ranked[:2]]
    assert APGValue.load(out / "best.zip").policy_kwargs["ensemble_size"] == 2
    assert (out / "final.zip").read_bytes() == (out / "member_0" / "final.zip").read_bytes()
