"""Regenerate the generalisation table of docs/results.md: every shipped open-floor model and the ORCA robot in other
crowds than the one they were trained in.

    python examples/generalisation.py [--episodes 500] [--workers 2] [--out paper_results/generalisation] \\
        [--scene eth=DIR/biwi_eth.txt,frame_rate=15 --scene hotel=DIR/biwi_hotel.txt ...] \\
        [--markdown-into docs/results.md] [--resume] [--keep paper_results/generalisation/generalisation.csv] \\
        [--planning-depth 2 --planning-width 8]

Rows: ``pretrained:NAME`` for each shipped open-floor model and the ORCA robot (``orca-constrained``: ORCA's velocity
mapped onto the robot's 80 actions), or the ``--policy`` given. Columns (``--columns``, default all five), each one
``sb3-crowdnav benchmark --crowd SPEC`` run in ``CrowdNav-v0`` on the same test seeds (1,000,000 + i; ``--seeds
validation``: 2,000,000 + i, to choose a model or a recipe without the held-out scenes):

* ``orca6``: ORCA, 6 people (``CrowdNav-v0`` as it is, the crowd every model was trained in);
* ``orca10``: ORCA, 10 people;
* ``social_force``: the social force crowd (``crowd="social_force"``);
* ``measured``: the measured-speed population (:data:`sb3_crowdnav.sim.population.MEASURED_POPULATION`: speeds drawn
  from walking speeds, one in five people stopping for a while, half of them seeing the robot) in ORCA;
* ``empty``: the empty floor (no one);

and one column per ``--scene NAME=PATH[,frame_rate=F]``: a recorded scene replayed (``crowd="replay"``; no recording
ships with the package, see the envs page for where the public ones are). Scenes named ``eth`` and ``hotel`` are held
out (never used for training or model selection) and flagged so in the table.

Every column is checked before the first episode: a crowd model that is not registered in this installation is
refused with a message, never skipped. ``OUT/generalisation.md`` / ``.csv`` hold the table (the CSV one row per
policy and column, with every metric and interval), ``OUT/headline.md`` the README's rows (``apg_rl`` and the ORCA
robot), ``OUT/columns.json`` what each column is, and ``OUT/cells/COLUMN/POLICY/`` each cell's own table, its
episode CSV and its ``meta.json``. The rows run one after the other over every column (the README's first), and
``--resume`` keeps the finished cells of an interrupted run (refusing a cell of other settings or, by its SHA-256,
of another model file of the same name) and goes on with the cell it was killed in from its last finished episode
(the cell's episode journal, evaluation page); ``--keep CSV`` (an earlier run's
``generalisation.csv``) keeps its rows of the policies this run does not run, so that one model's row can be run
again (``--policy pretrained:apg_robust --keep paper_results/generalisation/generalisation.csv``).
A model's row runs its own robot in every column, stated under the table: a shipped model's
(:func:`~sb3_crowdnav.models.pretrained_env`, e.g. a model trained with ``actions="with_stop"`` keeps its stop), and
a model file's where the world its file records differs from ``CrowdNav-v0``'s (the step, the robot's actions and
limits; :func:`~sb3_crowdnav.serialization.read_world`).
``--planning-depth D`` / ``--planning-width K`` set the lookahead of the value-model rows (``benchmark``'s options;
the other rows act as they are; refused when no row is a value model), recorded in each cell's ``meta.json``; a
resumed cell run with other settings is refused. With two or more scenes, ``OUT/pooled.md`` also pools each row's
episodes over the scenes (success and collision rates with Wilson intervals). ``--markdown-into FILE`` also replaces
the block between ``<!-- generalisation:begin -->`` and ``<!-- generalisation:end -->`` in FILE (docs/results.md)
with the table.
"""

from __future__ import annotations

import argparse
import json
import re
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym

from sb3_crowdnav.cli import main as cli
from sb3_crowdnav.cli.common import (
    Parser,
    UsageError,
    check_env,
    check_lookahead,
    check_out,
    lookahead_settings,
    positive_int,
)
from sb3_crowdnav.evaluation.aggregate import check_block, write_block
from sb3_crowdnav.evaluation.crowd_spec import CrowdSpec
from sb3_crowdnav.evaluation.metrics import wilson_interval
from sb3_crowdnav.evaluation.policy_spec import PolicySpec
from sb3_crowdnav.evaluation.runner import TEST_SEED_OFFSET
from sb3_crowdnav.evaluation.tables import CrowdTable
from sb3_crowdnav.models import pretrained_env
from sb3_crowdnav.serialization import read_world, world_of
from sb3_crowdnav.sim.crowd import CROWD_MODELS
from sb3_crowdnav.sim.population import MEASURED_POPULATION
from sb3_crowdnav.sim.world import PREDICTION_FIELDS, env_keywords
from sb3_crowdnav.training import VALIDATION_SEED_OFFSET

