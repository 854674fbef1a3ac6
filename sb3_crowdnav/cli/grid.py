"""The grid file of ``sb3-crowdnav sweep``: methods x envs x seeds, each cell a ``train`` run and its evaluations.

A grid is a YAML mapping (paths in it are relative to the file)::

    seeds: [0, 1, 2]                      # training seeds (train --seed)
    methods:                              # a method: a paper variant, or a hyperparameter file and its algorithm
      APG_RL: {variant: apg_rl}
      PPO: {hyperparams: ../zoo_hyperparams/ppo.yml, algo: ppo, env: CrowdNav-v0, cpus: 1}  # cpus: optional, the
                                          # CPUs Ray reserves for each of its cells (default: sweep --cpus-per-cell)
      QRDQN: {hyperparams: ../zoo_hyperparams/qrdqn.yml, algo: qrdqn, seeds: [0]}  # seeds: optional, its own
    envs:                                 # optional: env keyword arguments of the training runs (default: one, {})
      orca6: {}
    train: {checkpoint_episodes: 500}     # optional: train options of every cell (a method's own 'train' adds to it)
    evaluate:                             # optional: the evaluations run after each training run
      episodes: 500
      columns: {orca6: {}, orca10: {num_humans: 10}, social_force: {crowd: social_force}}
      # env: CrowdNavWarehouse-v0         # optional: the env every column evaluates in (default: each cell's
                                          # training env, the columns' keyword arguments put over its world's)

With ``evaluate.env`` the columns are that env's keyword arguments and nothing else: the training world's are not
carried over (a model trained among several crowds in ``CrowdNavWorlds-v0`` is tested in one of its base envs, and a
robot setting it was trained with, such as ``actions: with_stop``, is written in each column, or the evaluation
refuses the world mismatch).

A cell is one method in one env with one seed. Its folder ``OUT/cells/METHOD/ENV/seed_S`` holds ``train/`` (the folder
of ``sb3-crowdnav train``, which resumes from it), ``eval/COLUMN/`` (``sb3-crowdnav evaluate --out``), ``cell.json``
(the settings the cell started with) and ``cell.log`` (what its commands printed). :func:`cell_state` reads the state
of a cell from these files alone.
"""

from __future__ import annotations

import argparse
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_crowdnav.cli.common import Parser, UsageError
from sb3_crowdnav.cli.train import HYPERPARAMS_FLAGS, SCHEDULE_FLAGS
from sb3_crowdnav.evaluation.journal import plain

TOP_KEYS = ("seeds", "methods", "envs", "train", "evaluate")
METHOD_KEYS = ("variant", "hyperparams", "algo", "env", "train", "model", "cpus", "seeds")
EVALUATE_KEYS = ("episodes", "seed_offset", "columns", "allow_env_mismatch", "env")
# train options a grid may set (its own keys set the rest: variant, hyperparams, algo, env, seed, out, env kwargs)
TRAIN_FLAGS = {**SCHEDULE_FLAGS, **{k: v for k, v in HYPERPARAMS_FLAGS.items() if k != "algo"},
               "imitation_episodes": "--imitation-episodes", "imitation_epochs": "--imitation-epochs",
               "imitation_learning_rate": "--imitation-learning-rate", "verbose": "--verbose"}
MODELS = ("best", "final")
HYPERPARAMS_CHECKPOINT_FREQ = 50_000  # env steps between a --hyperparams cell's checkpoints, unless its train sets it
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*\Z")
STATES = ("todo", "partial", "done")


class RaisingParser(Parser):
    """The command line's parser whose errors raise :class:`UsageError` instead of exiting (to check a cell)."""

    def error(self, message: str) -> Any:
        raise UsageError(message)


def _refuse(where: str, message: str) -> UsageError:
    return UsageError(f"{where}: {message}")


def _mapping(where: str, value: Any, allowed: tuple[str, ...] | None = None) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise _refuse(where, f"expected a mapping, got {value!r}")
    unknown = [key for key in value if allowed is not None and key not in allowed]
    if unknown:
        raise _refuse(where, f"unknown key {unknown[0]!r}; allowed: {', '.join(allowed or ())}")
    return dict(value)


