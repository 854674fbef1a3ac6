"""Results over training seeds, aggregated with the ``rliable`` library (Agarwal et al., NeurIPS 2021).

Each training seed of a method, evaluated in a column (a crowd, a number of people, ...), gives one
:class:`SeedScore`: its success rate and mean discounted return over the column's test episodes (read from the
episodes CSV that ``sb3-crowdnav evaluate --out`` writes). Scores are arranged as rliable expects them, one matrix
(seeds, columns) per method, and :func:`aggregate` computes with rliable:

- the interquartile mean (``rliable.metrics.aggregate_iqm``: the mean of the middle 50 % of the seeds' scores; with
  fewer than 4 seeds nothing is trimmed and it is the mean) per column and, with several columns, over all of them;
- its stratified bootstrap confidence interval (``rliable.library.get_interval_estimates``: the seeds are resampled
  within each column, percentile method);
- the probability of improvement of each method over each later one (``rliable.metrics.probability_of_improvement``:
  P(a seed of X scores a higher success than a seed of Y), ties counting one half, averaged over the columns) with its
  interval (``get_interval_estimates`` resampling each method's seeds independently within each column).

The bootstrap costs about 0.5 ms per resample of an IQM and 4 ms per resample and column of a probability of
improvement on one core: ``reps`` (2,000 by default) sets the time.

The input is checked first (:func:`check_scores`): one score per (method, column, seed); every seed of a method has the
same columns; in a column every seed of every method played the same test episodes. An interval needs two seeds:
a method with one seed gets its IQM and no interval, and no probability of improvement. rliable's bootstrap draws from
NumPy's global generator: :func:`aggregate` seeds it for the call and gives the caller's state back, so a table is the
same on every run.

With the seeds' training budgets (:mod:`sb3_crowdnav.evaluation.budget`: RL env steps and wall time, one per method
and seed), every table states them: the wide table in two columns (median over the seeds, and their range), the full
one per seed.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sb3_crowdnav.evaluation import budget as budgets_
from sb3_crowdnav.evaluation.budget import TrainingBudget

ALL_COLUMNS = "all"  # the column name of the rows over every column
INSTALL_HINT = "aggregating over seeds needs rliable: pip install 'sb3_crowdnav[results]'"


@dataclass(frozen=True)
class SeedScore:
    """One training seed of a method in one column.

    :param success: the share of the test episodes that reached the goal, in [0, 1]
    :param discounted_return: the mean discounted return over them (nan: not recorded)
    :param episode_seeds: the test episodes' seeds, in order (compared across seeds and methods)
    """

    method: str
    column: str
    seed: int
    success: float
    discounted_return: float
    episode_seeds: tuple[int, ...]

    @property
    def episodes(self) -> int:
        return len(self.episode_seeds)


def read_seed_score(path: str | Path, method: str, column: str, seed: int) -> SeedScore:
    """The score of an episodes CSV (``evaluate --out DIR`` writes ``DIR/episodes.csv``; ``path`` may be the file or
    ``DIR``) for ``method``'s training ``seed`` in ``column``."""
    path = Path(path)
    if path.is_dir():
        path = path / "episodes.csv"
    if not path.is_file():
        raise FileNotFoundError(f"no episodes CSV at {str(path)!r} (sb3-crowdnav evaluate --out DIR writes DIR/episodes.csv)")
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows or not {"seed", "outcome"} <= set(rows[0]):
        raise ValueError(f"{str(path)!r} has no episodes with 'seed' and 'outcome' columns")
    returns = [float(row["discounted_return"]) for row in rows] if "discounted_return" in rows[0] else [math.nan]
    return SeedScore(method, column, int(seed), float(np.mean([row["outcome"] == "success" for row in rows])),
                     float(np.mean(returns)), tuple(int(row["seed"]) for row in rows))


