"""Aggregates over training seeds with rliable: values computed here independently, refusals, the CLI."""

import json
import math
import signal
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rliable", reason="the results extra: pip install 'sb3_crowdnav[results]'")

from sb3_crowdnav.cli import main
from sb3_crowdnav.evaluation import budget
from sb3_crowdnav.evaluation.aggregate import SeedScore, aggregate, interval_estimates, read_seed_score
from sb3_crowdnav.evaluation.budget import TrainingBudget, read_budget

EPISODES = tuple(range(1_000_000, 1_000_010))
REPS = 200


def _scores(method, successes, column="test", returns=None, episodes=EPISODES):
    returns = returns if returns is not None else [0.1 * s for s in successes]
    pairs = enumerate(zip(successes, returns, strict=True))
    return [SeedScore(method, column, seed, s, r, episodes) for seed, (s, r) in pairs]


def _row(result, method, column):
    return next(r for r in result.rows if r.method == method and r.column == column)


def test_iqm_is_the_mean_of_the_middle_half():
    values = [0.9, 0.1, 0.6, 0.5, 0.7, 0.2, 1.0, 0.3]  # 8 seeds: the 2 lowest and the 2 highest are cut
    middle = sorted(values)[2:6]
    result = aggregate(_scores("A", values), reps=REPS)
    row = _row(result, "A", "test")
    assert row.success_iqm == pytest.approx(np.mean(middle))
    assert row.seeds == 8 and row.episodes == len(EPISODES)
    assert min(values) <= row.success_ci[0] <= row.success_iqm <= row.success_ci[1] <= max(values)


def test_iqm_of_three_seeds_is_their_mean_and_over_columns_pools_them():
    scores = _scores("A", [0.2, 0.5, 0.8], "a") + _scores("A", [0.4, 0.4, 0.4], "b")
    result = aggregate(scores, reps=REPS)
    assert _row(result, "A", "a").success_iqm == pytest.approx(0.5)
    pooled = sorted([0.2, 0.5, 0.8, 0.4, 0.4, 0.4])[1:5]  # 6 scores: one cut at each end
    assert _row(result, "A", "all").success_iqm == pytest.approx(np.mean(pooled))
    assert _row(result, "A", "b").success_ci == pytest.approx((0.4, 0.4))  # every resample is the same


def test_probability_of_improvement():
    scores = _scores("A", [0.9, 0.95, 0.92]) + _scores("B", [0.5, 0.6, 0.55]) + _scores("C", [0.5, 0.6, 0.55])
    result = aggregate(scores, reps=REPS)
    pairs = {(i.method, i.other): i for i in result.improvements}
    assert pairs["A", "B"].probability == 1.0 and pairs["A", "B"].ci == (1.0, 1.0) and pairs["A", "B"].resolved
    assert pairs["B", "C"].probability == 0.5 and not pairs["B", "C"].resolved  # the same scores
    assert set(pairs) == {("A", "B"), ("A", "C"), ("B", "C")}
    # P(X > Y) counted by hand: two of X's seeds beat every seed of Y, the third ties them (one half)
    mixed = aggregate(_scores("X", [0.6, 0.6, 0.55]) + _scores("Y", [0.55, 0.55, 0.55]), reps=REPS).improvements[0]
    assert mixed.probability == pytest.approx((1 + 1 + 0.5) / 3)


def test_a_method_with_one_seed_has_no_interval():
    result = aggregate(_scores("A", [0.9, 0.8]) + _scores("MaskablePPO", [0.7]), reps=REPS)
    assert _row(result, "MaskablePPO", "test").success_ci is None
    assert _row(result, "MaskablePPO", "test").success_iqm == pytest.approx(0.7)
    assert result.improvements == ()
    text = result.to_markdown()
    assert "0.700 (1 seed)" in text and "MaskablePPO: one seed" in text
    with pytest.raises(ValueError, match="at least 2 seeds, got 1"):
        interval_estimates({"m": np.ones((1, 1))}, np.mean, REPS, 0.95, 0)


def test_the_same_tables_every_time_and_the_callers_generator_untouched():
    scores = _scores("A", [0.2, 0.9, 0.5, 0.7]) + _scores("B", [0.3, 0.4, 0.8, 0.1])
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    first = aggregate(scores, reps=REPS)
    assert np.array_equal(np.random.get_state()[1], before)
    assert aggregate(scores, reps=REPS) == first
    assert aggregate(scores, reps=REPS, random_seed=1).rows != first.rows