def _name(where: str, name: Any) -> str:
    if not isinstance(name, str) or not NAME.match(name):
        raise _refuse(where, f"the name {name!r} must be letters, digits, '_', '.' or '-' (it names a folder)")
    return name


def train_options(where: str, options: dict[str, Any]) -> list[str]:
    """The ``train`` flags of a grid's ``train`` mapping; an unknown key or a value of the wrong kind is refused."""
    argv: list[str] = []
    for key, value in options.items():
        if key not in TRAIN_FLAGS:
            raise _refuse(f"{where}.{key}", f"not a train option of a grid; allowed: {', '.join(sorted(TRAIN_FLAGS))}")
        flag = TRAIN_FLAGS[key]
        if flag.startswith("--no-"):  # bootstrap_timeouts: true is the default, false gives the flag
            if not isinstance(value, bool):
                raise _refuse(f"{where}.{key}", f"expected true or false, got {value!r}")
            argv += [] if value else [flag]
        elif isinstance(value, (dict, list)) or value is None:
            raise _refuse(f"{where}.{key}", f"expected one value, got {value!r}")
        else:
            argv += [flag, "off" if value is False and key == "overlap" else str(value)]
    return argv


@dataclass(frozen=True)
class Method:
    """A row of the grid: ``variant`` (the paper's schedule) or ``hyperparams`` + ``algo`` (+ ``env``)."""

    name: str
    variant: str | None = None
    hyperparams: Path | None = None
    algo: str | None = None
    env: str | None = None
    train: tuple[str, ...] = ()  # train flags (the grid's, then the method's own)
    model: str = "best"  # the model evaluated: best.zip or final.zip (a --hyperparams run: best.zip or ALGO.zip)
    cpus: int | None = None  # the CPUs Ray reserves for each of its cells (None: sweep --cpus-per-cell)
    seeds: tuple[int, ...] | None = None  # its own training seeds (None: the grid's)


@dataclass(frozen=True)
class Grid:
    """A checked grid file (:func:`load_grid`)."""

    methods: tuple[Method, ...]
    seeds: tuple[int, ...]
    envs: dict[str, dict[str, Any]]
    columns: dict[str, dict[str, Any]] = field(default_factory=dict)
    episodes: int = 500
    seed_offset: int = 1_000_000
    allow_env_mismatch: bool = False
    eval_env: str | None = None  # evaluate.env: the env of every column (None: each cell's training env)


def _method(where: str, name: str, entry: Any, common: list[str], base: Path) -> Method:
    from sb3_crowdnav.cli.train import ALGOS
    from sb3_crowdnav.training.schedule import VARIANTS

    entry = _mapping(where, entry, METHOD_KEYS)
    train = common + train_options(f"{where}.train", _mapping(f"{where}.train", entry.get("train")))
    seeds = _int_list(f"{where}.seeds", entry["seeds"]) if "seeds" in entry else None
    model = entry.get("model", "best")
    cpus = entry.get("cpus")
    if cpus is not None and (isinstance(cpus, bool) or not isinstance(cpus, int) or cpus < 1):
        raise _refuse(f"{where}.cpus", f"expected a positive integer (the CPUs Ray reserves for each of the method's "
                                       f"cells; default: sweep --cpus-per-cell), got {cpus!r}")
    if model not in MODELS:
        raise _refuse(f"{where}.model", f"expected one of {', '.join(MODELS)}, got {model!r}")
    if ("variant" in entry) == ("hyperparams" in entry):
        raise _refuse(where, "give either 'variant' (a paper variant) or 'hyperparams' with 'algo'")
    if "variant" in entry:
        if entry["variant"] not in VARIANTS:
            raise _refuse(f"{where}.variant", f"expected one of {', '.join(sorted(VARIANTS))}, got {entry['variant']!r}")
        for key in ("algo", "env"):
            if key in entry:
                raise _refuse(f"{where}.{key}", "is for 'hyperparams' methods (a variant has its own env)")
        return Method(name, variant=entry["variant"], train=tuple(train), model=model, cpus=cpus, seeds=seeds)
    if entry.get("algo") not in ALGOS:
        raise _refuse(f"{where}.algo", f"expected one of {', '.join(ALGOS)}, got {entry.get('algo')!r}")
    if "model" not in entry:  # a --hyperparams run keeps its best model only when it validates its checkpoints
        model = "final"
    elif model == "best" and "--eval-episodes" not in train:
        raise _refuse(f"{where}.model", "a --hyperparams run keeps a best model only when it validates its checkpoints: "
                                        "give train: {eval_episodes: N}, or write final")
    path = Path(str(entry["hyperparams"]))
    path = path if path.is_absolute() else base / path
    if not path.is_file():
        raise _refuse(f"{where}.hyperparams", f"no file {str(path)!r} (paths are relative to the grid file)")
    env = entry.get("env", "CrowdNav-v0")
    if not isinstance(env, str):
        raise _refuse(f"{where}.env", f"expected an env id, got {env!r}")
    return Method(name, hyperparams=path.resolve(), algo=entry["algo"], env=env, train=tuple(train), model=model,
                  cpus=cpus, seeds=seeds)


