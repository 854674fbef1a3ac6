"""examples/reproduce.py: the Table 5 layout puts the paper's gap beside the three readings of ours."""

from __future__ import annotations

import runpy
from dataclasses import replace
from pathlib import Path

from sb3_crowdnav.evaluation import EpisodeRecord, summarize

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "reproduce.py"


def _record(seed: int, sep: float, in_danger: float, in_zone: float, sharp: int = 0) -> EpisodeRecord:
    rec = EpisodeRecord(seed=seed, outcome="success", steps=40, navigation_time=10.0, path_length=9.0,
                        episode_return=1.0, discounted_return=0.35, min_separation=sep, discomfort_frequency=0.1,
                        comfort_zone_time=1.0, heading_change=3.0, num_humans=6)
    return replace(rec, discomfort_separation=in_danger, comfort_zone_separation=in_zone, sharp_turns=sharp)


def test_table5_columns():
    table5 = runpy.run_path(str(SCRIPT))["table5"]
    summaries = {"APG_CRL": summarize([_record(0, 0.05, 0.11, 0.41, 1), _record(1, 0.15, 0.13, 0.47, 4)])}
    lines = table5(summaries).splitlines()
    assert len(lines) == 3 and lines[0].count("|") == lines[2].count("|")
    cells = [c.strip() for c in lines[2].strip("|").split("|")]
    # episode minimum, mean in discomfort, mean in comfort zones, then the paper's 0.64 m
    assert cells[0] == "APG_CRL" and cells[3:7] == ["0.10", "0.12", "0.44", "0.64"]
    assert cells[-1] == "2.50"  # sharp turns per episode