@pytest.mark.parametrize("scores, fragment", [
    ([], "no results"),
    (_scores("A", [0.5, 0.6]) + _scores("A", [0.5]), "given twice"),
    (_scores("A", [0.5, 0.6], "a") + _scores("A", [0.5], "b"), "same columns"),
    (_scores("A", [0.5, 0.6], "a") + _scores("B", [0.5, 0.6], "b"), "same columns"),
    (_scores("A", [0.5, 0.6]) + _scores("B", [0.5, 0.6], episodes=EPISODES[:5]), "same test episodes"),
    (_scores("A", [0.5, 0.6]) + _scores("B", [0.5, 0.6], returns=[math.nan, math.nan]), "all or none"),
])
def test_inconsistent_input_is_refused(scores, fragment):
    with pytest.raises(ValueError, match=fragment):
        aggregate(scores, reps=REPS)


def _episodes_csv(path, outcomes, first_seed=1_000_000):
    lines = ["seed,outcome,discounted_return"]
    lines += [f"{first_seed + i},{o},{0.3 if o == 'success' else 0.0}" for i, o in enumerate(outcomes)]
    path.mkdir(parents=True, exist_ok=True)
    (path / "episodes.csv").write_text("\n".join(lines) + "\n")
    return path


def test_read_seed_score(tmp_path):
    folder = _episodes_csv(tmp_path / "e", ["success", "collision", "success", "timeout"])
    score = read_seed_score(folder, "A", "test", 3)
    assert (score.success, score.discounted_return, score.episodes, score.seed) == (0.5, pytest.approx(0.15), 4, 3)
    assert read_seed_score(folder / "episodes.csv", "A", "test", 3) == score


def test_cli_tables_and_markdown_block(tmp_path, capsys):
    results = []
    for method, wins in (("A", [4, 3, 4]), ("B", [1, 0, 1])):
        for seed, k in enumerate(wins):
            folder = _episodes_csv(tmp_path / method / str(seed), ["success"] * k + ["collision"] * (4 - k))
            results.append(f"{method}@{seed}={folder}")
    doc = tmp_path / "results.md"
    doc.write_text("# Results\n<!-- seeds:begin -->\nold\n<!-- seeds:end -->\nafter\n")
    assert main(["aggregate", *results, "--reps", str(REPS), "--out", str(tmp_path / "out"),
                 "--markdown-into", str(doc)]) == 0
    out = capsys.readouterr().out
    assert "| A | test | 3 | 4 | 0.917 [0.750, 1.000] |" in out  # 3 seeds: the mean of 1, 0.75, 1
    assert "| A | B | test | 1.00 [1.00, 1.00] | yes |" in out
    text = doc.read_text()
    assert "old" not in text and text.endswith("<!-- seeds:end -->\nafter\n") and "| B | test | 0 | 4 | 0.250 |" in text
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "aggregate.csv", "aggregate.md", "aggregate_improvement.csv", "aggregate_per_seed.csv"]