def _files_from(base: Path, kwargs: dict[str, Any]) -> dict[str, Any]:
    """A column's env keyword arguments with its file paths (the warehouse's ``layout`` file, a recording's
    ``crowd_kwargs["path"]``) made absolute from ``base``, the grid file's folder, as every path of a grid is."""
    def absolute(value: Any) -> Any:
        return str((base / value).resolve()) if isinstance(value, str) and not Path(value).is_absolute() else value

    kwargs = dict(kwargs)
    if "layout" in kwargs:
        kwargs["layout"] = absolute(kwargs["layout"])
    if isinstance(kwargs.get("crowd_kwargs"), dict) and "path" in kwargs["crowd_kwargs"]:
        kwargs["crowd_kwargs"] = {**kwargs["crowd_kwargs"], "path": absolute(kwargs["crowd_kwargs"]["path"])}
    return kwargs


def _int_list(where: str, value: Any) -> tuple[int, ...]:
    values = value if isinstance(value, list) else [value]
    if not values or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in values):
        raise _refuse(where, f"expected integers >= 0 (one or a list), got {value!r}")
    if len(set(values)) != len(values):
        raise _refuse(where, f"a seed is given twice: {value!r}")
    return tuple(values)


def load_grid(path: str | Path) -> Grid:
    """Read and check a grid file's structure; :class:`UsageError` names the first bad key and what is allowed."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise UsageError(f"no grid file {str(path)!r}")
    try:
        content = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise UsageError(f"{path}: not valid YAML{f' (line {mark.line + 1})' if mark else ''}") from None
    top = _mapping(str(path), content, TOP_KEYS)
    for key in ("seeds", "methods"):
        if key not in top:
            raise _refuse(str(path), f"the key {key!r} is missing (keys: {', '.join(TOP_KEYS)})")
    seeds = _int_list(f"{path}: seeds", top["seeds"])
    common = train_options(f"{path}: train", _mapping(f"{path}: train", top.get("train")))
    methods = _mapping(f"{path}: methods", top["methods"])
    if not methods:
        raise _refuse(f"{path}: methods", "give at least one method")
    parsed = tuple(_method(f"{path}: methods.{_name(f'{path}: methods', name)}", name, entry, common, path.parent)
                   for name, entry in methods.items())
    envs = _mapping(f"{path}: envs", top.get("envs")) or {"default": {}}
    envs = {_name(f"{path}: envs", name): _mapping(f"{path}: envs.{name}", kwargs) for name, kwargs in envs.items()}
    evaluate = _mapping(f"{path}: evaluate", top.get("evaluate"), EVALUATE_KEYS)
    columns = _mapping(f"{path}: evaluate.columns", evaluate.get("columns"))
    columns = {_name(f"{path}: evaluate.columns", name): _files_from(path.parent, _mapping(
        f"{path}: evaluate.columns.{name}", kwargs)) for name, kwargs in columns.items()}
    if evaluate and not columns:
        raise _refuse(f"{path}: evaluate.columns", "give at least one column, e.g. {test: {}}")
    episodes, offset = evaluate.get("episodes", 500), evaluate.get("seed_offset", 1_000_000)
    for key, value, low in (("episodes", episodes, 1), ("seed_offset", offset, 0)):
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            raise _refuse(f"{path}: evaluate.{key}", f"expected an integer >= {low}, got {value!r}")
    allow = evaluate.get("allow_env_mismatch", False)
    if not isinstance(allow, bool):
        raise _refuse(f"{path}: evaluate.allow_env_mismatch", f"expected true or false, got {allow!r}")
    eval_env = evaluate.get("env")
    if eval_env is not None and (not isinstance(eval_env, str) or not eval_env):
        raise _refuse(f"{path}: evaluate.env", f"expected an env id (e.g. CrowdNavWarehouse-v0), got {eval_env!r}")
    return Grid(parsed, seeds, envs, columns, episodes, offset, allow, eval_env)


@dataclass(frozen=True)
class Cell:
    """One method in one env with one seed, in its folder.

    :param method: the grid's method (its ``train`` options)
    :param env: the env id the cell trains and evaluates in
    :param env_kwargs: that env's keyword arguments (the grid's env entry)
    :param seed: the training seed
    :param folder: ``OUT/cells/METHOD/ENV/seed_S``, which holds the run (``train/``) and its evaluations (``eval/COLUMN``)
    :param label: the method's name in the aggregated tables (METHOD, or METHOD@ENV with several envs)
    """

    method: Method
    env: str
    env_kwargs: dict[str, Any]
    seed: int
    folder: Path
    label: str

    @property
    def name(self) -> str:
        return f"{self.method.name}/{self.env}/seed_{self.seed}"

    @property
    def train_folder(self) -> Path:
        return self.folder / "train"

    def train_argv(self, threads: int = 1) -> list[str]:
        """The ``sb3-crowdnav train`` command of the cell."""
        m = self.method
        mode = ["--variant", m.variant] if m.variant else ["--hyperparams", str(m.hyperparams), "--algo", str(m.algo),
                                                           "--env", str(m.env)]
        kwargs = ["--env-kwargs", repr(self.env_kwargs)] if self.env_kwargs else []
        if m.hyperparams and "--checkpoint-freq" not in m.train:  # resumable: a rerun goes on from the newest
            kwargs += ["--checkpoint-freq", str(HYPERPARAMS_CHECKPOINT_FREQ)]
        return ["train", *mode, "--seed", str(self.seed), *kwargs, *m.train, "--out", str(self.train_folder),
                "--threads", str(threads), "--no-progress"]

    @property
    def model_path(self) -> Path:
        m = self.method
        return self.train_folder / (f"{m.algo}.zip" if m.hyperparams and m.model == "final" else f"{m.model}.zip")

    def eval_folder(self, column: str) -> Path:
        return self.folder / "eval" / column


def cells(grid: Grid, out: Path) -> list[Cell]:
    """The grid's cells, method by method, env by env, seed by seed."""
    several = len(grid.envs) > 1
    return [Cell(m, env, kwargs, seed, out / "cells" / m.name / env / f"seed_{seed}",
                 f"{m.name}@{env}" if several else m.name)
            for m in grid.methods for env, kwargs in grid.envs.items() for seed in (m.seeds or grid.seeds)]


