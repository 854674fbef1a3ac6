"""Regenerate the warehouse results of the README: ORCA, PPO and APG in ``CrowdNavWarehouse-v0``.

    python examples/warehouse_results.py [--episodes 500] [--out paper_results/warehouse] [--workers 2] \
        [--world both|today|paper] [--protective-field 0.5,0.3]

``sb3-crowdnav benchmark`` runs on the test seeds (1,000,000 + i: layouts the generator never drew in training,
which used the env's own stream from seed 0, nor in validation, seeds 2,000,000 + i). ``--world today`` runs the
warehouse as it is by default (a warehouse AMR with a stop and limits, racks that hide pickers, pickers who see the
robot), with ``pretrained:apg_warehouse`` (the ``apg_warehouse`` recipe, trained in that world), the ORCA robot (both
mappings) and every ``--policy`` given (e.g. the PPO baseline of the same wall time):

* ``OUT/today``: generated layouts, 6 pickers, and the sweep of ``apg_warehouse`` over ``--sweep`` pickers;
* ``OUT/today_social_force``: the same with social-force pickers;
* ``OUT/today_layout_file``: the fixed layout of ``examples/warehouse_layout.yaml``;
* ``OUT/protective_field``: generated layouts behind a protective field (``--protective-field``, default
  ``0.5,0.3``: 0.5 m around the robot, commands capped at 0.3 m/s).

``--world paper`` runs the models shipped before it, trained in the paper's world
(``sim.warehouse.config.PAPER_WAREHOUSE``: the paper's robot, pickers who never see it, every picker seen through
racks at any range): ``pretrained:apg_warehouse_paper``, ``pretrained:ppo_warehouse`` and the ORCA robot (``orca``,
and ``orca-constrained``: ORCA's velocity mapped onto the robot's 80 actions):

* ``OUT/generated``: generated layouts, 6 pickers, with trajectories over the layout and a GIF per policy, and the
  sweep of ``apg_warehouse_paper``;
* ``OUT/layout_file``: the fixed layout file;
* ``OUT/today_paper_models``: the same models under today's defaults (``--allow-env-mismatch``: they choose among
  their 80 actions, their lookahead predicting the paper's robot, and the env clips each command to the AMR's
  limits), to show how much they drop;
* ``OUT/unshaped``: with ``--unshaped ZIP``, a model trained without the route-progress shaping.

``--world both`` (the default) runs both, ``--world none`` neither (the summary only). Every table has its safety
figures beside it (minimum time-to-collision, near misses, speed near people, peak acceleration and turn rate,
clearance to racks). ``OUT/summary.md`` collects the
tables of every world run so far (the README's warehouse section is copied from it) and the training wall
times. These are read from run folders: ``--runs DIR`` times ``DIR/apg_warehouse`` and ``DIR/ppo_warehouse``, and
``--time-run NAME=FOLDER[:N]`` any run (to the validation of its checkpoint N, else of its ``best.zip``). Each is
recorded in ``OUT/wall_times.json``, which keeps the times of runs whose folders are no longer on this machine; the
summary lists every recorded time. Without ``--unshaped`` the summary keeps an earlier ``OUT/unshaped`` table.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

from sb3_crowdnav.cli import main as cli

ENV = "CrowdNavWarehouse-v0"
LAYOUT_FILE = Path(__file__).with_name("warehouse_layout.yaml")
TODAY = ("pretrained:apg_warehouse", "orca", "orca-constrained")
PAPER_MODELS = ("pretrained:apg_warehouse_paper", "pretrained:ppo_warehouse", "orca", "orca-constrained")
SWEEP = (2, 4, 6, 8, 10)
# the world the shipped warehouse models were trained in, not today's defaults: the paper's robot (80 actions, no
# limits) among pickers who do not see it (robot_visible=False), seen through racks at any range
PAPER_ROBOT = ("actions='paper', max_acceleration=None, max_turn_rate=None, robot_visible=False, occlusion=False, "
               "people_sensor_range=None")


def layout_arg() -> str:
    """The layout file as the runs name it: relative to the working folder when inside it (the tables' meta.json
    then record the repository's path, not this machine's)."""
    try:
        return str(LAYOUT_FILE.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(LAYOUT_FILE)


def benchmark(out: Path, policies, episodes: int, workers: int, extra=()) -> None:
    args = ["benchmark", "--env", ENV, "--episodes", str(episodes), "--workers", str(workers), "--out", str(out),
            "--no-progress", *extra]
    for policy in policies:
        args += ["--policy", policy]
    code = cli(args)
    if code:
        raise SystemExit(f"sb3-crowdnav {' '.join(args)} exited with {code}")


def number(row: dict[str, str], name: str, digits: int = 2) -> str:
    """A CSV cell rounded for a table; "–" when it is empty, nan or missing (an older CSV)."""
    return "–" if row.get(name, "") in ("", "nan") else f"{float(row[name]):.{digits}f}"


def compact(results_csv: Path, key: str = "method") -> str:
    """The README's columns of a ``results.csv``: rates with their 95 % intervals, time, path / route, gap."""
    def rate(row, name):
        return f"{float(row[name]):.3f} [{float(row[name + '_ci_low']):.3f}, {float(row[name + '_ci_high']):.3f}]"

    lines = [f"| {key} | success | picker collision | obstacle collision | timeout | time [s] | path / route | "
             "gap [m] |", "|---|---|---|---|---|---|---|---|"]
    with results_csv.open() as f:
        for row in csv.DictReader(f):
            lines.append(f"| {row[key]} | {rate(row, 'success')} | {rate(row, 'human_collision')} | "
                         f"{rate(row, 'obstacle_collision')} | {rate(row, 'timeout')} | {number(row, 'time')} | "
                         f"{number(row, 'route_ratio')} | {number(row, 'gap')} |")
    return "\n".join(lines)


