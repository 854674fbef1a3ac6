"""The generalisation benchmark: the crowd grammar, ``--crowd`` on every command, ``benchmark --crowd`` (one table
policy x crowd) and ``examples/generalisation.py``."""

from __future__ import annotations

import csv
import json
import math
import shutil
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from example_scripts import load_example
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sb3_crowdnav  # (registers the envs)
from sb3_crowdnav.cli import main
from sb3_crowdnav.evaluation.crowd_spec import CrowdSpec
from sb3_crowdnav.evaluation.metrics import summarize
from sb3_crowdnav.evaluation.policy_spec import PolicySpec
from sb3_crowdnav.evaluation.runner import run_episodes
from sb3_crowdnav.evaluation.tables import CSV_COLUMNS, CrowdTable, crowd_table
from sb3_crowdnav.sim import CROWD_MODELS
from sb3_crowdnav.sim.population import MEASURED_POPULATION


def _script():
    return load_example("generalisation")


def _refused(capsys, argv: list[str], fragment: str, run=main) -> str:
    with pytest.raises(SystemExit) as exc:
        run(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2, err
    assert fragment in err, err
    assert len(err.strip().splitlines()) == 1, err
    return err


# ------------------------------------------------------------------ the grammar
@pytest.mark.parametrize(("text", "model", "settings"), [
    ("orca", "orca", {}),
    (" ORCA ", "orca", {}),
    ("orca:safety_space=0.2", "orca", {"safety_space": 0.2}),
    ("social_force:a=1,b=true,c=null,d=text", "social_force", {"a": 1, "b": True, "c": None, "d": "text"}),
    ("replay:data/eth.txt", "replay", {"path": "data/eth.txt"}),
    ("replay:data/eth.txt,frame_rate=15", "replay", {"path": "data/eth.txt", "frame_rate": 15}),
    ("replay:path=15,frame_rate=2.5", "replay", {"path": "15", "frame_rate": 2.5}),  # a path stays text
])
def test_a_spec_gives_the_envs_crowd_and_its_settings(text, model, settings):
    spec = CrowdSpec.parse(text)
    assert spec.crowd_kwargs == settings
    assert spec.env_kwargs() == {"crowd": model, **({"crowd_kwargs": settings} if settings else {})}
    assert CrowdSpec.parse(str(spec)) == spec
    assert CrowdSpec.parse(spec) is spec


def test_a_replayed_recording_is_labelled_by_its_file_name():
    assert CrowdSpec.parse("replay:/some/where/biwi_eth.txt,frame_rate=15").label == "replay:biwi_eth.txt,frame_rate=15"
    assert CrowdSpec.parse("orca:safety_space=0.2").label == "orca:safety_space=0.2"


@pytest.mark.parametrize("text", ["", "1orca", "or ca", "orca;x", "orca:", "orca:x", "orca:=1", "orca:a=", "orca:a b=1",
                                  "orca:a=1,a=2", "replay:", "replay:a.txt,b", "replay:a.txt,path=b.txt"])
def test_a_bad_spec_is_refused_naming_the_option(text):
    with pytest.raises(ValueError, match="--crowd"):
        CrowdSpec.parse(text, name="--crowd")


def test_a_spec_that_is_no_string_is_a_type_error():
    with pytest.raises(TypeError, match="--crowd"):
        CrowdSpec.parse(3, name="--crowd")


# ------------------------------------------------------------------ the command line
@pytest.mark.parametrize("command", ["evaluate", "benchmark", "render"])
@pytest.mark.parametrize(("args", "fragment"), [
    (["--crowd", "nobody"], "--crowd 'nobody': crowd must be one of"),
    (["--crowd", "orca:x"], "--crowd: expected key=value"),
    (["--crowd", "orca:nope=1"], "unknown setting(s) ['nope']"),
    (["--crowd", "orca:safety_space=9"], "--crowd 'orca:safety_space=9': crowd_kwargs['safety_space']"),
    (["--crowd", "orca", "--human-policy", "linear"], "--crowd and --human-policy"),
    (["--crowd", "orca", "--env-kwargs", "dict(crowd_kwargs={})"], "--crowd and --env-kwargs crowd_kwargs"),
])
def test_a_bad_crowd_exits_2_with_one_line_before_any_work(tmp_path, capsys, command, args, fragment):
    argv = {"evaluate": ["evaluate", "--policy", "orca", "--episodes", "1"],
            "benchmark": ["benchmark", "--policy", "orca", "--episodes", "1", "--out", str(tmp_path / "b")],
            "render": ["render", "--policy", "orca", "--out", str(tmp_path / "r" / "e.gif")]}[command]
    _refused(capsys, [*argv, *args], fragment)
    assert not [p for p in tmp_path.rglob("*") if p.is_file()]


@pytest.mark.parametrize("command", ["evaluate", "render"])
def test_one_crowd_only_where_a_command_runs_in_one(tmp_path, capsys, command):
    argv = ["evaluate", "--episodes", "1"] if command == "evaluate" else ["render", "--out", str(tmp_path / "e.gif")]
    _refused(capsys, [*argv, "--policy", "orca", "--crowd", "orca", "linear"], "benchmark --crowd A B")


@pytest.mark.parametrize("extra", [["--sweep", "3"], ["--figure-seed", "5"], ["--gif"], ["--no-gif"]])
def test_benchmark_refuses_figures_and_sweeps_with_crowds(tmp_path, capsys, extra):
    err = _refused(capsys, ["benchmark", "--policy", "orca", "--crowd", "orca", "--episodes", "1",
                            "--out", str(tmp_path), *extra], "does not go with --crowd")
    assert extra[0] in err


def test_evaluate_in_another_crowd_is_the_runner_in_that_crowd(capsys):
    main(["evaluate", "--policy", "orca", "--crowd", "linear", "--episodes", "3", "--no-progress"])
    printed = capsys.readouterr().out
    expected = summarize(run_episodes("orca", 3, {"crowd": "linear"}))
    assert f"{expected.success_rate:.3f} [{expected.success_ci[0]:.3f}" in printed
    other = summarize(run_episodes("orca", 3))
    assert (other.success_rate, other.navigation_time) != (expected.success_rate, expected.navigation_time)


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def test_benchmark_evaluates_every_policy_in_every_crowd_on_the_same_seeds(tmp_path, capsys):
    out = tmp_path / "bench"
    main(["benchmark", "--policy", "orca", "--policy", "random:0", "--crowd", "orca", "linear", "--episodes", "2",
          "--no-progress", "--out", str(out)])
    printed = capsys.readouterr().out
    assert "| method | orca | linear |" in printed
    rows = _csv(out / "crowds.csv")
    assert [(r["method"], r["crowd"]) for r in rows] == [("ORCA", "orca"), ("ORCA", "linear"),
                                                         ("Random", "orca"), ("Random", "linear")]
    for row in rows:  # each cell is the runner's own summary of that policy in that crowd, on the same seeds
        episodes = _csv(out / f"episodes_{row['method']}_{row['crowd']}.csv")
        assert [int(e["seed"]) for e in episodes] == [1_000_000, 1_000_001]
        spec = "orca" if row["method"] == "ORCA" else "random:0"
        expected = summarize(run_episodes(spec, 2, {"crowd": row["crowd"]}))
        assert float(row["success"]) == pytest.approx(expected.success_rate)
        assert float(row["collision"]) == pytest.approx(expected.collision_rate)
        assert [e["outcome"] for e in episodes] == [r.outcome for r in run_episodes(spec, 2, {"crowd": row["crowd"]})]
    meta = json.loads((out / "meta.json").read_text())
    assert meta["crowds"] == {"orca": "orca", "linear": "linear"}
    assert not (out / "results.md").exists() and not list(out.glob("*.gif"))


def test_the_same_crowd_twice_gets_two_columns(tmp_path, capsys):
    main(["benchmark", "--policy", "orca", "--crowd", "linear", "linear", "--episodes", "1", "--no-progress",
          "--out", str(tmp_path)])
    assert [r["crowd"] for r in _csv(tmp_path / "crowds.csv")] == ["linear", "linear_2"]


# ------------------------------------------------------------------ the table
def _summaries():
    orca = summarize(run_episodes("orca", 3))
    linear = summarize(run_episodes("orca", 3, {"crowd": "linear"}))
    return {("ORCA", "orca"): orca, ("ORCA", "linear"): linear, ("Random", "linear"): linear}


def test_the_crowd_table_has_a_column_per_crowd_and_reads_back(tmp_path):
    table = crowd_table(_summaries())
    assert table.policies == ["ORCA", "Random"] and table.crowds == ["orca", "linear"]
    md = table.to_markdown({"orca": "ORCA, 6 people"})
    assert md.splitlines()[0] == "| method | ORCA, 6 people | linear |"
    assert md.splitlines()[3].split(" | ")[1] == "–"  # Random was not run among ORCA people
    table.save(tmp_path / "crowds")
    again = CrowdTable.read_csv(tmp_path / "crowds.csv")
    assert again.to_markdown() == table.to_markdown()
    for a, b in zip(again.rows, table.rows, strict=True):
        for key in CSV_COLUMNS:
            assert (math.isnan(a[key]) and math.isnan(b[key])) or a[key] == pytest.approx(b[key]), key


def test_a_crowd_table_has_one_row_per_pair():
    row = {"method": "A", "crowd": "orca", **dict.fromkeys(CSV_COLUMNS, 0.0)}
    with pytest.raises(ValueError, match="one row per"):
        CrowdTable([row, dict(row)])
    with pytest.raises(ValueError, match="at least one"):
        CrowdTable([])


# ------------------------------------------------------------------ the measured-speed population
def test_the_measured_population_passes_the_checkers_without_warnings():
    env = gym.make("CrowdNav-v0", **MEASURED_POPULATION)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)
    scene = env.unwrapped.scene
    assert (scene.human_speed, scene.robot_visible) == ("measured", 0.5) and scene.stop_probability > 0


