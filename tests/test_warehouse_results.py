"""examples/warehouse_results.py: the README's warehouse tables come from this script."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from example_scripts import load_example

ROOT = Path(__file__).resolve().parents[1]


def _script():
    return load_example("warehouse_results")


def _run_folder(path, start, validations):
    """A run folder as ``sb3-crowdnav train`` leaves it: config.json written at ``start``, one validation per row."""
    path.mkdir()
    (path / "config.json").write_text("{}")
    os.utime(path / "config.json", (start, start))
    (path / "eval_curve.jsonl").write_text("".join(json.dumps({"episodes": e, "wall": start + s}) + "\n"
                                                   for e, s in validations))
    return path


@pytest.mark.slow  # a training run or a full CLI run: make slow
def test_the_script_writes_every_table(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "wall_times.json").write_text(json.dumps({"earlier run": "67 min"}))  # a run no longer on this machine
    run = _run_folder(tmp_path / "run", 1_000_000.0, [(500, 600.0), (1000, 1500.0)])
    _script().main(["--episodes", "2", "--workers", "1", "--sweep", "2", "--no-gif", "--out", str(out),
                    "--time-run", f"second run={run}:500"])
    summary = (out / "summary.md").read_text()
    assert "- earlier run: 67 min" in summary and "- second run: 10 min (to the validation of checkpoint 500)" in summary
    assert json.loads((out / "wall_times.json").read_text())["second run"].startswith("10 min")
    titles = ("Today's defaults (", "apg_warehouse with 2 pickers, today's", "social-force pickers",
              "Today's defaults in the layout file warehouse_layout.yaml", "behind a protective field 0.5 m, cap 0.3 m/s",
              "The paper-world models under today's defaults", "As trained (", "apg_warehouse_paper with 2 pickers",
              "As trained, the layout file warehouse_layout.yaml")
    for title in titles:
        assert title in summary
    assert summary.count("| min TTC [s] |") == len(titles)  # every table has its safety figures
    for world in ("today", "protective_field"):  # today's model and the ORCA robot (a PPO row with --policy)
        table = (out / world / "results.md").read_text()
        assert all(f"| {row} |" in table for row in ("APG_WAREHOUSE", "ORCA", "ORCA-constrained"))
    meta = json.loads((out / "today" / "meta.json").read_text())
    assert meta["env_kwargs"] == {} and meta["protective_field"] is None  # today's defaults, no field
    assert json.loads((out / "protective_field" / "meta.json").read_text())["protective_field"]
    layout = json.loads((out / "today_layout_file" / "meta.json").read_text())["env_kwargs"]["layout"]
    assert Path(layout).resolve() == (ROOT / "examples" / "warehouse_layout.yaml").resolve()
    assert not Path(layout).is_absolute()  # run from the repository: its path, not this machine's
    generated = (out / "generated" / "results.md").read_text()
    for row in ("APG_WAREHOUSE_PAPER", "PPO_WAREHOUSE", "ORCA", "ORCA-constrained"):  # the paper-world models
        assert f"| {row} |" in generated
    assert "obstacle collision" in generated  # the warehouse columns
    assert (out / "layout_file" / "results.md").read_text().count("| 2 |") == 4  # 4 policies, 2 episodes each
    assert (out / "generated" / "trajectories.png").stat().st_size > 0


@pytest.mark.parametrize("spec", ["no-equals-sign", "name=", "=folder"])
def test_a_bad_time_run_is_refused_before_any_episode(tmp_path, spec, capsys):
    with pytest.raises(SystemExit) as exc:
        _script().main(["--out", str(tmp_path), "--time-run", spec])
    assert exc.value.code == 2 and "--time-run" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # nothing ran


def test_time_run_refuses_a_folder_that_is_no_run(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        _script().main(["--out", str(tmp_path / "out"), "--time-run", f"x={tmp_path}"])
    assert exc.value.code == 2 and "not a run folder" in capsys.readouterr().err
