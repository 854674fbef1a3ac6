"""Keep one training seed's evaluations in the repository: ``paper_results/seeds/METHOD/seed_S/COLUMN/episodes.csv``.

    python examples/record_seed.py apg_robust 1 --run runs/robust_s1 \\
        --eval runs/robust_s1/gen --eval runs/robust_s1/gen_lead:_lead_in
    python examples/record_seed.py apg_warehouse 1 --run runs/apg_warehouse_1 \\
        --eval pickers6=runs/wh1_6 --eval social_force=runs/wh1_sf

The model files stay with their runs; the episodes of their test evaluations (500 each, seeds 1,000,000 + i) are what
``sb3-crowdnav aggregate METHOD/COLUMN@SEED=paper_results/seeds/METHOD/seed_S/COLUMN`` reads, so that seeds trained on
different days and machines aggregate together (docs: training, "Sweeps and seeds").

``--eval`` takes either

* ``DIR[:SUFFIX]``, the ``--out`` of ``examples/generalisation.py`` run with one ``--policy``: each of its columns
  (``DIR/cells/COLUMN/POLICY/``) becomes ``COLUMN`` + ``SUFFIX`` (e.g. ``eth_lead_in`` for the scenes replayed with
  ``lead_in=1``); or
* ``COLUMN=DIR``, the ``--out`` of ``sb3-crowdnav evaluate`` or of ``sb3-crowdnav benchmark`` with one ``--policy``.

``--run`` copies the run's ``config.json`` (as ``train_config.json``) and its ``eval_curve.jsonl`` (the validations,
when it made any) beside them, and writes ``budget.json``: the RL env steps and the wall time the run used, from its
``progress.json`` (``sb3-crowdnav aggregate --budget METHOD@S=paper_results/seeds/METHOD/seed_S/budget.json`` states
them). A run that recorded no wall time (APGValue runs before it was recorded) takes it from ``--wall-time MIN``,
measured outside the run (``/usr/bin/time``); without it ``budget.json`` says ``null``. ``--run`` alone records just
these files. Every source is checked before anything is written, and a column recorded already is refused unless
``--replace`` is given.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
from pathlib import Path

from sb3_crowdnav.cli.common import Parser, UsageError, nonneg_int, positive_float

NAME = re.compile(r"[A-Za-z0-9_.-]+")


def episodes_in(folder: Path) -> Path:
    """The one episodes CSV of an evaluation folder (``episodes.csv``, or a benchmark's ``episodes_LABEL.csv``)."""
    if (folder / "episodes.csv").is_file():
        return folder / "episodes.csv"
    found = sorted(folder.glob("episodes_*.csv"))
    if len(found) != 1:
        raise UsageError(f"--eval: {str(folder)!r} holds {len(found)} episodes CSVs; give the folder of an evaluation "
                         "of one policy")
    return found[0]


def sources(text: str) -> dict[str, Path]:
    """``--eval`` -> {column: episodes CSV}."""
    column, equals, rest = text.partition("=")
    if equals:
        if not NAME.fullmatch(column):
            raise UsageError(f"--eval: the column {column!r} must be letters, digits, '_', '.' or '-'")
        folder = Path(rest)
        if not folder.is_dir():
            raise UsageError(f"--eval: no folder {rest!r}")
        return {column: episodes_in(folder)}
    path, _, suffix = text.rpartition(":") if ":" in text else (text, "", "")
    folder = Path(path)
    if suffix and not NAME.fullmatch(suffix):
        raise UsageError(f"--eval: the suffix {suffix!r} must be letters, digits, '_', '.' or '-'")
    if not (folder / "cells").is_dir():
        raise UsageError(f"--eval: {str(folder)!r} is no examples/generalisation.py output (no cells/); for one "
                         "evaluation write COLUMN=DIR")
    found = {}
    for cell in sorted(p for p in (folder / "cells").iterdir() if p.is_dir()):
        policies = [p for p in cell.iterdir() if p.is_dir()]
        if len(policies) != 1:
            raise UsageError(f"--eval: the column {cell.name!r} of {str(folder)!r} has {len(policies)} policies; "
                             "record the output of a run with one --policy")
        found[cell.name + suffix] = episodes_in(policies[0])
    if not found:
        raise UsageError(f"--eval: {str(folder)!r} has no columns")
    return found


def run_budget(run: Path, wall_time: float | None) -> dict:
    """The budget of the run folder ``run``: its RL env steps and wall time [s] (``wall_time`` [min] when the run
    recorded none; refused when it did)."""
    from sb3_crowdnav.evaluation.budget import read_budget

    try:
        found = read_budget(run, "run", 0)
    except (FileNotFoundError, ValueError) as exc:
        raise UsageError(f"--run: {exc}") from None
    if wall_time is not None and found.wall_time_s is not None:
        raise UsageError(f"--wall-time: the run recorded its wall time ({found.wall_time_s / 60:.1f} min); leave it out")
    seconds = found.wall_time_s if wall_time is None else round(60 * wall_time, 1)
    return {"env_steps": found.env_steps, "wall_time_s": seconds,
            "source": "progress.json" if wall_time is None else "progress.json, wall time from --wall-time"}


def main(argv: list[str] | None = None) -> None:
    p = Parser(prog="record_seed.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("method", help="the method's folder name, e.g. apg_robust")
    p.add_argument("seed", type=nonneg_int, help="the training seed")
    p.add_argument("--eval", action="append", default=[], metavar="DIR[:SUFFIX] | COLUMN=DIR",
                   help="evaluations to keep (repeat)")
    p.add_argument("--run", type=Path, metavar="DIR",
                   help="the training run: its config.json and eval_curve.jsonl, and its budget (budget.json)")
    p.add_argument("--wall-time", type=positive_float, metavar="MIN",
                   help="the run's wall time [min] when its progress.json has none (e.g. from /usr/bin/time)")
    p.add_argument("--into", type=Path, default=Path("paper_results/seeds"), help="default: paper_results/seeds")
    p.add_argument("--replace", action="store_true", help="replace columns recorded already")
    args = p.parse_args(argv)
    try:  # everything checked before anything is written
        if not args.eval and args.run is None:
            raise UsageError("nothing to record: give --eval, --run or both")
        if args.wall_time is not None and args.run is None:
            raise UsageError("--wall-time: is the wall time of the --run; give --run")
        if not NAME.fullmatch(args.method):
            raise UsageError(f"method {args.method!r} must be letters, digits, '_', '.' or '-'")
        columns: dict[str, Path] = {}
        for text in args.eval:
            for column, csv in sources(text).items():
                if column in columns:
                    raise UsageError(f"--eval: the column {column!r} is given twice")
                columns[column] = csv
        extras = {}
        if args.run is not None:
            extras = {"train_config.json": args.run / "config.json"}
            if not extras["train_config.json"].is_file():
                raise UsageError(f"--run: no config.json in {str(args.run)!r}")
            if (args.run / "eval_curve.jsonl").is_file():  # (a run without validations has none)
                extras["eval_curve.jsonl"] = args.run / "eval_curve.jsonl"
            json.loads(extras["train_config.json"].read_text())  # (a run's config, not any file of that name)
            budget = run_budget(args.run, args.wall_time)
        target = args.into / args.method / f"seed_{args.seed}"
        taken = [column for column in columns if (target / column / "episodes.csv").exists()]
        if taken and not args.replace:
            raise UsageError(f"{str(target)!r} has {', '.join(taken)} already; give --replace to replace them")
    except (UsageError, ValueError) as exc:
        p.error(str(exc))
    for column, csv in columns.items():
        (target / column).mkdir(parents=True, exist_ok=True)
        shutil.copyfile(csv, target / column / "episodes.csv")
        print(f"{target / column / 'episodes.csv'} <- {csv}")
    target.mkdir(parents=True, exist_ok=True)
    for name, path in extras.items():
        shutil.copyfile(path, target / name)
        print(f"{target / name} <- {path}")
    if args.run is not None:
        (target / "budget.json").write_text(json.dumps(budget, indent=1) + "\n")
        wall = "no wall time (give --wall-time MIN)" if budget["wall_time_s"] is None else \
            f"{budget['wall_time_s'] / 60:.1f} min"
        print(f"{target / 'budget.json'}: {budget['env_steps']:,} RL env steps, {wall}")


if __name__ == "__main__":
    main()