def check_scores(scores: Sequence[SeedScore]) -> None:
    """``ValueError`` naming what does not fit: an empty input, a (method, column, seed) given twice, a seed whose
    columns differ from its method's other seeds' or from another method's, or a column whose seeds played other
    test episodes (another number, other seeds)."""
    if not scores:
        raise ValueError("no results to aggregate")
    seen: set[tuple[str, str, int]] = set()
    for s in scores:
        if (s.method, s.column, s.seed) in seen:
            raise ValueError(f"{s.method}, column {s.column!r}, seed {s.seed} is given twice")
        seen.add((s.method, s.column, s.seed))
    columns: dict[tuple[str, int], set[str]] = {}
    for s in scores:
        columns.setdefault((s.method, s.seed), set()).add(s.column)
    (first_method, first_seed), expected = next(iter(columns.items()))
    for (method, seed), found in columns.items():
        if found != expected:
            raise ValueError(f"{method} seed {seed} has columns {sorted(found)} but {first_method} seed {first_seed} "
                             f"has {sorted(expected)}: every seed of every method needs the same columns")
    reference: dict[str, SeedScore] = {}
    for s in scores:
        ref = reference.setdefault(s.column, s)
        if s.episode_seeds != ref.episode_seeds:
            raise ValueError(f"column {s.column!r}: {s.method} seed {s.seed} played {s.episodes} episodes "
                             f"{_seed_range(s)} but {ref.method} seed {ref.seed} played {ref.episodes} {_seed_range(ref)}; "
                             "every seed of every method needs the same test episodes")
    if any(math.isnan(s.discounted_return) for s in scores) and not all(math.isnan(s.discounted_return) for s in scores):
        raise ValueError("some results have a discounted_return column and others not: give all or none")


def _seed_range(s: SeedScore) -> str:
    return f"(seeds {s.episode_seeds[0]}-{s.episode_seeds[-1]})"


def score_matrix(scores: Iterable[SeedScore], method: str, columns: Sequence[str], metric: str = "success") -> np.ndarray:
    """rliable's layout of ``method``'s scores: (seeds, columns), seeds ascending."""
    by_key = {(s.seed, s.column): getattr(s, metric) for s in scores if s.method == method}
    seeds = sorted({seed for seed, _ in by_key})
    return np.array([[by_key[(seed, column)] for column in columns] for seed in seeds], dtype=float)


def _rliable() -> tuple[Any, Any]:
    """rliable's ``library`` and ``metrics`` modules (an install hint when rliable is missing)."""
    try:
        from rliable import library, metrics
    except ImportError as exc:
        raise ImportError(INSTALL_HINT) from exc
    return library, metrics


def interval_estimates(matrices: dict[str, Any], func: Any, reps: int, confidence: float,
                       random_seed: int) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """rliable's ``get_interval_estimates`` of ``func`` for each matrix (or pair of matrices): point estimates and
    stratified bootstrap intervals; ``ValueError`` when a matrix has fewer than 2 seeds (rows)."""
    library, _ = _rliable()
    for key, value in matrices.items():
        for matrix in value if isinstance(value, (list, tuple)) else (value,):
            if matrix.shape[0] < 2:
                raise ValueError(f"{key}: a confidence interval needs at least 2 seeds, got {matrix.shape[0]}")
    state = np.random.get_state()
    np.random.seed(random_seed)  # rliable resamples with NumPy's global generator: seeded here, given back below
    try:
        points, intervals = library.get_interval_estimates(matrices, lambda *m: np.array([func(*m)]), reps=reps,
                                                           confidence_interval_size=confidence)
    finally:
        np.random.set_state(state)
    return ({key: float(np.ravel(v)[0]) for key, v in points.items()},
            {key: (float(np.ravel(v)[0]), float(np.ravel(v)[1])) for key, v in intervals.items()})


@dataclass(frozen=True)
class AggregateRow:
    """A method in a column (or over all columns): its seeds' IQM of success and of return with intervals (None: one
    seed)."""

    method: str
    column: str
    seeds: int
    episodes: int
    success_iqm: float
    success_ci: tuple[float, float] | None
    return_iqm: float
    return_ci: tuple[float, float] | None


@dataclass(frozen=True)
class Improvement:
    """P(X > Y): the probability that a seed of ``method`` scores a higher success than a seed of ``other``."""

    method: str
    other: str
    column: str
    probability: float
    ci: tuple[float, float]

    @property
    def resolved(self) -> bool:
        """The interval excludes 0.5: one method is better at this confidence."""
        return self.ci[0] > 0.5 or self.ci[1] < 0.5