def test_the_measured_population_repeats_its_episodes():
    def episode(seed):
        env = gym.make("CrowdNav-v0", **MEASURED_POPULATION)
        obs, _ = env.reset(seed=seed)
        out = [obs["humans"].copy()]
        for _ in range(30):
            obs, *_ = env.step(40)
            out.append(obs["humans"].copy())
        return np.stack(out)

    np.testing.assert_array_equal(episode(5), episode(5))
    assert not np.array_equal(episode(5), episode(6))


# ------------------------------------------------------------------ the script
def test_the_script_refuses_columns_it_cannot_run_before_any_episode(tmp_path, capsys):
    script = _script()
    missing = [name for name in ("social_force", "replay") if name not in CROWD_MODELS]
    if "social_force" in missing:
        _refused(capsys, ["--out", str(tmp_path / "o")], "'social_force', which is not registered", script.main)
    if "replay" in missing:
        _refused(capsys, ["--columns", "orca6", "--scene", "eth=x.txt", "--out", str(tmp_path / "o")],
                 "'replay', which is not registered", script.main)
    _refused(capsys, ["--columns", "orca6", "--scene", "ETH", "--out", str(tmp_path / "o")], "NAME=PATH", script.main)
    _refused(capsys, ["--columns", "--out", str(tmp_path / "o")], "no column", script.main)
    _refused(capsys, ["--columns", "orca6", "--scene", "empty=a.txt", "--out", str(tmp_path / "o")], "is taken",
             script.main)
    _refused(capsys, ["--columns", "nope", "--out", str(tmp_path / "o")], "--columns", script.main)
    (tmp_path / "doc.md").write_text("no markers\n")
    _refused(capsys, ["--columns", "orca6", "--out", str(tmp_path / "o"), "--markdown-into", str(tmp_path / "doc.md")],
             "generalisation:begin", script.main)
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_a_scene_is_a_replay_column_and_eth_and_hotel_are_held_out():
    script = _script()
    assert script.parse_scene("eth=d/biwi_eth.txt,frame_rate=15") == (
        "eth", "eth (held out)", CrowdSpec("replay", (("path", "d/biwi_eth.txt"), ("frame_rate", 15))))
    assert script.parse_scene("zara1=d/crowds_zara01.txt")[1] == "zara1"