ENV = "CrowdNav-v0"
MODELS = ("apg_rl", "apg_robust", "lm_rl", "sf_rl", "cadrl", "ppo_apg", "dqn_apg", "apg_crl", "apg_carl")
POLICIES = (*(f"pretrained:{name}" for name in MODELS), "orca-constrained")
ROW_ORDER = (*(name.upper() for name in MODELS), "ORCA-constrained")  # their rows' labels, in a full run's order
HEADLINE = ("APG_RL", "APG_ROBUST", "ORCA-constrained")  # the README's rows (table labels)
FIRST = ("pretrained:apg_rl", "orca-constrained")  # their policies, run first
HELD_OUT = ("eth", "hotel")  # scenes never used for training or model selection
SEEDS = {"test": TEST_SEED_OFFSET, "validation": VALIDATION_SEED_OFFSET}  # --seeds -> first episode seed
# key -> (title, crowd spec, env keyword arguments beside the crowd)
COLUMNS: dict[str, tuple[str, str, dict[str, Any]]] = {
    "orca6": ("ORCA, 6 people", "orca", {}),
    "orca10": ("ORCA, 10 people", "orca", {"num_humans": 10}),
    "social_force": ("social force", "social_force", {}),
    "measured": ("measured-speed population", "orca", dict(MEASURED_POPULATION)),
    "empty": ("empty floor", "orca", {"num_humans": 0}),
}
BLOCK = "generalisation"  # the page's block: <!-- generalisation:begin --> ... <!-- generalisation:end -->
_SCENE_NAME = re.compile(r"[a-z][a-z0-9_]*\Z")


def parse_scene(text: str) -> tuple[str, str, CrowdSpec]:
    """``NAME=PATH[,frame_rate=F]`` of ``--scene``: the column's key, its title and its replay crowd."""
    name, equals, rest = text.partition("=")
    name = name.strip().lower()
    if not (equals and _SCENE_NAME.match(name) and rest.strip()):
        raise UsageError(f"--scene: expected NAME=PATH[,frame_rate=F] with NAME lower-case letters, digits and '_', "
                         f"got {text!r}")
    try:
        spec = CrowdSpec.parse(f"replay:{rest.strip()}", name="--scene")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    title = f"{name} (held out)" if name in HELD_OUT else name
    return name, title, spec


def plan(columns: list[str], scenes: list[str]) -> dict[str, tuple[str, CrowdSpec, dict[str, Any]]]:
    """Every column's title, crowd and env keyword arguments, each checked by making its env once."""
    planned = {key: (COLUMNS[key][0], CrowdSpec.parse(COLUMNS[key][1]), COLUMNS[key][2]) for key in columns}
    for text in scenes:
        key, title, spec = parse_scene(text)
        if key in planned or key in COLUMNS:
            raise UsageError(f"--scene {key}: the name is taken (by a column or another scene); give another")
        planned[key] = (title, spec, {})
    if not planned:
        raise UsageError("no column: give --columns or --scene")
    for key, (_, spec, kwargs) in planned.items():
        if spec.model not in CROWD_MODELS:
            raise UsageError(f"column {key!r} needs the crowd model {spec.model!r}, which is not registered in this "
                             f"installation (registered: {', '.join(CROWD_MODELS)}); leave the column out (--columns, "
                             "--scene) or install the version of sb3_crowdnav that has it")
        try:
            check_env(ENV, {**kwargs, **spec.env_kwargs()}, spec)
        except UsageError as exc:
            raise UsageError(f"column {key!r}: {exc}") from None
    return planned


def cell(out: Path, key: str, policy: str) -> Path:
    """The folder of one cell: one policy in one column."""
    return out / "cells" / key / "".join(c if c.isalnum() or c in "-_." else "_" for c in policy)


