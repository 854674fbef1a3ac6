"""The failure tables of docs/results.md: several ``examples/failure_analysis.py`` folders (one crowd each) in one table.

    python examples/failure_summary.py "ORCA, 6 people=runs/fail/orca6" "social force=runs/fail/sf" \
        "UNIV=runs/fail/univ" --figures paper_results/failures/apg_robust \
        --markdown-into docs/results.md --block failures_apg_robust

One row per folder (``NAME=DIR``: a column name and a folder ``failure_analysis.py`` wrote) and policy, read from
``DIR/failures.json``: the episodes, the collisions with people and with racks, and of the collisions with people the
shares already touching as the step began (no one closing: a recorded person appearing on the robot), where the
person closed faster than the robot, came from behind, was seen in the observation the robot acted
on, saw the robot (was one who avoids it) and could have been avoided by some action in the colliding step or with 1 s
of warning, and the robot's median speed in the colliding step; then the timeouts, those with nobody in view, and the
mean distance left (the rules: :mod:`sb3_crowdnav.evaluation.failures`). ``--figures``
copies each folder's ``collisions_*.png`` (the last seconds of one collision per most frequent class) to
``FIGURES/<name>/`` and links them under the table. Bad input exits with status 2 and one line, before anything is
written.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
from pathlib import Path
from typing import Any

from sb3_crowdnav.cli.common import Parser, UsageError
from sb3_crowdnav.evaluation.aggregate import check_block, write_block

COLUMNS = ("crowd", "policy", "episodes", "collisions (people / racks)", "already touching", "person closing faster",
           "from behind",
           "seen", "sees the robot", "avoidable in the step", "avoidable with 1 s", "robot speed [m/s]", "timeouts",
           "nobody in view", "distance left [m]")


def parse_folder(spec: str) -> tuple[str, Path]:
    """``NAME=DIR`` → the column name and a folder holding ``failures.json``."""
    name, sep, folder = spec.partition("=")
    if not sep or not name.strip() or not folder:
        raise UsageError(f"expected NAME=DIR, got {spec!r}")
    if not (Path(folder) / "failures.json").is_file():
        raise UsageError(f"{spec!r}: no failures.json in {folder} (write it with examples/failure_analysis.py)")
    return name.strip(), Path(folder)


def share(shares: dict[str, Any], key: str) -> str:
    """``count / total`` of a share; "–" when nothing was counted."""
    entry = shares.get(key) or {}
    return f"{entry['count']} / {entry['total']}" if entry.get("total") else "–"


def rows(name: str, folder: Path) -> list[list[str]]:
    """The table rows of one folder: one per policy."""
    data = json.loads((folder / "failures.json").read_text())
    out = []
    for label, entry in data["policies"].items():
        s = entry["summary"]
        shares = s["shares"]
        left, speed = s.get("distance_left"), s.get("robot_speed")  # (None: no collision, or written before it)
        touching = sum(s["table"]["none"].values())  # nobody closing: the discs overlapped as the step began
        touching = f"{touching} / {s['collisions']}" if s["collisions"] else "–"
        out.append([name, label, str(s["episodes"]), f"{s['collisions']} / {s['obstacle_collisions']}", touching,
                    share(shares, "person_faster"), share(shares, "behind"), share(shares, "seen"),
                    share(shares, "sees_robot"), share(shares, "avoidable"), share(shares, "avoidable_with_warning"),
                    "–" if speed is None else f"{speed:.2f}", str(s["timeouts"]),
                    share(shares, "nobody_in_view"), "–" if left is None else f"{left:.2f}"])
    return out


def slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


def table(folders: list[tuple[str, Path]], figures: Path | None, relative_to: Path) -> str:
    """The Markdown table, and the figure links when ``figures`` is given (paths relative to ``relative_to``)."""
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(row) + " |" for name, folder in folders for row in rows(name, folder)]
    if figures is not None:
        lines.append("")
        for name, folder in folders:
            target = figures / slug(name)
            target.mkdir(parents=True, exist_ok=True)
            for png in sorted(folder.glob("collisions_*.png")):
                shutil.copyfile(png, target / png.name)
                policy = png.stem.removeprefix("collisions_")
                link = Path(os.path.relpath(target / png.name, relative_to)).as_posix()
                lines.append(f"![{name}: typical collisions of {policy}]({link})")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    p = Parser(prog="failure_summary.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folders", nargs="+", metavar="NAME=DIR", help="a column name and a failure_analysis.py folder")
    p.add_argument("--figures", type=Path, help="copy the collision figures here and link them")
    p.add_argument("--markdown-into", type=Path, metavar="FILE", help="write the table into a block of this page")
    p.add_argument("--block", default="failures", help="the block's name: <!-- NAME:begin --> ... <!-- NAME:end -->")
    args = p.parse_args(argv)
    try:
        folders = [parse_folder(spec) for spec in args.folders]
        if args.markdown_into is not None:
            check_block(args.markdown_into, args.block)
    except (UsageError, ValueError) as exc:
        p.error(str(exc))
    page_dir = args.markdown_into.parent if args.markdown_into is not None else Path.cwd()
    text = table(folders, args.figures, page_dir)
    if args.markdown_into is not None:
        write_block(args.markdown_into, args.block, text)
    print(text, end="")


if __name__ == "__main__":
    main()
