"""``sb3-crowdnav sweep GRID.yaml``: a grid of ``train`` runs and their evaluations on Ray, then one rliable table.

Each cell (:mod:`sb3_crowdnav.cli.grid`) is one Ray task that runs ``sb3-crowdnav train`` into the cell's folder and then
``sb3-crowdnav evaluate`` for each column, in the Ray worker's process. A rerun of the sweep skips the finished cells and
resumes the others from their folders, from their newest checkpoints (a ``--hyperparams`` cell checkpoints every
50,000 env steps unless its ``train`` options set ``checkpoint_freq``); a worker that dies is retried by Ray
(``--retries``) and the retry resumes the same way. A cell that fails is reported and the others go on; the command
exits with 1 at the end if any failed. Then the evaluations of the finished cells are aggregated with rliable
(:mod:`sb3_crowdnav.evaluation.aggregate`) into ``OUT/aggregate.md`` and its CSVs, which state each cell's training
budget (RL env steps and wall time, from its run's ``progress.json``).

A cell's folder is ``OUT/cells/METHOD/ENV/seed_S`` (the grid's format: docs/training.md, "Sweeps and seeds"). The
sweep starts a local Ray instance by default (loopback only); ``--address`` joins a cluster, with OUT and the grid's
files on storage that every node sees.
"""

from __future__ import annotations

import argparse
import contextlib
import fnmatch
import json
import os
import shlex
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sb3_crowdnav.cli import grid as grids
from sb3_crowdnav.cli.common import UsageError, add_command, check_env, check_out, env_kwargs_from_args, positive_int
from sb3_crowdnav.cli.grid import Cell, Grid

INSTALL_HINT = "sb3-crowdnav sweep runs on Ray: pip install 'sb3_crowdnav[cluster]'"


def add_parser(sub: Any, parents: list[argparse.ArgumentParser]) -> None:
    """Add ``sweep`` to the subcommands ``sub``."""
    p = add_command(sub, "sweep", parents, __doc__,
                    "run a grid of train runs and their evaluations on Ray, then aggregate them")
    p.add_argument("grid", type=Path, metavar="GRID.yaml", help="the grid file")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="the sweep's folder")
    p.add_argument("--dry-run", action="store_true", help="check the grid, list the cells and their state, run nothing")
    p.add_argument("--address", metavar="ADDRESS", help="a running Ray cluster's address (ray.init(address=...))")
    p.add_argument("--num-cpus", type=positive_int, help="CPUs of the local Ray instance (default: the machine's)")
    p.add_argument("--cpus-per-cell", type=positive_int, default=1,
                   help="CPUs Ray reserves for each cell (default: 1; give 2 to variant runs with overlap=process); "
                        "a method's 'cpus' in the grid overrides it for its cells")
    p.add_argument("--retries", type=int, choices=range(0, 11), default=1, metavar="N",
                   help="times Ray runs a cell again whose worker died (default: 1); the retry resumes the cell")
    p.add_argument("--cells", nargs="+", metavar="PATTERN",
                   help="run only the cells whose name METHOD/ENV/seed_S matches one of these shell-style patterns "
                        "(e.g. 'LM_RL/*/seed_[12]' 'SF_RL/*'; quote them); the aggregate still covers every finished "
                        "cell in OUT (default: every cell)")
    p.add_argument("--reps", type=positive_int, default=2000, help="bootstrap resamples per interval (default: 2000)")
    p.set_defaults(func=cmd_sweep)


