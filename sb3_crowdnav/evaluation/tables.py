"""Results tables as Markdown and CSV.

Table 3 layout (one row per policy): the paper's columns first — method, success, collision,
time (s), return — then timeout, gap (m), discomfort, comfort-zone time (s), heading change
(rad), path length (m), the number of episodes, and the mean minimum separation over the steps
in discomfort (< 0.2 m) and inside comfort zones (see :mod:`sb3_crowdnav.evaluation.metrics`).
Table 4 layout (one row per number of pedestrians N) has ``humans`` in place of ``method``. In
Markdown a rate is printed with its Wilson 95 % interval, ``0.990 [0.977, 0.996]``; the CSV has separate ``*_ci_low`` /
``*_ci_high`` columns and full precision. The policy x crowd table (:class:`CrowdTable`, ``benchmark --crowd``) has one
Markdown row per policy and one column per crowd, each cell the success rate with its interval, the collision rate and
the time; its CSV has one row per (policy, crowd) with every column of Table 3.

The safety figures (:data:`SAFETY_COLUMNS`, see :mod:`sb3_crowdnav.evaluation.metrics`) are the last columns of every
CSV; in Markdown they are a second table (:meth:`ResultsTable.to_safety_markdown`, one row per policy: minimum
time-to-collision (s), the share of episodes with one below 1 s, near misses per episode, the speed near people (m/s),
the peak acceleration (m/s²) and turn rate (rad/s) as "mean / max" over the episodes, and with warehouse episodes the
clearance to racks and walls (m) as "mean / min"), which :meth:`ResultsTable.save` writes beside the main one as
``stem_safety.md`` and ``evaluate`` / ``benchmark`` print under it: the main table keeps its width.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sb3_crowdnav.evaluation.metrics import Summary

SAFETY_COLUMNS = ("min_ttc", "short_ttc", "near_misses", "speed_near_people", "peak_acceleration",
                  "peak_acceleration_max", "peak_turn_rate", "peak_turn_rate_max", "min_clearance", "min_clearance_worst")
CSV_COLUMNS = (
    "success", "success_ci_low", "success_ci_high",
    "collision", "collision_ci_low", "collision_ci_high",
    "time", "return",
    "timeout", "timeout_ci_low", "timeout_ci_high",
    "gap", "discomfort", "comfort_time", "heading_change", "path_length", "reward_sum", "episodes",
    "discomfort_gap", "comfort_gap", "sharp_turns",
    "human_collision", "human_collision_ci_low", "human_collision_ci_high",
    "obstacle_collision", "obstacle_collision_ci_low", "obstacle_collision_ci_high", "route_ratio",
    *SAFETY_COLUMNS,
)
MARKDOWN_HEADERS = ("success", "collision", "time (s)", "return", "timeout", "gap (m)", "discomfort",
                    "comfort (s)", "heading (rad)", "path (m)", "episodes", "gap in discomfort (m)",
                    "gap in comfort zones (m)", "sharp turns")
OBSTACLE_HEADERS = ("human collision", "obstacle collision", "path / route")  # tables of warehouse episodes
SAFETY_HEADERS = ("min TTC (s)", "TTC < 1 s", "near misses", "speed near people (m/s)", "peak accel. (m/s²)",
                  "peak turn rate (rad/s)")
CLEARANCE_HEADER = "clearance to racks (m)"  # safety tables of warehouse episodes


def summary_row(summary: Summary) -> dict[str, Any]:
    """The CSV columns of one summary (no label)."""
    s = summary
    return {
        "success": s.success_rate, "success_ci_low": s.success_ci[0], "success_ci_high": s.success_ci[1],
        "collision": s.collision_rate, "collision_ci_low": s.collision_ci[0], "collision_ci_high": s.collision_ci[1],
        "time": s.navigation_time, "return": s.discounted_return,
        "timeout": s.timeout_rate, "timeout_ci_low": s.timeout_ci[0], "timeout_ci_high": s.timeout_ci[1],
        "gap": s.min_separation, "discomfort": s.discomfort_frequency, "comfort_time": s.comfort_zone_time,
        "heading_change": s.heading_change, "path_length": s.path_length, "reward_sum": s.episode_return,
        "episodes": s.episodes,
        "discomfort_gap": s.discomfort_separation, "comfort_gap": s.comfort_zone_separation,
        "sharp_turns": s.sharp_turns,
        "human_collision": s.human_collision_rate, "human_collision_ci_low": s.human_collision_ci[0],
        "human_collision_ci_high": s.human_collision_ci[1],
        "obstacle_collision": s.obstacle_collision_rate, "obstacle_collision_ci_low": s.obstacle_collision_ci[0],
        "obstacle_collision_ci_high": s.obstacle_collision_ci[1], "route_ratio": s.route_ratio,
        "min_ttc": s.min_time_to_collision, "short_ttc": s.short_ttc_rate, "near_misses": s.near_misses,
        "speed_near_people": s.speed_near_people, "peak_acceleration": s.peak_acceleration,
        "peak_acceleration_max": s.peak_acceleration_max, "peak_turn_rate": s.peak_turn_rate,
        "peak_turn_rate_max": s.peak_turn_rate_max, "min_clearance": s.min_clearance,
        "min_clearance_worst": s.min_clearance_worst,
    }


def _num(x: float, digits: int) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def _rate(rate: float, ci: tuple[float, float]) -> str:
    return "-" if math.isnan(rate) else f"{rate:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]"


def _markdown_cells(s: Summary) -> list[str]:
    return [
        _rate(s.success_rate, s.success_ci), _rate(s.collision_rate, s.collision_ci),
        _num(s.navigation_time, 2), _num(s.discounted_return, 4), _rate(s.timeout_rate, s.timeout_ci),
        _num(s.min_separation, 3), _num(s.discomfort_frequency, 3), _num(s.comfort_zone_time, 2),
        _num(s.heading_change, 2), _num(s.path_length, 2), str(s.episodes),
        _num(s.discomfort_separation, 3), _num(s.comfort_zone_separation, 3), _num(s.sharp_turns, 2),
    ]


def _obstacle_cells(s: Summary) -> list[str]:
    return [_rate(s.human_collision_rate, s.human_collision_ci), _rate(s.obstacle_collision_rate, s.obstacle_collision_ci),
            _num(s.route_ratio, 3)]


def _pair(mean: float, extreme: float, digits: int) -> str:
    """``mean / extreme`` (``-`` when there is no mean)."""
    return "-" if math.isnan(mean) else f"{_num(mean, digits)} / {_num(extreme, digits)}"


def _safety_cells(s: Summary, clearance: bool) -> list[str]:
    cells = [_num(s.min_time_to_collision, 2), _num(s.short_ttc_rate, 3), _num(s.near_misses, 2),
             _num(s.speed_near_people, 2), _pair(s.peak_acceleration, s.peak_acceleration_max, 2),
             _pair(s.peak_turn_rate, s.peak_turn_rate_max, 2)]
    return [*cells, _pair(s.min_clearance, s.min_clearance_worst, 3)] if clearance else cells


class ResultsTable:
    """Rows of ``(key, Summary)``; ``key_name`` is ``"method"`` (Table 3) or ``"humans"`` (Table 4)."""

    def __init__(self, summaries: Mapping[Any, Summary], key_name: str = "method") -> None:
        if not summaries:
            raise ValueError("a results table needs at least one summary")
        self.summaries = dict(summaries)
        self.key_name = key_name

    @property
    def rows(self) -> list[dict[str, Any]]:
        """One dict per row, keyed by :data:`CSV_COLUMNS` after ``key_name``."""
        return [{self.key_name: key, **summary_row(s)} for key, s in self.summaries.items()]

    def to_markdown(self) -> str:
        """The Markdown table; with warehouse episodes also the human/obstacle collisions and path/route columns."""
        obstacles = any(s.has_obstacles for s in self.summaries.values())
        headers = (self.key_name, *MARKDOWN_HEADERS, *(OBSTACLE_HEADERS if obstacles else ()))
        lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
        for key, s in self.summaries.items():
            cells = [str(key), *_markdown_cells(s), *(_obstacle_cells(s) if obstacles else ())]
            lines.append("| " + " | ".join(cells) + " |")
        return "\n".join(lines) + "\n"

    def to_safety_markdown(self) -> str:
        """The safety table in Markdown (the module docstring's columns); with warehouse episodes also the clearance."""
        clearance = any(not math.isnan(s.min_clearance) for s in self.summaries.values())
        headers = (self.key_name, *SAFETY_HEADERS, *((CLEARANCE_HEADER,) if clearance else ()))
        lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
        for key, s in self.summaries.items():
            lines.append("| " + " | ".join([str(key), *_safety_cells(s, clearance)]) + " |")
        return "\n".join(lines) + "\n"

    def to_csv(self, path: str | Path | None = None) -> str:
        """The CSV text (every column, the safety figures last); also written to ``path`` when given."""
        return _write_csv(self.rows, [self.key_name, *CSV_COLUMNS], path)

    def save(self, stem: str | Path) -> tuple[Path, Path]:
        """Write ``stem.md``, ``stem.csv`` and the safety table ``stem_safety.md``; return the first two paths."""
        stem = Path(stem)
        stem.parent.mkdir(parents=True, exist_ok=True)
        md, csv_path = stem.with_suffix(".md"), stem.with_suffix(".csv")
        md.write_text(self.to_markdown())
        stem.with_name(stem.name + "_safety.md").write_text(self.to_safety_markdown())
        self.to_csv(csv_path)
        return md, csv_path

    def __str__(self) -> str:
        return self.to_markdown()


def results_table(summaries: Mapping[str, Summary]) -> ResultsTable:
    """Table 3: one row per policy label."""
    return ResultsTable(summaries, "method")


def sweep_table(summaries: Mapping[int, Summary]) -> ResultsTable:
    """Table 4: one row per number of pedestrians."""
    return ResultsTable(dict(sorted(summaries.items())), "humans")


CROWD_CELL = "success [95 % interval] / collision / time (s)"


def _float(text: Any) -> float:
    return math.nan if text in ("", None) else float(text)


class CrowdTable:
    """Policy x crowd: ``summaries[(policy, crowd)]`` as CSV rows, or rows of ``(policy, crowd)`` read back from
    :meth:`to_csv`'s file with :meth:`read_csv`; the order of the policies and of the crowds is their first mention.

    :param rows: one dict per (policy, crowd) pair with ``method``, ``crowd`` and the columns of :data:`CSV_COLUMNS`
    """

    def __init__(self, rows: list[dict[str, Any]]) -> None:
        if not rows:
            raise ValueError("a policy x crowd table needs at least one row")
        pairs = [(row["method"], row["crowd"]) for row in rows]
        if len(set(pairs)) != len(pairs):
            raise ValueError(f"a policy x crowd table has one row per (policy, crowd), got {pairs}")
        self.rows = rows

    @classmethod
    def from_summaries(cls, summaries: Mapping[tuple[str, str], Summary]) -> CrowdTable:
        """The table of ``summaries[(policy, crowd)]``."""
        return cls([{"method": policy, "crowd": crowd, **summary_row(s)} for (policy, crowd), s in summaries.items()])

    @classmethod
    def read_csv(cls, path: str | Path) -> CrowdTable:
        """A table written by :meth:`to_csv` (numbers as floats again, ``episodes`` as an int)."""
        with Path(path).open(newline="") as f:
            # a file written before the safety figures has none of their columns (read as nan)
            rows = [{"method": row["method"], "crowd": row["crowd"],
                     **{k: int(row[k]) if k == "episodes" else _float(row.get(k) if k in SAFETY_COLUMNS else row[k])
                        for k in CSV_COLUMNS}}
                    for row in csv.DictReader(f)]
        return cls(rows)

    @property
    def policies(self) -> list[str]:
        return list(dict.fromkeys(row["method"] for row in self.rows))

    @property
    def crowds(self) -> list[str]:
        return list(dict.fromkeys(row["crowd"] for row in self.rows))

    def to_markdown(self, headers: Mapping[str, str] | None = None) -> str:
        """One row per policy, one column per crowd (titled ``headers[crowd]`` where given); a pair not run is "–".

        Each cell is :data:`CROWD_CELL`, e.g. ``0.992 [0.980, 0.997] / 0.008 / 10.78``.
        """
        headers = dict(headers or {})
        cells = {(row["method"], row["crowd"]): row for row in self.rows}
        crowds = self.crowds
        lines = ["| method | " + " | ".join(headers.get(c, c) for c in crowds) + " |",
                 "|" + "|".join("---" for _ in range(len(crowds) + 1)) + "|"]
        for policy in self.policies:
            row = [_crowd_cell(cells.get((policy, crowd))) for crowd in crowds]
            lines.append(f"| {policy} | " + " | ".join(row) + " |")
        return "\n".join(lines) + f"\n\nEach cell: {CROWD_CELL}.\n"

    def to_csv(self, path: str | Path | None = None) -> str:
        """The CSV text (one row per pair); also written to ``path`` when given."""
        return _write_csv(self.rows, ["method", "crowd", *CSV_COLUMNS], path)

    def save(self, stem: str | Path, headers: Mapping[str, str] | None = None) -> tuple[Path, Path]:
        """Write ``stem.md`` and ``stem.csv``; return both paths."""
        stem = Path(stem)
        stem.parent.mkdir(parents=True, exist_ok=True)
        md, csv_path = stem.with_suffix(".md"), stem.with_suffix(".csv")
        md.write_text(self.to_markdown(headers))
        self.to_csv(csv_path)
        return md, csv_path

    def __str__(self) -> str:
        return self.to_markdown()


def _write_csv(rows: list[dict[str, Any]], columns: list[str], path: str | Path | None) -> str:
    """``rows`` as CSV text with ``columns``; also written to ``path`` when given."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    text = buf.getvalue()
    if path is not None:
        Path(path).write_text(text)
    return text


def _crowd_cell(row: Mapping[str, Any] | None) -> str:
    if row is None:
        return "–"
    success = _rate(row["success"], (row["success_ci_low"], row["success_ci_high"]))
    return f"{success} / {_num(row['collision'], 3)} / {_num(row['time'], 2)}"


def crowd_table(summaries: Mapping[tuple[str, str], Summary]) -> CrowdTable:
    """The policy x crowd table of ``summaries[(policy, crowd)]``."""
    return CrowdTable.from_summaries(summaries)


def write_records_csv(records, path: str | Path) -> Path:
    """One row per episode with the scalar fields of :class:`~sb3_crowdnav.evaluation.runner.EpisodeRecord`."""
    from sb3_crowdnav.evaluation.runner import RECORD_FIELDS

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(RECORD_FIELDS), lineterminator="\n")
        writer.writeheader()
        writer.writerows(r.to_dict() for r in records)
    return path


__all__ = ["CROWD_CELL", "CSV_COLUMNS", "SAFETY_COLUMNS", "CrowdTable", "ResultsTable", "crowd_table", "results_table",
           "summary_row", "sweep_table", "write_records_csv"]