def test_the_script_writes_the_table_the_cells_and_the_docs_block(tmp_path, capsys):
    doc = tmp_path / "results.md"
    doc.write_text("# Results\n\n<!-- generalisation:begin -->\nold\n<!-- generalisation:end -->\n\nafter\n")
    out = tmp_path / "out"
    _script().main(["--episodes", "2", "--workers", "1", "--policy", "orca-constrained", "--policy", "random:0",
                    "--columns", "orca6", "empty", "measured", "--out", str(out), "--markdown-into", str(doc)])
    rows = _csv(out / "generalisation.csv")
    assert [(r["method"], r["crowd"]) for r in rows] == [
        (p, c) for p in ("ORCA-constrained", "Random") for c in ("orca6", "empty", "measured")]
    for key in ("orca6", "empty", "measured"):
        assert (out / "cells" / key / "random_0" / "episodes_Random_orca.csv").is_file()
    empty = next(r for r in rows if (r["method"], r["crowd"]) == ("ORCA-constrained", "empty"))
    assert float(empty["collision"]) == 0.0  # no one to run into
    text = doc.read_text()
    assert "old" not in text and text.endswith("<!-- generalisation:end -->\n\nafter\n")
    assert "| method | ORCA, 6 people | empty floor | measured-speed population |" in text
    assert "| ORCA-constrained |" in (out / "headline.md").read_text()
    assert "Random" not in (out / "headline.md").read_text()
    columns = json.loads((out / "columns.json").read_text())
    assert columns["measured"]["env_kwargs"]["human_speed"] == "measured"

    # an interrupted run resumes: the finished cells are kept, a missing one runs again; never mixed silently
    again = ["--episodes", "2", "--workers", "1", "--policy", "orca-constrained", "--policy", "random:0",
             "--columns", "orca6", "empty", "measured", "--out", str(out)]
    with pytest.raises(SystemExit):
        _script().main(again)
    shutil.rmtree(out / "cells" / "empty" / "random_0")
    capsys.readouterr()
    _script().main([*again, "--resume"])
    printed = capsys.readouterr().out
    assert printed.count("kept ") == 5 and "empty/random_0" not in printed.split("README headline")[0].split("kept")[-1]
    assert _csv(out / "generalisation.csv") == rows
    with pytest.raises(SystemExit, match="holds 2 episodes"):
        _script().main([*again[2:], "--episodes", "3", "--resume"])
    with pytest.raises(SystemExit, match="from seed 1000000, not --episodes 2 from seed 2000000"):
        _script().main([*again, "--resume", "--seeds", "validation"])