@pytest.mark.parametrize("argv, fragment", [
    (["A0=x"], "METHOD[/COLUMN]@SEED=PATH"),
    (["A@0=missing"], "no episodes CSV"),
    (["A@0={a}", "A@1={b}"], "same test episodes"),
    (["A@0={a}", "--markdown-into", "{doc}"], "no block between <!-- seeds:begin -->"),
])
def test_cli_refusals(tmp_path, capsys, argv, fragment):
    a = _episodes_csv(tmp_path / "a", ["success"] * 3)
    b = _episodes_csv(tmp_path / "b", ["success"] * 2)
    (tmp_path / "doc.md").write_text("no block\n")
    argv = [x.format(a=a, b=b, doc=tmp_path / "doc.md") for x in argv]
    with pytest.raises(SystemExit) as exc:
        main(["aggregate", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert fragment in err and len(err.strip().splitlines()) == 1


def test_cli_wide_table_one_row_per_method(tmp_path, capsys):
    results = []
    for method, wins in (("A", {"x": [4, 3], "y": [2, 2]}), ("B", {"x": [1, 1], "y": [0, 0]})):
        for column, per_seed in wins.items():
            for seed, k in enumerate(per_seed):
                folder = _episodes_csv(tmp_path / method / column / str(seed), ["success"] * k + ["collision"] * (4 - k))
                results.append(f"{method}/{column}@{seed}={folder}")
    doc = tmp_path / "README.md"
    doc.write_text("<!-- readme:begin -->\nold\n<!-- readme:end -->\n")
    assert main(["aggregate", *results, "--reps", str(REPS), "--table", "wide", "--label", "x=crowd X",
                 "--markdown-into", str(doc), "--block", "readme"]) == 0
    out = capsys.readouterr().out
    assert "| method (success IQM [95 % CI]) | seeds | crowd X | y | all |" in out
    assert "| A | 2 | 0.875 [0.750, 1.000] | 0.500 [0.500, 0.500] |" in out  # seeds 1.0 and 0.75; 0.5 and 0.5
    assert "| B | 2 | 0.250 [0.250, 0.250] | 0.000 [0.000, 0.000] |" in out
    assert "Per seed" not in out and "P(X > Y)" not in out and "'all' pools the columns" in out
    assert "| A | 2 | 0.875" in doc.read_text() and "old" not in doc.read_text()


@pytest.mark.parametrize("argv, fragment", [
    (["--label", "x=X"], "pass --table wide"),
    (["--table", "wide", "--label", "z=Z"], "no result has the column 'z'"),
    (["--table", "wide", "--label", "x"], "expected COLUMN=TEXT"),
    (["--table", "wide", "--label", "x=a|b"], "expected COLUMN=TEXT"),
])
def test_cli_label_refusals(tmp_path, capsys, argv, fragment):
    a = _episodes_csv(tmp_path / "a", ["success"] * 3)
    with pytest.raises(SystemExit) as exc:
        main(["aggregate", f"A/x@0={a}", *argv])
    assert exc.value.code == 2
    assert fragment in capsys.readouterr().err


def _budget(path, **data):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))
    return path


def test_budgets_read_from_runs_and_records_and_stated_per_method(tmp_path):
    run = tmp_path / "run"  # a train run folder: its progress.json
    _budget(run / "progress.json", timesteps=511_757, wall_time_s=1727.4, finished=True)
    assert read_budget(run, "A", 0) == TrainingBudget("A", 0, 511_757, 1727.4)
    recorded = _budget(tmp_path / "budget.json", env_steps=520_000, wall_time_s=None)  # no wall time recorded
    assert read_budget(recorded, "A", 1) == TrainingBudget("A", 1, 520_000, None)
    budgets = [TrainingBudget("A", 0, 145_464, 3054.0), TrainingBudget("A", 1, 148_030, 4092.0),
               TrainingBudget("A", 2, 144_764, 4123.0), TrainingBudget("B", 0, 2_000_000, None),
               TrainingBudget("B", 1, 2_000_000, 60.0)]
    assert budget.summary(budgets, "A") == ("145 k (145 k–148 k)", "68.2 min (50.9–68.7)")  # medians and ranges
    assert budget.summary(budgets, "B") == ("2.00 M", "–")  # a seed without a wall time: none stated
    scores = _scores("A", [0.9, 0.8, 0.7]) + _scores("B", [0.5, 0.6])
    result = aggregate(scores, reps=REPS, budgets=budgets[::-1])
    assert [(b.method, b.seed) for b in result.budgets] == [("A", 0), ("A", 1), ("A", 2), ("B", 0), ("B", 1)]
    wide = result.wide_markdown()
    assert wide.splitlines()[0].endswith("| test | RL env steps | wall time |")
    assert "| A | 3 | 0.800 [0.700, 0.900] | 145 k (145 k–148 k) | 68.2 min (50.9–68.7) |" in wide
    assert "| B | 0 | 2,000,000 | – |" in result.to_markdown() and "| A | 1 | 148,030 | 68.2 |" in result.to_markdown()
    assert result.to_csv()["budget"].splitlines()[1] == "A,0,145464,3054.0"
    assert "RL env steps" not in aggregate(scores, reps=REPS).wide_markdown()  # no budgets, no columns


