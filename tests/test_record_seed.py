"""examples/record_seed.py: a seed's evaluations copied into the per-seed records, checked before anything is written."""

import json

import pytest
from example_scripts import load_example

from sb3_crowdnav.evaluation.aggregate import read_seed_score
from sb3_crowdnav.evaluation.budget import TrainingBudget, read_budget

HEADER = "seed,outcome,steps,discounted_return\n"


def _episodes(path, outcomes):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(HEADER + "".join(f"{1_000_000 + i},{o},10,0.5\n" for i, o in enumerate(outcomes)))
    return path


def _generalisation(root, columns):
    """An examples/generalisation.py output of one policy: OUT/cells/COLUMN/POLICY/episodes_LABEL_COLUMN.csv."""
    for column, outcomes in columns.items():
        _episodes(root / "cells" / column / "_runs_s1_best.zip" / f"episodes_best_{column}.csv", outcomes)
    return root


def _run(root, **progress):
    root.mkdir(parents=True)
    (root / "config.json").write_text(json.dumps({"variant": "apg_robust", "seed": 1}))
    (root / "eval_curve.jsonl").write_text('{"episodes": 750, "success": 0.9}\n')
    (root / "progress.json").write_text(json.dumps({"episodes": 3000, "timesteps": 148_030, **progress}))
    return root


def test_columns_of_generalisation_and_benchmark_outputs_are_recorded(tmp_path):
    gen = _generalisation(tmp_path / "gen", {"orca6": ["success", "collision"], "orca10": ["success", "success"]})
    lead = _generalisation(tmp_path / "lead", {"eth": ["collision", "timeout"]})
    bench = tmp_path / "bench"
    _episodes(bench / "episodes_APG_WAREHOUSE.csv", ["success", "success", "collision", "success"])
    into = tmp_path / "seeds"
    load_example("record_seed").main(["apg_robust", "1", "--run", str(_run(tmp_path / "run")), "--eval", str(gen),
                                      "--eval", f"{lead}:_lead_in", "--eval", f"pickers6={bench}",
                                      "--wall-time", "68.2", "--into", str(into)])
    seed = into / "apg_robust" / "seed_1"
    assert sorted(p.name for p in seed.iterdir()) == ["budget.json", "eth_lead_in", "eval_curve.jsonl", "orca10",
                                                       "orca6", "pickers6", "train_config.json"]
    # the budget: the run's RL env steps, and the wall time measured outside the run (the run recorded none)
    assert read_budget(seed / "budget.json", "APG_ROBUST", 1) == TrainingBudget("APG_ROBUST", 1, 148_030, 4092.0)
    assert read_seed_score(seed / "orca6", "APG_ROBUST", "orca6", 1).success == pytest.approx(0.5)
    assert read_seed_score(seed / "orca10", "APG_ROBUST", "orca10", 1).success == pytest.approx(1.0)
    assert read_seed_score(seed / "eth_lead_in", "APG_ROBUST", "eth_lead_in", 1).success == pytest.approx(0.0)
    assert read_seed_score(seed / "pickers6", "APG_ROBUST", "pickers6", 1).success == pytest.approx(0.75)
    assert json.loads((seed / "train_config.json").read_text())["seed"] == 1


def test_a_recorded_column_is_kept_unless_replace(tmp_path, capsys):
    into = tmp_path / "seeds"
    first = _generalisation(tmp_path / "a", {"orca6": ["success"]})
    second = _generalisation(tmp_path / "b", {"orca6": ["collision"]})
    record = load_example("record_seed").main
    record(["m", "0", "--eval", str(first), "--into", str(into)])
    with pytest.raises(SystemExit) as exit_info:
        record(["m", "0", "--eval", str(second), "--into", str(into)])
    assert exit_info.value.code == 2 and "--replace" in capsys.readouterr().err
    assert read_seed_score(into / "m" / "seed_0" / "orca6", "M", "orca6", 0).success == 1.0  # untouched
    record(["m", "0", "--eval", str(second), "--into", str(into), "--replace"])
    assert read_seed_score(into / "m" / "seed_0" / "orca6", "M", "orca6", 0).success == 0.0


def test_a_run_without_validations_is_recorded_without_a_curve(tmp_path):
    """A run that made no validation (a hyperparameter-file run without --eval-episodes) has no eval_curve.jsonl."""
    into = tmp_path / "seeds"
    run = _run(tmp_path / "run", wall_time_s=2400.0)
    (run / "eval_curve.jsonl").unlink()
    load_example("record_seed").main(["m", "0", "--run", str(run), "--into", str(into)])
    assert sorted(p.name for p in (into / "m" / "seed_0").iterdir()) == ["budget.json", "train_config.json"]


def test_a_run_that_recorded_its_wall_time_is_recorded_alone(tmp_path, capsys):
    into = tmp_path / "seeds"
    run = _run(tmp_path / "run", wall_time_s=1727.4)
    load_example("record_seed").main(["m", "2", "--run", str(run), "--into", str(into)])
    assert "1,727.4" not in capsys.readouterr().out
    assert read_budget(into / "m" / "seed_2" / "budget.json", "M", 2) == TrainingBudget("M", 2, 148_030, 1727.4)


@pytest.mark.parametrize("case", ["no_cells", "two_policies", "twice", "two_csvs", "no_run_config", "bad_column",
                                  "nothing", "wall_time_without_run", "wall_time_recorded", "no_progress"])
def test_bad_sources_are_refused_before_anything_is_written(tmp_path, capsys, case):
    into = tmp_path / "seeds"
    gen = _generalisation(tmp_path / "gen", {"orca6": ["success"]})
    evals = ["--eval", str(gen)]
    extra = []
    if case == "no_cells":
        evals += ["--eval", str(tmp_path)]
    elif case == "two_policies":
        _episodes(gen / "cells" / "orca6" / "orca-constrained" / "episodes_ORCA.csv", ["success"])
    elif case == "twice":
        evals += ["--eval", f"orca6={gen / 'cells' / 'orca6' / '_runs_s1_best.zip'}"]
    elif case == "two_csvs":
        bench = tmp_path / "bench"
        _episodes(bench / "episodes_A.csv", ["success"])
        _episodes(bench / "episodes_B.csv", ["success"])
        evals += ["--eval", f"pickers6={bench}"]
    elif case == "no_run_config":
        (tmp_path / "run").mkdir()
        extra = ["--run", str(tmp_path / "run")]
    elif case == "nothing":
        evals = []
    elif case == "wall_time_without_run":
        extra = ["--wall-time", "30"]
    elif case == "wall_time_recorded":  # the run's own clock is not overridden
        extra = ["--run", str(_run(tmp_path / "run", wall_time_s=60.0)), "--wall-time", "30"]
    elif case == "no_progress":
        (_run(tmp_path / "run") / "progress.json").unlink()
        extra = ["--run", str(tmp_path / "run")]
    else:
        evals += ["--eval", f"a/b={gen}"]
    with pytest.raises(SystemExit) as exit_info:
        load_example("record_seed").main(["m", "0", *evals, *extra, "--into", str(into)])
    assert exit_info.value.code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not into.exists()