def test_validation_seeds_choose_without_the_held_out_scenes_or_the_docs(tmp_path, capsys):
    script = _script()
    (tmp_path / "doc.md").write_text("<!-- generalisation:begin -->\n<!-- generalisation:end -->\n")
    _refused(capsys, ["--seeds", "validation", "--columns", "orca6", "--scene", "eth=x.txt,frame_rate=15",
                      "--out", str(tmp_path / "o")], "held-out scenes (eth)", script.main)
    _refused(capsys, ["--seeds", "validation", "--columns", "orca6", "--out", str(tmp_path / "o"), "--markdown-into",
                      str(tmp_path / "doc.md")], "leave out --markdown-into", script.main)
    out = tmp_path / "v"
    script.main(["--seeds", "validation", "--episodes", "2", "--workers", "1", "--policy", "random:0", "--columns",
                 "orca6", "--out", str(out)])
    meta = json.loads((out / "cells" / "orca6" / "random_0" / "meta.json").read_text())
    assert meta["seeds"] == [2_000_000, 2_000_001]


def test_the_lookahead_options_set_the_value_models_rows_only(tmp_path, capsys):
    script = _script()
    out = tmp_path / "beam"
    base = ["--episodes", "1", "--workers", "1", "--columns", "empty", "--out", str(out)]
    script.main([*base, "--policy", "pretrained:apg_robust", "--policy", "random:0", "--planning-depth", "2",
                 "--planning-width", "8"])
    meta = json.loads((out / "cells" / "empty" / "pretrained_apg_robust" / "meta.json").read_text())
    assert meta["lookahead"] == {"planning_depth": 2, "planning_width": 8}
    assert json.loads((out / "cells" / "empty" / "random_0" / "meta.json").read_text())["lookahead"] is None
    with pytest.raises(SystemExit, match="lookahead settings"):  # resumed with another search: refused, not mixed
        script.main([*base, "--policy", "pretrained:apg_robust", "--planning-depth", "3", "--resume"])
    _refused(capsys, [*base[:-1], str(tmp_path / "o"), "--policy", "random:0", "--planning-depth", "2"],
             "none of the policies given is one", script.main)