def test_a_record_without_env_steps_states_none(tmp_path):
    """A hand-written budget.json of a lost run folder may say its steps are unknown (the key present, null): the
    tables say "–" for that method's steps, never a number made up from the other seeds."""
    lost = _budget(tmp_path / "budget.json", env_steps=None, wall_time_s=1932.0)
    assert read_budget(lost, "A", 0) == TrainingBudget("A", 0, None, 1932.0)
    budgets = [read_budget(lost, "A", 0), TrainingBudget("A", 1, 143_161, 2415.9), TrainingBudget("B", 0, 1000, 60.0)]
    assert budget.summary(budgets, "A") == ("–", "36.2 min (32.2–40.3)")
    assert budget.summary(budgets, "B") == ("1000", "1.0 min")
    result = aggregate(_scores("A", [0.9, 0.8]) + _scores("B", [0.5]), reps=REPS, budgets=budgets)
    assert "| A | 0 | – | 32.2 |" in result.to_markdown() and "| A | 1 | 143,161 | 40.3 |" in result.to_markdown()
    assert result.to_csv()["budget"].splitlines()[1] == "A,0,,1932.0"
    with pytest.raises(ValueError, match="no env step count"):  # a run's progress.json always counts its steps
        read_budget(_budget(tmp_path / "run" / "progress.json", timesteps=None, wall_time_s=1.0), "A", 0)


@pytest.mark.parametrize("budgets, fragment", [
    ([("A", 0), ("A", 1)], "no budget for A seed 2"),
    ([("A", 0), ("A", 1), ("A", 2), ("B", 0)], "a budget for B seed 0, which has no results"),
    ([("A", 0), ("A", 0), ("A", 1), ("A", 2)], "a budget is given twice for A seed 0"),
])
def test_budgets_must_match_the_seeds(budgets, fragment):
    with pytest.raises(ValueError, match=fragment):
        aggregate(_scores("A", [0.9, 0.8, 0.7]), reps=REPS,
                  budgets=[TrainingBudget(m, s, 1000, 1.0) for m, s in budgets])


@pytest.mark.parametrize("data, fragment", [
    ({"wall_time_s": 3.0}, "no env step count"),
    ({"timesteps": -1}, "no env step count"),
    ({"timesteps": 10, "wall_time_s": float("nan")}, "wall_time_s must be a finite number"),
    ({"timesteps": 10, "wall_time_s": "1 h"}, "wall_time_s must be a finite number"),
])
def test_a_file_without_a_budget_is_refused(tmp_path, data, fragment):
    with pytest.raises(ValueError, match=fragment):
        read_budget(_budget(tmp_path / "progress.json", **data), "A", 0)
    with pytest.raises(FileNotFoundError, match="no training budget"):
        read_budget(tmp_path / "elsewhere", "A", 0)


def test_cli_budgets(tmp_path, capsys):
    results, budgets = [], []
    for seed, k in enumerate([4, 3]):
        results.append(f"A@{seed}={_episodes_csv(tmp_path / 'e' / str(seed), ['success'] * k + ['collision'] * (4 - k))}")
        run = tmp_path / "runs" / str(seed)
        _budget(run / "progress.json", timesteps=1000 * (seed + 1), wall_time_s=60.0 * (seed + 1))
        budgets += ["--budget", f"A@{seed}={run}"]
    assert main(["aggregate", *results, *budgets, "--reps", str(REPS), "--table", "wide", "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "| A | 2 | 0.875 [0.750, 1.000] | 1500 (1000–2000) | 1.5 min (1.0–2.0) |" in out
    assert "the training budget of the seeds (RL env steps; wall time, imitation and validations included)" in out
    assert (tmp_path / "o" / "aggregate_budget.csv").read_text().splitlines() == [
        "method,seed,env_steps,wall_time_s", "A,0,1000,60.0", "A,1,2000,120.0"]
    for argv, fragment in ((["--budget", "A0=x"], "--budget: expected METHOD@SEED=PATH"),
                           (budgets[:2], "no budget for A seed 1"),
                           ([*budgets, "--budget", f"A@1={tmp_path}"], "no training budget at")):
        with pytest.raises(SystemExit) as exc:
            main(["aggregate", *results, *argv, "--reps", str(REPS)])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert fragment in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.slow  # a subprocess of the command line (fault injection: make slow)
def test_a_closed_stdout_ends_the_command_quietly(tmp_path):
    """As `sb3-crowdnav aggregate ... | head`: the reader goes away before the command writes; no error line."""
    a = _episodes_csv(tmp_path / "a", ["success"] * 3)
    proc = subprocess.Popen([sys.executable, "-m", "sb3_crowdnav.cli", "aggregate", f"A@0={a}", "--reps", "10"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 128 + signal.SIGPIPE and err == b"", err