def world_kwargs(cell: Cell) -> dict[str, Any]:
    """The env keyword arguments of the world the cell trains in: the variant's (or the hyperparameter file's), then
    the grid env's; a column's are put over them."""
    if cell.method.variant:
        from sb3_crowdnav.training.schedule import VARIANTS

        base = dict(VARIANTS[cell.method.variant].env_kwargs)
    else:
        from sb3_crowdnav.training.hyperparams import load_hyperparams, prepare

        hp = load_hyperparams(str(cell.method.hyperparams), str(cell.method.env))
        base = prepare(str(cell.method.algo), hp)["env_kwargs"]
    return {**base, **cell.env_kwargs}


def env_id(cell: Cell) -> str:
    if cell.method.variant:
        from sb3_crowdnav.training.schedule import VARIANTS

        return VARIANTS[cell.method.variant].env_id
    return str(cell.method.env)


def eval_argv(cell: Cell, grid: Grid, column: str, threads: int = 1) -> list[str]:
    """The ``sb3-crowdnav evaluate`` command of the cell's model in ``column``: in ``evaluate.env`` with the column's
    keyword arguments, else in the cell's training env with the column's put over its world's."""
    if grid.eval_env is not None:
        env, kwargs = grid.eval_env, dict(grid.columns[column])
    else:
        env, kwargs = env_id(cell), {**world_kwargs(cell), **grid.columns[column]}
    return ["evaluate", "--policy", str(cell.model_path), "--env", env, "--episodes", str(grid.episodes),
            "--seed-offset", str(grid.seed_offset), "--out", str(cell.eval_folder(column)), "--threads", str(threads),
            "--no-progress", *(["--env-kwargs", repr(kwargs)] if kwargs else []),
            *(["--allow-env-mismatch"] if grid.allow_env_mismatch else [])]