def test_a_shipped_models_row_runs_its_own_robot_in_every_column(tmp_path, capsys, monkeypatch):
    script = _script()
    calls = []
    monkeypatch.setattr(script, "benchmark", lambda out, spec, kwargs, policy, *rest: calls.append((policy, kwargs)))
    monkeypatch.setattr(script, "combine", lambda *a: (_ for _ in ()).throw(KeyboardInterrupt))  # stop there
    monkeypatch.setitem(sb3_crowdnav.models.PRETRAINED_ENV, "apg_rl", ("CrowdNav-v0", {"actions": "with_stop"}))
    with pytest.raises(KeyboardInterrupt):
        script.main(["--episodes", "1", "--columns", "orca10", "empty", "--policy", "pretrained:apg_rl", "--policy",
                     "random:0", "--out", str(tmp_path / "o")])
    assert sorted(calls, key=str) == sorted([
        ("pretrained:apg_rl", {"num_humans": 10, "actions": "with_stop"}), ("pretrained:apg_rl", {"num_humans": 0,
        "actions": "with_stop"}), ("random:0", {"num_humans": 10}), ("random:0", {"num_humans": 0})], key=str)
    table = type("Table", (), {"to_markdown": lambda self, titles: ""})()
    block = script.markdown_block(table, script.plan(["empty"], []), 1, {"pretrained:apg_rl": {"actions": "with_stop"},
                                                                         "random:0": {}})
    assert block.count("runs its model's robot") == 1
    assert "the row of `pretrained:apg_rl` runs its model's robot in every column: `actions='with_stop'`" in block
    _refused(capsys, ["--columns", "empty", "--policy", "pretrained:apg_warehouse", "--out", str(tmp_path / "w")],
             "trained in CrowdNavWarehouse-v0", script.main)


def test_a_model_files_row_runs_the_robot_its_file_records(tmp_path, capsys, monkeypatch):
    """--policy FILE: a model trained with the stop runs with it in every column; a paper-robot file adds nothing;
    a file that is no model is refused before any episode."""
    from sb3_crowdnav import APGValue

    script = _script()
    paths = {}
    for actions in ("with_stop", "paper"):
        model = APGValue("ApgPolicy", gym.make("CrowdNav-v0", actions=actions), imitation_episodes=0, seed=0)
        paths[actions] = str(tmp_path / f"{actions}.zip")
        model.save(paths[actions])
    calls = []
    monkeypatch.setattr(script, "benchmark", lambda out, spec, kwargs, policy, *rest: calls.append((policy, kwargs)))
    monkeypatch.setattr(script, "combine", lambda *a: (_ for _ in ()).throw(KeyboardInterrupt))  # stop there
    with pytest.raises(KeyboardInterrupt):
        script.main(["--episodes", "1", "--columns", "empty", "--policy", paths["with_stop"], "--policy",
                     paths["paper"], "--out", str(tmp_path / "o")])
    assert sorted(calls, key=str) == sorted([(paths["with_stop"], {"num_humans": 0, "actions": "with_stop"}),
                                            (paths["paper"], {"num_humans": 0})], key=str)
    junk = tmp_path / "junk.zip"
    junk.write_text("not a zip")
    _refused(capsys, ["--columns", "empty", "--policy", str(junk), "--out", str(tmp_path / "j")],
             "not a model file", script.main)