def check_grid(grid: Grid, all_cells: list[Cell]) -> None:
    """Every cell's ``train`` and ``evaluate`` commands, checked as those commands check them, before any work."""
    checked: set[tuple[str, str]] = set()
    for cell in all_cells:
        if (cell.method.name, cell.env) in checked:
            continue
        checked.add((cell.method.name, cell.env))
        where = f"methods.{cell.method.name} in envs.{cell.env}"
        if cell.method.model == "best" and "--eval-episodes" in cell.method.train \
                and cell.method.train[cell.method.train.index("--eval-episodes") + 1] == "0":
            raise UsageError(f"{where}: model 'best' needs validation (eval_episodes > 0); write model: final")
        try:
            from sb3_crowdnav.cli.train import check_train

            check_train(grids.parse_command(cell.train_argv()))
            for column in grid.columns:
                args = grids.parse_command(grids.eval_argv(cell, grid, column))
                check_env(args.env, env_kwargs_from_args(args))
        except UsageError as exc:
            raise UsageError(f"{where}: {exc}") from None
    for cell in all_cells:
        grids.cell_state(cell, grid)  # a folder of other settings is refused here


def select_cells(all_cells: list[Cell], patterns: list[str] | None) -> list[Cell]:
    """The cells whose name (``METHOD/ENV/seed_S``) matches one of the shell-style ``patterns`` (:mod:`fnmatch`, case
    sensitive), in the grid's order; every cell without patterns. A pattern that matches no cell is refused."""
    if not patterns:
        return all_cells
    for pattern in patterns:
        if not any(fnmatch.fnmatchcase(cell.name, pattern) for cell in all_cells):
            names = ", ".join(cell.name for cell in all_cells[:4]) + (", ..." if len(all_cells) > 4 else "")
            raise UsageError(f"--cells: {pattern!r} matches none of the grid's cells ({names})")
    return [cell for cell in all_cells if any(fnmatch.fnmatchcase(cell.name, p) for p in patterns)]


def cmd_sweep(args: argparse.Namespace) -> int:
    if args.address is not None and args.num_cpus is not None:
        raise UsageError("--num-cpus sets the local Ray instance's CPUs; a cluster (--address) has its own")
    grid = grids.load_grid(args.grid)
    all_cells = grids.cells(grid, args.out)
    check_grid(grid, all_cells)
    selected = select_cells(all_cells, args.cells)
    if args.address is None:  # a cell to run that reserves more CPUs than the local instance has would never start
        available = args.num_cpus or os.cpu_count() or 1
        for method in dict.fromkeys(cell.method for cell in selected):  # (the methods of --cells only)
            needed = method.cpus or args.cpus_per_cell
            if needed > available:
                source = f"methods.{method.name}.cpus" if method.cpus else "--cpus-per-cell"
                raise UsageError(f"{source}: each {method.name} cell reserves {needed} CPUs, more than the local Ray "
                                 f"instance's {available} (--num-cpus); it would never start")
    states = {cell.name: grids.cell_state(cell, grid) for cell in all_cells}
    for cell in selected:
        state, detail = states[cell.name]
        print(f"{state:8s} {cell.name}{f' ({detail})' if detail else ''}")
    counts = {state: sum(states[cell.name][0] == state for cell in selected) for state in grids.STATES}
    print(", ".join(f"{n} {state}" for state, n in counts.items())
          + (f" (--cells: {len(selected)} of the grid's {len(all_cells)} cells)" if args.cells else ""))
    if args.dry_run:
        return 0
    check_out(args.out)
    todo = [cell for cell in selected if states[cell.name][0] != "done"]
    failed = run_on_ray(todo, grid, args.address, args.num_cpus, args.cpus_per_cell, args.threads, args.retries) \
        if todo else []
    done = [cell for cell in all_cells if cell.name not in {c.name for c in failed}
            and grids.cell_state(cell, grid)[0] == "done"]
    if grid.columns and done:
        _aggregate(done, grid, args.out, args.reps)
    if failed:
        print(f"{len(failed)} of {len(all_cells)} cells failed: {', '.join(c.name for c in failed)}; run the same "
              "command again to resume them", file=sys.stderr)
        return 1
    return 0