def compact_safety(results_csv: Path, key: str = "method") -> str:
    """The safety figures of a ``results.csv``: min TTC (mean over episodes, s), the share of episodes with one below
    1 s, near misses per episode, speed near people (m/s), peak acceleration and turn rate (mean / max), clearance to
    racks (mean / worst, m)."""
    lines = [f"| {key} | min TTC [s] | TTC < 1 s | near misses | speed near people [m/s] | peak accel. [m/s²] | "
             "peak turn rate [rad/s] | clearance to racks [m] |", "|---|---|---|---|---|---|---|---|"]
    with results_csv.open() as f:
        for row in csv.DictReader(f):
            lines.append(f"| {row[key]} | {number(row, 'min_ttc')} | {number(row, 'short_ttc', 3)} | "
                         f"{number(row, 'near_misses')} | {number(row, 'speed_near_people')} | "
                         f"{number(row, 'peak_acceleration')} / {number(row, 'peak_acceleration_max')} | "
                         f"{number(row, 'peak_turn_rate')} / {number(row, 'peak_turn_rate_max')} | "
                         f"{number(row, 'min_clearance', 3)} / {number(row, 'min_clearance_worst', 3)} |")
    return "\n".join(lines)


def run_wall_time(folder: Path, episodes: int | None = None) -> str:
    """The wall time of a run folder: from ``config.json``, written at its start, to the validation of the checkpoint
    of ``episodes`` RL episodes (the last one a shipped average used) or else of its ``best.zip`` (the shipped
    checkpoint), or of its last checkpoint without one."""
    if not folder.is_dir():
        return "–"
    config = json.loads((folder / "config.json").read_text())
    if "wall_time_s" in config:  # an --algo run records its own
        return f"{config['wall_time_s'] / 60:.0f} min"
    start = (folder / "config.json").stat().st_mtime
    if episodes is not None:
        rows = [json.loads(line) for line in (folder / "eval_curve.jsonl").read_text().splitlines() if line]
        row = next((r for r in rows if r["episodes"] == episodes), None)
        if row is None:
            raise SystemExit(f"--apg-episodes {episodes}: no validation of that checkpoint in {folder}")
        return f"{(row['wall'] - start) / 60:.0f} min (to the validation of checkpoint {episodes})"
    if (folder / "best.json").is_file():
        best = json.loads((folder / "best.json").read_text())
        return f"{(best['wall'] - start) / 60:.0f} min (to the validation of best.zip, {best['episodes']} RL episodes)"
    curve = [json.loads(line) for line in (folder / "eval_curve.jsonl").read_text().splitlines() if line]
    end = max(row["wall"] for row in curve)
    return f"{(end - start) / 60:.0f} min (to the last validation, {curve[-1]['episodes']} RL episodes)"