def parse_command(argv: list[str]) -> argparse.Namespace:
    """A cell's command parsed by the command line's own parser (:class:`UsageError` on a bad value)."""
    from sb3_crowdnav.cli import build_parser

    return build_parser(RaisingParser).parse_args(argv)


def identity(cell: Cell) -> dict[str, Any]:
    """What ``cell.json`` records: the training run's settings (its threads aside), compared on every rerun."""
    argv = cell.train_argv()
    return {"cell": cell.name, "train": argv[:argv.index("--out")]}


def eval_done(cell: Cell, grid: Grid, column: str) -> bool:
    """The cell's model has been evaluated in ``column`` as the grid says (episodes, seeds, env, model)."""
    folder = cell.eval_folder(column)
    try:
        meta = json.loads((folder / "meta.json").read_text())
    except (OSError, ValueError):
        return False
    args = parse_command(eval_argv(cell, grid, column))
    from sb3_crowdnav.cli.common import env_kwargs_from_args

    return ((folder / "episodes.csv").is_file() and meta.get("episodes") == grid.episodes
            and meta.get("seeds", [None])[0] == grid.seed_offset and meta.get("env") == args.env
            and plain(meta.get("env_kwargs")) == plain(env_kwargs_from_args(args))
            and str(cell.model_path) in (meta.get("policies") or {}).values())


def trained(cell: Cell) -> bool:
    """The cell's training run has finished (what ``train`` leaves at its end)."""
    folder = cell.train_folder
    if cell.method.variant:
        progress = _read(folder / "progress.json") or {}
        return bool(progress.get("finished")) and (folder / "final.zip").is_file() and cell.model_path.is_file()
    return "wall_time_s" in (_read(folder / "config.json") or {}) and cell.model_path.is_file()


def _read(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def cell_state(cell: Cell, grid: Grid) -> tuple[str, str]:
    """``(state, detail)`` of a cell from its folder: ``todo`` (nothing yet), ``partial`` (started, or trained and
    not every column evaluated) or ``done``; :class:`UsageError` when the folder holds a run of other settings."""
    recorded = _read(cell.folder / "cell.json")
    if recorded is not None and recorded != plain(identity(cell)):
        raise UsageError(f"{cell.folder} holds a run started with other settings ({' '.join(recorded.get('train', []))}); "
                         "the grid now says otherwise: remove the folder or give another --out")
    started = cell.train_folder.is_dir() and any(cell.train_folder.iterdir())
    if recorded is None and not started:
        return "todo", ""
    if not trained(cell):
        return "partial", _training_detail(cell)
    missing = [column for column in grid.columns if not eval_done(cell, grid, column)]
    if missing:
        return "partial", f"trained; to evaluate: {', '.join(missing)}"
    return "done", ""


def _training_detail(cell: Cell) -> str:
    folder = cell.train_folder
    if cell.method.hyperparams:
        progress = _read(folder / "progress.json") or {}
        if progress.get("checkpoint"):
            return f"resumes at {progress.get('timesteps')} env steps of {(progress.get('run') or {}).get('timesteps')}"
        return "started; training starts over"
    from sb3_crowdnav.training.run_folder import latest_checkpoint

    latest = latest_checkpoint(folder) if folder.is_dir() else None
    total = (_read(folder / "config.json") or {}).get("rl_episodes")
    if latest is not None:
        return f"resumes at RL episode {latest[0]} of {total}"
    if (folder / "imitation.zip").is_file():
        return "imitation done; resumes with RL"
    return "started; imitation starts over"


__all__ = ["STATES", "TRAIN_FLAGS", "Cell", "Grid", "Method", "RaisingParser", "cell_state", "cells", "env_id",
           "eval_argv", "eval_done", "identity", "load_grid", "parse_command", "train_options", "trained", "world_kwargs"]