@dataclass(frozen=True)
class Aggregates:
    """Per-seed scores, aggregated rows and probabilities of improvement (and the seeds' training budgets, when
    given), with Markdown and CSV writers."""

    scores: tuple[SeedScore, ...]
    rows: tuple[AggregateRow, ...]
    improvements: tuple[Improvement, ...]
    reps: int
    confidence: float
    budgets: tuple[TrainingBudget, ...] = ()

    def per_seed_markdown(self) -> str:
        lines = ["| method | column | seed | episodes | success | return |", "|---|---|---|---|---|---|"]
        lines += [f"| {s.method} | {s.column} | {s.seed} | {s.episodes} | {s.success:.3f} | {_num(s.discounted_return)} |"
                  for s in self.scores]
        return "\n".join(lines) + "\n"

    def aggregate_markdown(self) -> str:
        percent = f"{self.confidence * 100:g} %"
        lines = [f"| method | column | seeds | episodes per seed | success IQM [{percent} CI] | return IQM [{percent} CI] |",
                 "|---|---|---|---|---|---|"]
        lines += [f"| {r.method} | {r.column} | {r.seeds} | {r.episodes} | {_estimate(r.success_iqm, r.success_ci, 3)} | "
                  f"{_estimate(r.return_iqm, r.return_ci, 4)} |" for r in self.rows]
        return "\n".join(lines) + "\n"

    def wide_markdown(self, labels: dict[str, str] | None = None) -> str:
        """One row per method, one column per evaluation column (and ``all``): the success IQM with its interval, the
        number of seeds beside the method (the README's form), and with budgets the RL env steps and wall time
        (median over the seeds, and their range). ``labels`` renames columns in the header."""
        labels = labels or {}
        columns = list(dict.fromkeys(r.column for r in self.rows))
        percent = f"{self.confidence * 100:g} %"
        extra = ["RL env steps", "wall time"] if self.budgets else []
        lines = [f"| method (success IQM [{percent} CI]) | seeds | "
                 + " | ".join([labels.get(c, c) for c in columns] + extra) + " |",
                 "|---" * (len(columns) + 2 + len(extra)) + "|"]
        for method in dict.fromkeys(r.method for r in self.rows):
            rows = {r.column: r for r in self.rows if r.method == method}
            seeds = sorted({r.seeds for r in rows.values()})
            cells = [("–" if c not in rows else _estimate(rows[c].success_iqm, rows[c].success_ci, 3)
                      if rows[c].success_ci is not None else _num(rows[c].success_iqm, 3)) for c in columns]
            cells += list(budgets_.summary(self.budgets, method)) if self.budgets else []
            lines.append(f"| {method} | {'/'.join(map(str, seeds))} | " + " | ".join(cells) + " |")
        return "\n".join(lines) + "\n"

    def wide_markdown_block(self, labels: dict[str, str] | None = None) -> str:
        """The wide table with a line that says how it was computed (``--table wide``)."""
        pooled = any(r.column == ALL_COLUMNS for r in self.rows)
        note = f"; '{(labels or {}).get(ALL_COLUMNS, ALL_COLUMNS)}' pools the columns" if pooled else ""
        budget = ("; the training budget of the seeds (RL env steps; wall time, imitation and validations included): "
                  "median (range)") if self.budgets else ""
        return (f"Success: interquartile mean (IQM) over training seeds with stratified bootstrap "
                f"{self.confidence * 100:g} % confidence intervals ({self.reps} resamples), computed with rliable"
                f"{note}{budget}.\n\n{self.wide_markdown(labels)}")

    def improvement_markdown(self) -> str:
        percent = f"{self.confidence * 100:g} %"
        lines = [f"| X | Y | column | P(X > Y) [{percent} CI] | interval excludes 0.5 |", "|---|---|---|---|---|"]
        lines += [f"| {i.method} | {i.other} | {i.column} | {_estimate(i.probability, i.ci, 2)} | "
                  f"{'yes' if i.resolved else 'no'} |" for i in self.improvements]
        return "\n".join(lines) + "\n"

    def to_markdown(self) -> str:
        """The three tables with a line that says how they were computed (the block for ``--markdown-into``)."""
        single = sorted({r.method for r in self.rows if r.success_ci is None})
        note = f" {', '.join(single)}: one seed, so no interval and no probability of improvement." if single else ""
        parts = [f"Interquartile mean (IQM) over training seeds with stratified bootstrap {self.confidence * 100:g} % "
                 f"confidence intervals ({self.reps} resamples), computed with rliable; success and return are each "
                 f"seed's mean over its test episodes.{note}", "", self.aggregate_markdown()]
        if self.improvements:
            parts += ["Probability of improvement: P(a seed of X has a higher success than a seed of Y), ties counting "
                      "one half, averaged over the columns.", "", self.improvement_markdown()]
        parts += ["Per seed:", "", self.per_seed_markdown()]
        if self.budgets:
            parts += ["Training budgets (RL env steps; wall time of the run, imitation and validations included):", "",
                      budgets_.per_seed_markdown(self.budgets)]
        return "\n".join(parts)

    def to_csv(self) -> dict[str, str]:
        """CSV texts: ``per_seed``, ``aggregate`` and ``improvement`` (and ``budget`` with budgets)."""
        per_seed = [{"method": s.method, "column": s.column, "seed": s.seed, "episodes": s.episodes,
                     "success": s.success, "return": s.discounted_return} for s in self.scores]
        rows = [{"method": r.method, "column": r.column, "seeds": r.seeds, "episodes": r.episodes,
                 **_csv_estimate("success_iqm", r.success_iqm, r.success_ci),
                 **_csv_estimate("return_iqm", r.return_iqm, r.return_ci)} for r in self.rows]
        improvements = [{"method": i.method, "other": i.other, "column": i.column,
                         **_csv_estimate("probability", i.probability, i.ci), "resolved": i.resolved}
                        for i in self.improvements]
        budget = [{"method": b.method, "seed": b.seed, "env_steps": b.env_steps,
                   "wall_time_s": math.nan if b.wall_time_s is None else b.wall_time_s} for b in self.budgets]
        return {"per_seed": _csv(per_seed, ["method", "column", "seed", "episodes", "success", "return"]),
                **({"budget": _csv(budget, ["method", "seed", "env_steps", "wall_time_s"])} if budget else {}),
                "aggregate": _csv(rows, ["method", "column", "seeds", "episodes", "success_iqm", "success_iqm_ci_low",
                                         "success_iqm_ci_high", "return_iqm", "return_iqm_ci_low", "return_iqm_ci_high"]),
                "improvement": _csv(improvements, ["method", "other", "column", "probability", "probability_ci_low",
                                                   "probability_ci_high", "resolved"])}

    def save(self, stem: str | Path) -> list[Path]:
        """Write ``stem.md`` and ``stem_per_seed.csv``, ``stem.csv``, ``stem_improvement.csv`` (and
        ``stem_budget.csv`` with budgets); return the paths."""
        stem = Path(stem)
        stem.parent.mkdir(parents=True, exist_ok=True)
        texts = self.to_csv()
        paths = {stem.with_suffix(".md"): self.to_markdown(), stem.with_name(f"{stem.name}_per_seed.csv"): texts["per_seed"],
                 stem.with_suffix(".csv"): texts["aggregate"],
                 stem.with_name(f"{stem.name}_improvement.csv"): texts["improvement"]}
        if "budget" in texts:
            paths[stem.with_name(f"{stem.name}_budget.csv")] = texts["budget"]
        for path, text in paths.items():
            path.write_text(text)
        return list(paths)