def parse_time_run(parser: argparse.ArgumentParser, spec: str) -> tuple[str, Path, int | None]:
    """``NAME=FOLDER[:N]`` of ``--time-run``: the name, the run folder and the checkpoint (None: its best.zip)."""
    name, _, rest = spec.partition("=")
    folder, _, episodes = rest.rpartition(":") if rest.rpartition(":")[2].isdigit() else (rest, "", "")
    if not name or not folder:
        parser.error(f"--time-run: expected NAME=FOLDER[:N], got {spec!r}")
    if not (Path(folder) / "config.json").is_file():
        parser.error(f"--time-run: {folder} is not a run folder (no config.json)")
    return name, Path(folder), int(episodes) if episodes else None


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=500)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("paper_results/warehouse"))
    p.add_argument("--policy", action="append", default=[], metavar="SPEC",
                   help="another policy of today's tables (repeatable), e.g. the PPO baseline of the same wall time")
    p.add_argument("--unshaped", metavar="ZIP", help="also evaluate this model trained without progress shaping")
    p.add_argument("--runs", type=Path, help="folder holding the run folders apg_warehouse and ppo_warehouse")
    p.add_argument("--apg-episodes", type=int, metavar="N",
                   help="time the apg_warehouse run to its checkpoint N (the last one a shipped average used; "
                        "default: its best.zip)")
    p.add_argument("--time-run", action="append", default=[], metavar="NAME=FOLDER[:N]",
                   help="record the wall time of this run folder as NAME (to its checkpoint N; repeatable)")
    p.add_argument("--sweep", type=int, nargs="*", default=SWEEP,
                   help="pickers of the sweep (default: 2 4 6 8 10; none: no sweep, an earlier sweep table is kept)")
    p.add_argument("--gif", action=argparse.BooleanOptionalAction, default=True, help="a GIF per policy")
    p.add_argument("--world", choices=("both", "today", "paper", "none"), default="both",
                   help="the default warehouse (today), the shipped models' world (paper), both, or none (only "
                        "rebuild OUT/summary.md from the tables there)")
    p.add_argument("--protective-field", default="0.5,0.3", metavar="D,CAP[,DEG]",
                   help="the field of OUT/protective_field (default: %(default)s)")
    args = p.parse_args(argv)
    timed = [parse_time_run(p, spec) for spec in args.time_run]  # (bad input refused before any episode runs)
    if args.runs:
        timed = [("apg_warehouse", args.runs / "apg_warehouse", args.apg_episodes),
                 ("ppo_warehouse", args.runs / "ppo_warehouse", None), *timed]

    today = (*TODAY, *args.policy)
    if args.world in ("both", "today"):
        sweep = ["--sweep", *map(str, args.sweep)] if args.sweep else []
        benchmark(args.out / "today", today, args.episodes, args.workers, [*sweep, *([] if args.gif else ["--no-gif"])])
        benchmark(args.out / "today_social_force", today, args.episodes, args.workers,
                  ["--env-kwargs", "dict(crowd='social_force')", "--no-gif"])
        benchmark(args.out / "today_layout_file", today, args.episodes, args.workers,
                  ["--env-kwargs", f"dict(layout={layout_arg()!r})", "--no-gif"])
        benchmark(args.out / "protective_field", today, args.episodes, args.workers,
                  ["--protective-field", args.protective_field, "--no-gif"])
    if args.world in ("both", "paper"):
        benchmark(args.out / "generated", PAPER_MODELS, args.episodes, args.workers,
                  ["--env-kwargs", f"dict({PAPER_ROBOT})", *(["--sweep", *map(str, args.sweep)] if args.sweep else []),
                   *([] if args.gif else ["--no-gif"])])
        benchmark(args.out / "layout_file", PAPER_MODELS, args.episodes, args.workers,
                  ["--env-kwargs", f"dict(layout={layout_arg()!r}, {PAPER_ROBOT})", "--no-gif"])
        benchmark(args.out / "today_paper_models", PAPER_MODELS, args.episodes, args.workers,
                  ["--allow-env-mismatch", "--no-gif"])
    field = json.loads((args.out / "protective_field" / "meta.json").read_text())["protective_field"] \
        if (args.out / "protective_field" / "meta.json").is_file() else None
    pickers = ", ".join(map(str, args.sweep or SWEEP))
    sections = [("Today's defaults (a warehouse AMR, racks that hide pickers, pickers who see the robot), generated "
                 "layouts, 6 pickers", args.out / "today" / "results.csv", "method"),
                (f"apg_warehouse with {pickers} pickers, today's defaults", args.out / "today" / "sweep.csv", "humans"),
                ("Today's defaults with social-force pickers", args.out / "today_social_force" / "results.csv",
                 "method"),
                (f"Today's defaults in the layout file {LAYOUT_FILE.name}", args.out / "today_layout_file" / "results.csv",
                 "method"),
                (f"Today's defaults behind a {field}", args.out / "protective_field" / "results.csv", "method"),
                ("The paper-world models under today's defaults", args.out / "today_paper_models" / "results.csv",
                 "method"),
                ("As trained (the paper's robot, blind pickers, seen through racks), generated layouts, 6 pickers",
                 args.out / "generated" / "results.csv", "method"),
                (f"apg_warehouse_paper with {pickers} pickers, as trained", args.out / "generated" / "sweep.csv",
                 "humans"),
                (f"As trained, the layout file {LAYOUT_FILE.name}, 6 pickers", args.out / "layout_file" / "results.csv",
                 "method")]
    sections = [(title, path, key) for title, path, key in sections if path.is_file()]
    if args.unshaped:
        benchmark(args.out / "unshaped", [args.unshaped], args.episodes, args.workers,
                  ["--env-kwargs", f"dict({PAPER_ROBOT})", "--no-gif"])
    if (args.out / "unshaped" / "results.csv").is_file():
        sections.append(("Trained without the progress shaping", args.out / "unshaped" / "results.csv", "method"))
    text = [f"# CrowdNavWarehouse-v0, {args.episodes} test episodes per row (seeds 1,000,000 + i)\n"]
    text += [f"## {title}\n\n{compact(path, key)}\n\nSafety:\n\n{compact_safety(path, key)}\n"
             for title, path, key in sections]
    times_file = args.out / "wall_times.json"
    times = json.loads(times_file.read_text()) if times_file.is_file() else {}
    times.update({name: run_wall_time(folder, episodes) for name, folder, episodes in timed})
    if times:
        times_file.write_text(json.dumps(times, indent=1) + "\n")
        text.append("## Training wall time (2 cores)\n")
        text += [f"- {name}: {time}" for name, time in times.items()]
    (args.out / "summary.md").write_text("\n".join(text) + "\n")
    print((args.out / "summary.md").read_text())


if __name__ == "__main__":
    main()
