"""``sb3-crowdnav aggregate``: evaluations of several training seeds per method, aggregated with rliable.

It reads one episodes CSV per method, column and training seed (what ``sb3-crowdnav evaluate --out DIR`` writes as
``DIR/episodes.csv``) and prints per-seed rows, the interquartile mean of success and return per method and column with
stratified bootstrap confidence intervals, and the probability of improvement between methods, all computed with
rliable (install: ``pip install 'sb3_crowdnav[results]'``). Every seed of every method needs the same columns and test
episodes.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any

from sb3_crowdnav.cli.common import UsageError, add_command, check_out, nonneg_int, positive_int

RESULT = re.compile(r"(?P<method>[^/@=]+)(?:/(?P<column>[^/@=]+))?@(?P<seed>\d+)=(?P<path>.+)")
RESULT_GRAMMAR = "METHOD[/COLUMN]@SEED=PATH"
BUDGET = re.compile(r"(?P<method>[^/@=]+)@(?P<seed>\d+)=(?P<path>.+)")
BUDGET_GRAMMAR = "METHOD@SEED=PATH"
DEFAULT_COLUMN = "test"
TABLES = ("full", "wide")


def _confidence(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}")
    return value


def add_parser(sub: Any, parents: list[argparse.ArgumentParser]) -> None:
    """Add ``aggregate`` to the subcommands ``sub``."""
    p = add_command(sub, "aggregate", parents, __doc__,
                    "aggregate evaluations over training seeds with rliable (IQM, intervals)")
    p.add_argument("results", nargs="+", metavar=RESULT_GRAMMAR,
                   help=f"one evaluation: the method, the column (default: {DEFAULT_COLUMN}), the training seed and the "
                        "episodes CSV or the folder holding episodes.csv, e.g. APG_RL@0=runs/apg_rl_0/eval")
    p.add_argument("--reps", type=positive_int, default=2000, help="bootstrap resamples per interval (default: 2000)")
    p.add_argument("--confidence", type=_confidence, default=0.95, help="coverage of the intervals (default: 0.95)")
    p.add_argument("--bootstrap-seed", type=nonneg_int, default=0, help="seed of the bootstrap (default: 0)")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="also write aggregate.md, aggregate.csv, aggregate_per_seed.csv and aggregate_improvement.csv")
    p.add_argument("--markdown-into", type=Path, metavar="FILE",
                   help="replace the block between <!-- NAME:begin --> and <!-- NAME:end --> in FILE with the tables")
    p.add_argument("--block", default="seeds", metavar="NAME", help="the block's NAME (default: seeds)")
    p.add_argument("--table", choices=TABLES, default="full",
                   help="what is printed and written into --markdown-into: 'full' (the default: the aggregates, the "
                        "probabilities of improvement and the per-seed rows, one row per method and column) or 'wide' "
                        "(one row per method, one column per evaluation column: success IQM and interval; the "
                        "README's form). --out writes every table either way")
    p.add_argument("--label", action="append", default=[], metavar="COLUMN=TEXT",
                   help="the header of COLUMN in the wide table, e.g. 'orca10=ORCA, 10 people' (repeatable; a COLUMN "
                        "that no result has is refused)")
    p.add_argument("--budget", action="append", default=[], metavar=BUDGET_GRAMMAR,
                   help="the training budget of a method's seed, stated in every table: a 'sb3-crowdnav train' run "
                        "folder (its progress.json: RL env steps and wall time), that progress.json, or a recorded "
                        "seed's budget.json (examples/record_seed.py); repeat for every seed of every method, or give "
                        "none")
    p.set_defaults(func=cmd_aggregate)


def parse_result(text: str) -> tuple[str, str, int, Path]:
    """``METHOD[/COLUMN]@SEED=PATH`` -> (method, column, seed, path)."""
    match = RESULT.fullmatch(text.strip())
    if match is None:
        raise UsageError(f"expected {RESULT_GRAMMAR}, e.g. APG_RL@0=runs/apg_rl_0/eval, got {text!r}")
    return (match["method"].strip(), (match["column"] or DEFAULT_COLUMN).strip(), int(match["seed"]),
            Path(match["path"].strip()))


def parse_budget(text: str) -> tuple[str, int, Path]:
    """``METHOD@SEED=PATH`` -> (method, seed, path)."""
    match = BUDGET.fullmatch(text.strip())
    if match is None:
        raise UsageError(f"--budget: expected {BUDGET_GRAMMAR}, e.g. APG_RL@0=runs/apg_rl_0, got {text!r}")
    return match["method"].strip(), int(match["seed"]), Path(match["path"].strip())


def parse_labels(texts: list[str], columns: set[str], table: str) -> dict[str, str]:
    """``--label COLUMN=TEXT`` -> {column: text}; refused unless the table is wide and every COLUMN is a result's."""
    from sb3_crowdnav.evaluation.aggregate import ALL_COLUMNS

    if texts and table != "wide":
        raise UsageError("--label: names the columns of the wide table; pass --table wide")
    labels = {}
    for text in texts:
        column, sep, label = text.partition("=")
        if not sep or not column.strip() or not label.strip() or "|" in label:
            raise UsageError(f"--label: expected COLUMN=TEXT (no '|' in TEXT), e.g. 'orca10=ORCA, 10 people', got {text!r}")
        if column.strip() not in columns | {ALL_COLUMNS}:
            raise UsageError(f"--label: no result has the column {column.strip()!r}; the columns are "
                             f"{', '.join(sorted(columns))} and {ALL_COLUMNS}")
        labels[column.strip()] = label.strip()
    return labels


def cmd_aggregate(args: argparse.Namespace) -> int:
    from sb3_crowdnav.evaluation.aggregate import aggregate, check_block, read_seed_score, write_block
    from sb3_crowdnav.evaluation.budget import read_budget

    parsed = [parse_result(text) for text in args.results]
    budget_sources = [parse_budget(text) for text in args.budget]
    labels = parse_labels(args.label, {column for _, column, _, _ in parsed}, args.table)
    if args.out is not None:
        check_out(args.out)
    if args.markdown_into is not None:
        try:
            check_block(args.markdown_into, args.block)
        except ValueError as exc:
            raise UsageError(f"--markdown-into: {exc}") from None
    try:
        scores = [read_seed_score(path, method, column, seed) for method, column, seed, path in parsed]
        budgets = [read_budget(path, method, seed) for method, seed, path in budget_sources]
        result = aggregate(scores, reps=args.reps, confidence=args.confidence, random_seed=args.bootstrap_seed,
                           budgets=budgets)
    except (FileNotFoundError, ValueError, ImportError) as exc:
        raise UsageError(str(exc)) from None
    text = result.to_markdown() if args.table == "full" else result.wide_markdown_block(labels)
    print(text, end="")
    if args.out is not None:
        written = result.save(args.out / "aggregate")
        print(f"\nwrote {', '.join(p.name for p in written)} in {args.out}")
    if args.markdown_into is not None:
        write_block(args.markdown_into, args.block, text)
        print(f"wrote the tables into {args.markdown_into}")
    return 0
