"""examples/warehouse_results.py: the README's warehouse tables come from this script."""

from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "warehouse_results.py"


def test_the_script_writes_every_table(tmp_path):
    spec = importlib.util.spec_from_file_location("warehouse_results", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(["--episodes", "2", "--workers", "1", "--sweep", "2", "--no-gif", "--out", str(tmp_path)])
    summary = (tmp_path / "summary.md").read_text()
    for title in ("Generated layouts, 6 pickers", "apg_warehouse with 2 pickers", "warehouse_layout.yaml"):
        assert title in summary
    generated = (tmp_path / "generated" / "results.md").read_text()
    for row in ("APG_WAREHOUSE", "PPO_WAREHOUSE", "ORCA", "ORCA-constrained"):
        assert f"| {row} |" in generated
    assert "obstacle collision" in generated  # the warehouse columns
    assert (tmp_path / "layout_file" / "results.md").read_text().count("| 2 |") == 4  # 4 policies, 2 episodes each
    assert (tmp_path / "generated" / "trajectories.png").stat().st_size > 0