def _num(x: float, digits: int = 4) -> str:
    return "-" if math.isnan(x) else f"{x:.{digits}f}"


def _estimate(point: float, ci: tuple[float, float] | None, digits: int) -> str:
    if math.isnan(point):
        return "-"
    if ci is None:
        return f"{point:.{digits}f} (1 seed)"
    return f"{point:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def _csv_estimate(name: str, point: float, ci: tuple[float, float] | None) -> dict[str, float]:
    low, high = ci if ci is not None else (math.nan, math.nan)
    return {name: point, f"{name}_ci_low": low, f"{name}_ci_high": high}


def _csv(rows: list[dict[str, Any]], columns: list[str]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def aggregate(scores: Sequence[SeedScore], reps: int = 2000, confidence: float = 0.95, random_seed: int = 0,
              budgets: Sequence[TrainingBudget] = ()) -> Aggregates:
    """Check ``scores`` (:func:`check_scores`) and aggregate them with rliable (see the module docstring).

    :param budgets: none, or one training budget per (method, seed) of ``scores``
        (:func:`~sb3_crowdnav.evaluation.budget.check_budgets`), which the tables then state
    :param reps: bootstrap resamples per interval
    :param confidence: the intervals' coverage, in (0, 1)
    :param random_seed: the bootstrap's seed (the same tables on every run)
    """
    from sb3_crowdnav.sim.validation import check_int, check_range

    check_int("reps", reps, 1)
    check_range("confidence", confidence, 0.0, 1.0, low_open=True, high_open=True)
    check_int("random_seed", random_seed, 0)
    check_scores(scores)
    if budgets:
        budgets_.check_budgets(budgets, {(s.method, s.seed) for s in scores})
    _, metrics = _rliable()
    methods = list(dict.fromkeys(s.method for s in scores))
    columns = list(dict.fromkeys(s.column for s in scores))
    tasks = [[column] for column in columns] + ([columns] if len(columns) > 1 else [])
    has_return = not math.isnan(scores[0].discounted_return)
    episodes = {s.column: s.episodes for s in scores}
    rows = []
    for method in methods:
        for task in tasks:
            success = score_matrix(scores, method, task)
            returns = score_matrix(scores, method, task, "discounted_return")
            row = {"success": (float(metrics.aggregate_iqm(success)), None),
                   "return": (float(metrics.aggregate_iqm(returns)) if has_return else math.nan, None)}
            if success.shape[0] >= 2:
                for name, matrix in (("success", success), ("return", returns))[:1 + has_return]:
                    points, cis = interval_estimates({method: matrix}, metrics.aggregate_iqm, reps, confidence, random_seed)
                    row[name] = (points[method], cis[method])
            rows.append(AggregateRow(method, task[0] if len(task) == 1 else ALL_COLUMNS, success.shape[0],
                                     episodes[task[0]] if len(task) == 1 else sum(episodes[c] for c in task),
                                     *row["success"], *row["return"]))
    improvements = []
    several = [m for m in methods if score_matrix(scores, m, columns[:1]).shape[0] >= 2]
    for i, method in enumerate(several):  # over all columns at once: rliable's average over tasks
        for other in several[i + 1:]:
            pair = [score_matrix(scores, method, columns), score_matrix(scores, other, columns)]
            points, cis = interval_estimates({"pair": pair}, metrics.probability_of_improvement, reps, confidence,
                                             random_seed)
            improvements.append(Improvement(method, other, columns[0] if len(columns) == 1 else ALL_COLUMNS,
                                            points["pair"], cis["pair"]))
    ordered = sorted(scores, key=lambda s: (methods.index(s.method), columns.index(s.column), s.seed))
    order = {(s.method, s.seed): i for i, s in enumerate(ordered)}
    return Aggregates(tuple(ordered), tuple(rows), tuple(improvements), reps, confidence,
                      tuple(sorted(budgets, key=lambda b: order[(b.method, b.seed)])))


def _split_block(path: Path, name: str) -> tuple[str, str, str, str]:
    begin, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    content = path.read_text() if path.is_file() else ""
    head, found, rest = content.partition(begin)
    if not found or end not in rest:
        raise ValueError(f"{str(path)!r} has no block between {begin} and {end} to replace")
    return head, begin, end, rest.partition(end)[2]


def check_block(path: str | Path, name: str) -> None:
    """``ValueError`` unless ``path`` has the block :func:`write_block` replaces (checked before any work)."""
    _split_block(Path(path), name)


def write_block(path: str | Path, name: str, text: str) -> None:
    """Replace the text between ``<!-- name:begin -->`` and ``<!-- name:end -->`` in ``path`` with ``text``;
    ``ValueError`` when the file has no such block."""
    head, begin, end, tail = _split_block(Path(path), name)
    Path(path).write_text(f"{head}{begin}\n{text}{end}{tail}")


__all__ = ["ALL_COLUMNS", "AggregateRow", "Aggregates", "Improvement", "SeedScore", "aggregate", "check_block", "check_scores",
           "interval_estimates", "read_seed_score", "score_matrix", "write_block"]