def _aggregate(done: list[Cell], grid: Grid, out: Path, reps: int) -> None:
    from sb3_crowdnav.evaluation.aggregate import aggregate, read_seed_score
    from sb3_crowdnav.evaluation.budget import read_budget

    scores = [read_seed_score(cell.eval_folder(column), cell.label, column, cell.seed)
              for cell in done for column in grid.columns]
    try:  # every cell's run states its budget (RL env steps, wall time) in the tables
        budgets = [read_budget(cell.train_folder, cell.label, cell.seed) for cell in done]
        result = aggregate(scores, reps=reps, budgets=budgets)
    except (FileNotFoundError, ImportError, ValueError) as exc:
        print(f"no aggregate table: {exc}", file=sys.stderr)
        return
    written = result.save(out / "aggregate")
    print(result.to_markdown(), end="")
    print(f"\nwrote {', '.join(p.name for p in written)} in {out}")


@dataclass(frozen=True)
class Report:
    """What a cell's task returns: None or the error, and the wall time [s] of this attempt."""

    error: str | None
    seconds: float


@contextlib.contextmanager
def _output_to(path: Path) -> Iterator[None]:
    """This process's stdout and stderr (file descriptors 1 and 2, so child processes' too) appended to ``path``."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with path.open("a") as log:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)


def _command(argv: list[str]) -> int:
    """``sb3-crowdnav ARGV`` in this process; its exit status."""
    from sb3_crowdnav.cli import main

    print(f"$ sb3-crowdnav {shlex.join(argv)}", flush=True)
    try:
        return int(main(argv) or 0)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1


def _last_error(log: Path) -> str:
    lines = [line for line in log.read_text(errors="replace").splitlines() if line.strip()]
    errors = [line for line in lines if "error:" in line]
    return (errors or lines or ["(no output)"])[-1]


def run_cell(cell: Cell, grid: Grid, threads: int = 1) -> Report:
    """Train (or resume) the cell, then evaluate its model in every column not yet evaluated (in a Ray worker)."""
    start = time.perf_counter()
    cell.folder.mkdir(parents=True, exist_ok=True)
    if not (cell.folder / "cell.json").is_file():
        (cell.folder / "cell.json").write_text(json.dumps(grids.identity(cell)) + "\n")
    log = cell.folder / "cell.log"
    with _output_to(log):
        commands = [] if grids.trained(cell) else [("train", cell.train_argv(threads))]
        commands += [(f"evaluate {column}", grids.eval_argv(cell, grid, column, threads)) for column in grid.columns
                     if not grids.eval_done(cell, grid, column)]
        for name, argv in commands:
            code = _command(argv)
            if code != 0:
                return Report(f"{name} exited with {code}: {_last_error(log)} (log: {log})", time.perf_counter() - start)
    return Report(None, time.perf_counter() - start)


def run_on_ray(todo: list[Cell], grid: Grid, address: str | None = None, num_cpus: int | None = None,
               cpus_per_cell: int = 1, threads: int = 1, retries: int = 1) -> list[Cell]:
    """Run the cells as Ray tasks (a local instance unless ``address``; Ray already started in this process is used
    as it is); print each one's end; return the cells that failed."""
    try:
        import ray
    except ImportError:
        raise UsageError(INSTALL_HINT) from None
    started = not ray.is_initialized()
    if started:
        local = {"num_cpus": num_cpus, "_node_ip_address": "127.0.0.1"} if address is None else {}
        ray.init(address=address, include_dashboard=False, log_to_driver=False, **local)
    try:
        task = ray.remote(run_cell)
        pending = {task.options(num_cpus=cell.method.cpus or cpus_per_cell, max_retries=retries).remote(cell, grid, threads):
                   cell for cell in todo}
        failed = []
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            cell = pending.pop(ready[0])
            try:
                report = ray.get(ready[0])
            except ray.exceptions.RayError as exc:  # the worker died more often than --retries, or Ray failed
                report = Report(f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}", float("nan"))
            if report.error is not None:
                failed.append(cell)
                print(f"failed   {cell.name}: {report.error}", flush=True)
            else:
                print(f"done     {cell.name} ({report.seconds:.0f} s)", flush=True)
        return failed
    finally:
        if started:
            ray.shutdown()