def done(folder: Path, episodes: int, seed_offset: int = TEST_SEED_OFFSET,
         lookahead: dict[str, Any] | None = None, *, policy: str) -> bool:
    """Whether the cell in ``folder`` is finished with ``episodes`` episodes from ``seed_offset``, the lookahead
    settings ``lookahead`` and the file ``policy`` plays, by its SHA-256 (``--resume`` keeps it); a finished cell with
    other episodes, seeds, settings or another file of that name is refused, not mixed into the table (a cell written
    before its meta.json recorded the file's SHA-256 is taken as it is)."""
    if not (folder / "crowds.csv").is_file():
        return False
    meta = json.loads((folder / "meta.json").read_text())
    had, seeds = meta.get("episodes"), meta.get("seeds", [None])
    if had != episodes or seeds[0] != seed_offset:
        raise SystemExit(f"{folder} holds {had} episodes from seed {seeds[0]}, not --episodes {episodes} from seed "
                         f"{seed_offset}: give another --out")
    if meta.get("lookahead") != lookahead:
        raise SystemExit(f"{folder} was run with the lookahead settings {meta.get('lookahead')}, not {lookahead}: "
                         "give another --out")
    if "policy_sha256" in meta:
        (recorded,), digest = meta["policy_sha256"].values(), PolicySpec.parse(policy).file_sha256()
        if recorded != digest:
            raise SystemExit(f"{folder} was run with another file of {policy} (SHA-256 {str(recorded)[:16]}...), not "
                             f"this one ({str(digest)[:16]}...): give another --out")
    return True


def lookahead_flags(args: argparse.Namespace, policy: str) -> list[str]:
    """``--planning-depth`` / ``--planning-width`` as given, for a value model's benchmark (APGValue); none for
    another policy (ORCA, a DQN: the settings are a value model's lookahead)."""
    if lookahead_settings(args, PolicySpec.parse(policy)) is None:
        return []
    return [item for key in ("planning_depth", "planning_width") if getattr(args, key) is not None
            for item in (f"--{key.replace('_', '-')}", str(getattr(args, key)))]


