"""The training budget of each seed in a table over seeds: the RL env steps and the wall time its run used.

A comparison between methods is fair only at equal budgets, so a table over seeds states both for every row
(``sb3-crowdnav aggregate --budget METHOD@SEED=PATH``; ``sb3-crowdnav sweep`` reads its cells' runs itself).
:func:`read_budget` takes

- the folder of a ``sb3-crowdnav train`` run: its ``progress.json`` holds ``timesteps`` and ``wall_time_s`` (the
  wall time over all the run's segments, imitation and validations included); or
- a JSON file: a run's ``progress.json``, or the ``budget.json`` that ``examples/record_seed.py`` keeps beside a
  recorded seed's evaluations (``{"env_steps": N, "wall_time_s": S}``).

The env steps are those of the RL phase (an imitation phase's demonstrations are the ORCA robot's episodes, the same
for every method that imitates). A run that recorded no wall time (APGValue runs before the field existed) gives
``None``; ``examples/record_seed.py --wall-time`` records one measured outside the run (``/usr/bin/time``). A
budget.json written by hand for a seed whose run folder was lost may say ``"env_steps": null`` (the key present): its
steps are not known, and the tables say "–" for them rather than a guess (a run's ``progress.json`` always counts its
steps).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

PROGRESS = "progress.json"


@dataclass(frozen=True)
class TrainingBudget:
    """What one training seed of a method used: RL env steps and wall time [s] (either None: not recorded)."""

    method: str
    seed: int
    env_steps: int | None
    wall_time_s: float | None


def read_budget(path: str | Path, method: str, seed: int) -> TrainingBudget:
    """The budget of the run folder or JSON file ``path`` (see the module docstring) for ``method``'s ``seed``;
    ``FileNotFoundError`` or ``ValueError`` naming the path when it holds none."""
    path = Path(path)
    file = path / PROGRESS if path.is_dir() else path
    if not file.is_file():
        raise FileNotFoundError(f"no training budget at {str(path)!r}: give a run folder (with {PROGRESS}), its "
                                f"{PROGRESS} or a recorded seed's budget.json")
    try:
        data = json.loads(file.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{str(file)!r} is not JSON: {exc}") from None
    steps = data.get("env_steps", data.get("timesteps")) if isinstance(data, dict) else None
    unknown = isinstance(data, dict) and "env_steps" in data and steps is None  # a record that says it is not known
    if not unknown and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 0):
        raise ValueError(f"{str(file)!r} has no env step count ('timesteps' of a run's {PROGRESS}, 'env_steps' of a "
                         f"budget.json), got {steps!r}")
    wall = data.get("wall_time_s")
    if wall is not None and (isinstance(wall, bool) or not isinstance(wall, (int, float)) or not math.isfinite(wall)
                             or wall < 0):
        raise ValueError(f"{str(file)!r}: wall_time_s must be a finite number of seconds >= 0 or null, got {wall!r}")
    return TrainingBudget(method, int(seed), steps, None if wall is None else float(wall))


def check_budgets(budgets: Sequence[TrainingBudget], seeds: set[tuple[str, int]]) -> None:
    """``ValueError`` unless ``budgets`` has exactly one budget per (method, seed) of ``seeds`` (the table's)."""
    given = [(b.method, b.seed) for b in budgets]
    twice = sorted({key for key in given if given.count(key) > 1})
    if twice:
        raise ValueError(f"a budget is given twice for {_pairs(twice)}")
    missing, extra = sorted(seeds - set(given)), sorted(set(given) - seeds)
    if missing:
        raise ValueError(f"no budget for {_pairs(missing)}: give one for every seed of every method, or none")
    if extra:
        raise ValueError(f"a budget for {_pairs(extra)}, which has no results")


def _pairs(pairs: Sequence[tuple[str, int]]) -> str:
    return ", ".join(f"{method} seed {seed}" for method, seed in pairs)


def _steps(n: float) -> str:
    return f"{n / 1e6:.2f} M" if n >= 1e6 else f"{n / 1e3:.0f} k" if n >= 1e4 else f"{n:.0f}"


def _median_and_range(values: Sequence[float | None], fmt, unit: str = "") -> str:
    """The median of ``values`` by ``fmt`` with ``unit``, then their range when they differ; "–" when one is None."""
    if any(v is None for v in values):
        return "–"
    low, high = min(values), max(values)
    return fmt(float(np.median(values))) + unit + (f" ({fmt(low)}–{fmt(high)})" if low != high else "")


def summary(budgets: Sequence[TrainingBudget], method: str) -> tuple[str, str]:
    """``method``'s env steps and wall time over its seeds, as table cells: the median, then the range over the
    seeds when they differ (``"145 k (145-148 k)"``, ``"68.2 min (50.9-68.7)"``); ``"–"`` for either when a seed
    did not record it."""
    own = [b for b in budgets if b.method == method]
    walls = [None if b.wall_time_s is None else b.wall_time_s / 60 for b in own]
    return (_median_and_range([b.env_steps for b in own], _steps),
            _median_and_range(walls, lambda minutes: f"{minutes:.1f}", " min"))


def per_seed_markdown(budgets: Sequence[TrainingBudget]) -> str:
    lines = ["| method | seed | RL env steps | wall time [min] |", "|---|---|---|---|"]
    lines += [f"| {b.method} | {b.seed} | {'–' if b.env_steps is None else f'{b.env_steps:,}'} | "
              f"{'–' if b.wall_time_s is None else f'{b.wall_time_s / 60:.1f}'} |" for b in budgets]
    return "\n".join(lines) + "\n"


__all__ = ["TrainingBudget", "check_budgets", "per_seed_markdown", "read_budget", "summary"]