def test_keep_runs_one_row_again_inside_an_earlier_table(tmp_path, capsys):
    """--keep: the earlier table's other rows stay; the row run again replaces its old one."""
    script = _script()
    first = tmp_path / "first"
    script.main(["--episodes", "2", "--workers", "1", "--policy", "random:0", "--policy", "orca-constrained",
                 "--columns", "orca6", "empty", "--out", str(first)])
    earlier = _csv(first / "generalisation.csv")
    stale = next(r for r in earlier if (r["method"], r["crowd"]) == ("Random", "orca6"))
    stale["success"] = "0.123"  # an old model's number, which the new run must replace
    with (first / "generalisation.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(earlier[0]))
        writer.writeheader()
        writer.writerows(earlier)
    _refused(capsys, ["--episodes", "2", "--workers", "1", "--policy", "random:0", "--columns", "orca6",
                      "--out", str(tmp_path / "o"), "--keep", str(first / "generalisation.csv")],
             "--keep", script.main)
    assert not (tmp_path / "o").exists()
    again = tmp_path / "again"
    script.main(["--episodes", "2", "--workers", "1", "--policy", "random:0", "--columns", "orca6", "empty",
                 "--out", str(again), "--keep", str(first / "generalisation.csv")])
    rows = _csv(again / "generalisation.csv")  # a full run's rows first (the ORCA robot), the others after them
    assert [(r["method"], r["crowd"]) for r in rows] == [
        (p, c) for p in ("ORCA-constrained", "Random") for c in ("orca6", "empty")]
    fresh = next(r for r in rows if (r["method"], r["crowd"]) == ("Random", "orca6"))
    assert fresh["success"] != "0.123"
    assert [r for r in rows if r["method"] == "ORCA-constrained"] == [
        r for r in earlier if r["method"] == "ORCA-constrained"]


def test_the_scenes_pool_by_episodes_with_wilson_intervals():
    from sb3_crowdnav.evaluation.metrics import wilson_interval

    script = _script()
    rows = [{"method": "A", "crowd": crowd, "success": success, "collision": 1 - success, "episodes": n}
            for crowd, success, n in (("orca6", 0.0, 100), ("eth", 0.5, 4), ("univ", 0.75, 12))]
    text = script.pooled_scenes(CrowdTable(rows), ["eth", "univ"], {"eth": "ETH", "univ": "UNIV"})
    low, high = wilson_interval(11, 16)  # 2 of 4 and 9 of 12; the orca6 column is not a scene
    assert f"| A | {11 / 16:.3f} [{low:.3f}, {high:.3f}] / {5 / 16:.3f}" in text and "| 16 |" in text
    assert "ETH + UNIV" in text


def test_kept_rows_take_a_full_runs_order():
    script = _script()
    rows = lambda *methods: CrowdTable([{"method": m, "crowd": "orca6", "success": 1.0, "episodes": 1}  # noqa: E731
                                        for m in methods])
    table = script.merged(rows("APG_RL", "LM_RL", "ORCA-constrained", "X"), rows("APG_ROBUST", "Y"))
    assert table.policies == ["APG_RL", "APG_ROBUST", "LM_RL", "ORCA-constrained", "X", "Y"]


def test_a_resumed_cell_of_another_model_file_of_the_same_name_is_refused(tmp_path, capsys):
    from sb3_crowdnav.models import pretrained_path

    model = tmp_path / "model.zip"
    shutil.copyfile(pretrained_path("apg_rl"), model)
    base = ["--episodes", "1", "--workers", "1", "--columns", "empty", "--policy", str(model), "--out",
            str(tmp_path / "out")]
    _script().main(base)
    meta = json.loads((_script().cell(tmp_path / "out", "empty", str(model)) / "meta.json").read_text())
    assert meta["policy_sha256"] == {"model": PolicySpec("file", str(model)).file_sha256()}
    _script().main([*base, "--resume"])  # the same file: kept
    assert "kept " in capsys.readouterr().out
    shutil.copyfile(pretrained_path("apg_crl"), model)  # another network under the same name: never mixed in
    with pytest.raises(SystemExit, match=r"another file of .*model\.zip"):
        _script().main([*base, "--resume"])


def test_meta_records_each_policys_file_hash_and_none_for_orca(tmp_path):
    main(["evaluate", "--policy", "orca", "--episodes", "1", "--out", str(tmp_path / "o")])
    assert json.loads((tmp_path / "o" / "meta.json").read_text())["policy_sha256"] == {"ORCA": None}