def robot_kwargs(policy: str) -> dict[str, Any]:
    """The env keyword arguments of a model's own robot, added to every column of its row: a shipped model's
    (``pretrained:NAME``: :func:`~sb3_crowdnav.models.pretrained_env`, e.g. ``actions="with_stop"``), or those in
    which a model file's world differs from ``CrowdNav-v0``'s (:func:`~sb3_crowdnav.serialization.read_world`: the
    step and the robot's actions and limits); none for another policy."""
    spec = PolicySpec.parse(policy)
    if spec.kind == "file":
        try:
            world = read_world(str(spec.argument))
        except (OSError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
            raise UsageError(f"--policy {policy}: not a model file this package reads ({exc})") from None
        return {} if world is None else env_keywords(world, world_of(gym.make(ENV)), PREDICTION_FIELDS)
    if spec.kind != "pretrained":
        return {}
    env_id, kwargs = pretrained_env(str(spec.argument))
    if env_id != ENV:
        raise UsageError(f"--policy {policy}: the model was trained in {env_id}, the table is of {ENV}")
    return kwargs


def benchmark(out: Path, spec: CrowdSpec, env_kwargs: dict[str, Any], policy: str, episodes: int,
              workers: int, seed_offset: int = TEST_SEED_OFFSET, lookahead: tuple[str, ...] = ()) -> None:
    """One ``sb3-crowdnav benchmark --crowd`` run: one policy in one column (``lookahead``: its lookahead flags)."""
    args = ["benchmark", "--env", ENV, "--crowd", str(spec), "--episodes", str(episodes), "--workers", str(workers),
            "--out", str(out), "--no-progress", "--seed-offset", str(seed_offset), "--policy", policy, *lookahead]
    if env_kwargs:
        args += ["--env-kwargs", repr(env_kwargs)]
    code = cli(args)
    if code:
        raise SystemExit(f"sb3-crowdnav {' '.join(args)} exited with {code}")


def combine(out: Path, planned: dict[str, tuple[str, CrowdSpec, dict[str, Any]]], policies: list[str]) -> CrowdTable:
    """The cells' tables as one, each column's crowd named by its key, the rows in the order of ``policies``."""
    rows = []
    for policy in policies:
        for key in planned:
            rows += [{**row, "crowd": key} for row in CrowdTable.read_csv(cell(out, key, policy) / "crowds.csv").rows]
    return CrowdTable(rows)


def earlier_rows(path: Path, keys: list[str]) -> CrowdTable:
    """An earlier run's table (its ``generalisation.csv``), checked to have this run's columns."""
    if not path.is_file():
        raise UsageError(f"--keep: no table at {str(path)!r}")
    earlier = CrowdTable.read_csv(path)
    if earlier.crowds != keys:
        raise UsageError(f"--keep: {str(path)!r} has the columns {earlier.crowds}, this run {keys}")
    return earlier


def merged(earlier: CrowdTable, table: CrowdTable) -> CrowdTable:
    """``earlier``'s rows with the methods of ``table`` in their place, in the order of a full run (the shipped models'
    rows, then the ORCA robot's: :data:`ROW_ORDER`), any other rows after them in the order they come."""
    fresh = {method: [row for row in table.rows if row["method"] == method] for method in table.policies}
    given = list(dict.fromkeys([*earlier.policies, *fresh]))
    methods = sorted(given, key=lambda m: (ROW_ORDER.index(m), 0) if m in ROW_ORDER else (len(ROW_ORDER), given.index(m)))
    return CrowdTable([row for method in methods
                       for row in fresh.get(method, [r for r in earlier.rows if r["method"] == method])])


def pooled_scenes(table: CrowdTable, scenes: list[str], titles: dict[str, str]) -> str:
    """Per policy, the episodes of every scene column pooled: success and collision rates of all of them, with Wilson
    intervals (a markdown table)."""
    lines = [f"| method | {' + '.join(titles[key] for key in scenes)} | episodes |", "|---|---|---|"]
    for method in table.policies:
        rows = [row for row in table.rows if row["method"] == method and row["crowd"] in scenes]
        n = sum(int(row["episodes"]) for row in rows)
        cells = []
        for rate in ("success", "collision"):
            count = round(sum(float(row[rate]) * int(row["episodes"]) for row in rows))
            low, high = wilson_interval(count, n)
            cells.append(f"{count / n:.3f} [{low:.3f}, {high:.3f}]")
        lines.append(f"| {method} | {' / '.join(cells)} | {n:,} |")
    return "\n".join(lines) + "\n\nEach cell: success [95 % interval] / collision [95 % interval], pooled over the scenes.\n"


def markdown_block(table: CrowdTable, planned, episodes: int, robots: dict[str, dict[str, Any]] | None = None) -> str:
    """The docs' block: the table, then what each column is and the rows whose robot differs (``robots``: policy ->
    :func:`robot_kwargs`)."""
    titles = {key: title for key, (title, _, _) in planned.items()}
    lines = [f"{episodes} test episodes per cell (seeds 1,000,000 + i, the same in every column), `{ENV}` otherwise; "
             "written by `examples/generalisation.py`.", "", table.to_markdown(titles).rstrip(), "", "Columns:", ""]
    for key, (title, spec, kwargs) in planned.items():
        setting = ", ".join(f"`{k}={v!r}`" for k, v in kwargs.items())
        text = str(spec)
        path = dict(spec.settings).get("path") if spec.model == "replay" else None
        if path:  # the recording's folder is this machine's: DATA, as in the command above the table
            text = text.replace(str(path), f"DATA/{Path(str(path)).name}")
        lines.append(f"- {title} (`{key}`): `--crowd {text}`" + (f" with {setting}" if setting else ""))
    for policy, kwargs in (robots or {}).items():
        if kwargs:
            setting = ", ".join(f"`{k}={v!r}`" for k, v in kwargs.items())
            lines.append(f"- the row of `{policy}` runs its model's robot in every column: {setting}")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    p = Parser(prog="generalisation.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=positive_int, default=500, help="test episodes per cell (default: 500)")
    p.add_argument("--workers", type=positive_int, default=2, help="worker processes (default: 2)")
    p.add_argument("--out", type=Path, default=Path("paper_results/generalisation"), help="output folder")
    p.add_argument("--policy", action="append", metavar="SPEC",
                   help="a row (repeat; default: every shipped open-floor model and orca-constrained)")
    p.add_argument("--columns", nargs="*", choices=tuple(COLUMNS), default=list(COLUMNS), metavar="KEY",
                   help=f"the built-in columns, of {', '.join(COLUMNS)} (default: all)")
    p.add_argument("--scene", action="append", default=[], metavar="NAME=PATH[,frame_rate=F]",
                   help="a column of a recorded scene (repeat); eth and hotel are flagged held out")
    p.add_argument("--seeds", choices=tuple(SEEDS), default="test",
                   help="the test seeds (1,000,000 + i, the docs' tables) or the validation seeds (2,000,000 + i, for "
                        "choosing a model or a recipe; refuses the held-out scenes and --markdown-into)")
    p.add_argument("--resume", action="store_true",
                   help="keep the finished cells (one policy in one column) of an earlier run into --out")
    p.add_argument("--keep", type=Path, metavar="CSV",
                   help="an earlier run's generalisation.csv (the same columns): its rows of the policies this run does "
                        "not run are kept in the table, so that one row can be run again")
    p.add_argument("--planning-depth", type=positive_int, metavar="D",
                   help="the value models' lookahead searches D steps before V (benchmark --planning-depth; default: "
                        "each model's own)")
    p.add_argument("--planning-width", type=positive_int, metavar="K",
                   help="with a depth > 1, the best K actions of each step searched deeper (benchmark --planning-width)")
    p.add_argument("--markdown-into", type=Path, metavar="FILE",
                   help=f"replace the block between <!-- {BLOCK}:begin --> and <!-- {BLOCK}:end --> in FILE with the table")
    args = p.parse_args(argv)
    try:  # every column, the output and the docs' block, before any episode
        if args.seeds == "validation":
            if held := [key for key in (parse_scene(text)[0] for text in args.scene) if key in HELD_OUT]:
                raise UsageError(f"--seeds validation: the held-out scenes ({', '.join(held)}) are never used to "
                                 "choose; leave them out")
            if args.markdown_into is not None:
                raise UsageError("--seeds validation: the docs' table is of the test seeds; leave out --markdown-into")
        planned = plan(list(dict.fromkeys(args.columns)), args.scene)
        earlier = None if args.keep is None else earlier_rows(args.keep, list(planned))
        check_out(args.out)
        if args.markdown_into is not None:
            check_block(args.markdown_into, BLOCK)
    except (UsageError, ValueError) as exc:
        p.error(str(exc))
    policies = args.policy or list(POLICIES)
    try:
        check_lookahead(args, [PolicySpec.parse(policy) for policy in policies])
        robots = {policy: robot_kwargs(policy) for policy in policies}
    except (UsageError, ValueError) as exc:
        p.error(str(exc))
    if not args.resume and (args.out / "cells").exists():
        p.error(f"--out {str(args.out)!r} holds cells of an earlier run: pass --resume to keep them, or give another")

    # one policy at a time over every column (the first rows, the README's, finish first); a finished cell is kept
    for policy in sorted(policies, key=lambda spec: spec not in FIRST):
        for key, (_, spec, kwargs) in planned.items():
            folder = cell(args.out, key, policy)
            flags = lookahead_flags(args, policy)
            if args.resume and done(folder, args.episodes, SEEDS[args.seeds],
                                    lookahead_settings(args) if flags else None, policy=policy):
                print(f"kept {folder}")
                continue
            benchmark(folder, spec, {**kwargs, **robots[policy]}, policy, args.episodes, args.workers,
                      SEEDS[args.seeds], tuple(flags))
    table = combine(args.out, planned, policies)
    if earlier is not None:
        table = merged(earlier, table)
    titles = {key: title for key, (title, _, _) in planned.items()}
    table.save(args.out / "generalisation", titles)
    (args.out / "columns.json").write_text(json.dumps(
        {key: {"title": title, "crowd": str(spec), "env_kwargs": kwargs, "held_out": key in HELD_OUT}
         for key, (title, spec, kwargs) in planned.items()}, indent=1, default=list) + "\n")
    block = markdown_block(table, planned, args.episodes, robots)
    print(block)
    scenes = [key for key, (_, spec, _) in planned.items() if spec.model == "replay"]
    if len(scenes) > 1:
        text = pooled_scenes(table, scenes, titles)
        (args.out / "pooled.md").write_text(text)
        print(f"The scenes pooled:\n\n{text}")
    headline = [row for row in table.rows if row["method"] in HEADLINE]
    if headline:
        text = CrowdTable(headline).to_markdown(titles)
        (args.out / "headline.md").write_text(text)
        print(f"README headline:\n\n{text}")
    if args.markdown_into is not None:
        write_block(args.markdown_into, BLOCK, block)
        print(f"wrote the table into {args.markdown_into}")


if __name__ == "__main__":
    main()
