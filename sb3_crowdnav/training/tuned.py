"""``sb3-crowdnav-zoo tuned``: the hyperparameter file an Optuna study of ``sb3-crowdnav-zoo train -optimize`` chose.

    sb3-crowdnav-zoo tuned --algo qrdqn --env CrowdNav-v0 -conf zoo_hyperparams/qrdqn.yml \\
        --storage sqlite:///tune.db --study-name qrdqn --out zoo_hyperparams/qrdqn.yml

``--storage`` is what rl-zoo3's takes: a database URL, or a path ending in ``.log``, an Optuna journal file (plain
text that a study can be carried in from machine to machine, :func:`open_storage`).

It takes the study's best trial, turns its sampled values into hyperparameters with rl-zoo3's converter (as
``rl_zoo3.train --trial-id`` does), puts them over the file the study started from (``policy_kwargs`` over its
``policy_kwargs``, as the trials ran them) and writes the result as ``--env``'s entry of ``--out`` (the file's other
envs' entries are kept as written), headed by comments that state what the choice
cost: the study's command, its trials (complete, pruned, failed) and their wall time, the env steps of a trial, the
evaluations that scored it and the best trial's score. The values come from the study's database and are written as
plain YAML (``policy_kwargs`` as the ``dict(...)`` string the package's files use, read back by ``safe_eval``).
"""

from __future__ import annotations

import argparse
import datetime
import shlex
import sys
import textwrap
from pathlib import Path
from typing import Any

import yaml

# the user attribute of the trial that ran the file's own settings, unsampled (sb3-crowdnav-zoo train --file-trial)
FILE_TRIAL = "file_settings"
TRIAL_MINUTES = "pruned_after_minutes"  # the user attribute of a trial that --trial-minutes stopped (its minutes)
FLAGS = {"n_timesteps": ("-n", "--n-timesteps"), "n_evaluations": ("--n-evaluations",),
         "eval_episodes": ("--eval-episodes",), "n_trials": ("--n-trials",), "max_total_trials": ("--max-total-trials",)}


def _literal(value: Any) -> str:
    """``value`` (plain data, ``torch.nn`` classes) as the Python-looking text of a hyperparameter file."""
    if isinstance(value, dict):
        return "dict(" + ", ".join(f"{k}={_literal(v)}" for k, v in value.items()) + ")"
    if isinstance(value, (list, tuple)):
        items = ", ".join(_literal(v) for v in value)
        return f"[{items}]" if isinstance(value, list) else f"({items}{',' if len(value) == 1 else ''})"
    if isinstance(value, type):
        import torch.nn as nn

        if getattr(nn, value.__name__, None) is value:
            return f"nn.{value.__name__}"
        raise ValueError(f"cannot write the class {value.__module__}.{value.__qualname__} into a hyperparameter file")
    if value is None or isinstance(value, (bool, int, float, str)):
        return repr(value)
    raise ValueError(f"cannot write {type(value).__name__} {value!r} into a hyperparameter file")


def open_storage(storage: str, create: bool = False) -> Any:
    """The Optuna storage ``storage`` names, by rl-zoo3's rule: a path ending in ``.log`` is a journal file
    (``JournalStorage``: one JSON line per change of the study, appended), anything else a database URL. A journal
    file that does not exist is refused, or with ``create`` started (its folder too), as rl-zoo3 starts one."""
    import optuna

    if not storage.endswith(".log"):
        return storage
    if create:
        Path(storage).parent.mkdir(parents=True, exist_ok=True)
    elif not Path(storage).is_file():
        raise ValueError(f"--storage: no journal file {storage!r}")
    return optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(storage))


def stored_study(storage: str, study_name: str) -> Any:
    """Study ``study_name`` of ``storage``, or None when the storage (a journal file that does not exist) or the
    study is not there yet."""
    import optuna

    if storage.endswith(".log") and not Path(storage).is_file():
        return None
    try:
        return optuna.load_study(study_name=study_name, storage=open_storage(storage))
    except KeyError:  # (Optuna's answer for a study the storage does not hold)
        return None


def stored_trial_count(storage: str, study_name: str) -> int:
    """The number of trials, in any state, of study ``study_name`` in ``storage`` (0 for a study, or a journal file,
    that does not exist yet)."""
    study = stored_study(storage, study_name)
    return 0 if study is None else len(study.get_trials(deepcopy=False))


def fail_running_trials(storage: str, study_name: str) -> list[int]:
    """Mark the trials of study ``study_name`` that are still RUNNING as FAIL; their numbers. For a study whose
    tuning process was killed (a stopped machine leaves its trial RUNNING, and rl-zoo3's ``--max-total-trials``
    counts it as one to come): never while another worker tunes the same study. A study not yet in ``storage`` has
    none."""
    from optuna.trial import TrialState

    study = stored_study(storage, study_name)
    if study is None:
        return []
    running = study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
    for trial in running:
        study.tell(trial.number, state=TrialState.FAIL)
    return [t.number for t in running]


def enqueue_file_trial(storage: str, study_name: str) -> bool:
    """Queue a trial of study ``study_name`` that runs the file's own settings, nothing sampled (its user attribute
    :data:`FILE_TRIAL`; :mod:`sb3_crowdnav.training.zoo`'s sampler gives it no values), unless the study holds one
    that is waiting, running or finished (a failed one is queued again); whether one was queued. The study is created
    as rl-zoo3 creates it (maximize) when ``storage`` does not hold it yet; a journal file (``.log``) and its folder
    too."""
    import optuna
    from optuna.trial import TrialState

    study = optuna.create_study(storage=open_storage(storage, create=True), study_name=study_name, load_if_exists=True,
                                direction="maximize")
    if any(t.user_attrs.get(FILE_TRIAL) and t.state != TrialState.FAIL for t in study.get_trials(deepcopy=False)):
        return False
    study.enqueue_trial({}, user_attrs={FILE_TRIAL: True})
    return True


def study_budget(study: Any) -> dict[str, Any]:
    """The trials of ``study`` by state, the settings its recorded command gave (None where not given) and the wall
    time of its complete and pruned trials (``trial_hours``: start to end of each, summed). Failed trials are not
    summed: one killed with its machine ends when ``--fail-running`` marks it, hours after it stopped."""
    from optuna.trial import TrialState

    trials = study.get_trials(deepcopy=False)
    states = {name: sum(t.state == state for t in trials)
              for name, state in (("complete", TrialState.COMPLETE), ("pruned", TrialState.PRUNED),
                                  ("failed", TrialState.FAIL))}
    command = study.user_attrs.get("command")
    try:
        words = shlex.split(command) if isinstance(command, str) else []
    except ValueError:  # (unbalanced quotes in a recorded command: its flags are not read)
        words = []
    given = {key: next((words[i + 1] for i, w in enumerate(words[:-1]) if w in flags), None)
             for key, flags in FLAGS.items()}
    hours = sum((t.datetime_complete - t.datetime_start).total_seconds() for t in trials
                if t.datetime_start and t.datetime_complete and t.state in (TrialState.COMPLETE, TrialState.PRUNED)) / 3600
    stopped = sorted({t.user_attrs[TRIAL_MINUTES] for t in trials if TRIAL_MINUTES in t.user_attrs})
    timed_out = sum(TRIAL_MINUTES in t.user_attrs for t in trials)
    return {**states, **given, "command": command, "trial_hours": hours, "timed_out": timed_out,
            "trial_minutes": stopped}


def tuned_hyperparams(algo: str, base: dict[str, Any], storage: str, study_name: str) -> tuple[dict[str, Any], Any]:
    """``base`` (a file's entry, as read) with the best trial's hyperparameters over it; and the study. The converter
    is rl-zoo3's for ``algo``, as :func:`sb3_crowdnav.training.zoo.register` leaves the table (``sb3-crowdnav-zoo``
    registers first; a script calls it before)."""
    import optuna
    from rl_zoo3 import hyperparams_opt

    from sb3_crowdnav.training.hyperparams import policy_kwargs_names, safe_eval

    if algo not in hyperparams_opt.HYPERPARAMS_CONVERTER:
        raise ValueError(f"--algo: rl-zoo3 has no converter for {algo!r}; "
                         f"known: {sorted(hyperparams_opt.HYPERPARAMS_CONVERTER)}")
    try:
        study = optuna.load_study(study_name=study_name, storage=open_storage(storage))
    except KeyError:
        raise ValueError(f"--study-name: no study {study_name!r} in {storage}") from None
    if not study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)):
        raise ValueError(f"--study-name: study {study_name!r} has no complete trial yet")
    if study.best_trial.user_attrs.get(FILE_TRIAL):  # the file's own settings scored best: nothing to put over them
        best: dict[str, Any] = {}
    else:
        best = hyperparams_opt.HYPERPARAMS_CONVERTER[algo](dict(study.best_trial.params))
    entry = dict(base)
    if "policy_kwargs" in best:
        own = entry.get("policy_kwargs") or {}
        own = safe_eval(own, policy_kwargs_names()) if isinstance(own, str) else dict(own)
        entry["policy_kwargs"] = _literal({**own, **best.pop("policy_kwargs")})
    for key, value in best.items():
        entry[key] = value if value is None or isinstance(value, (bool, int, float, str)) else _literal(value)
    return entry, study


def _sections(text: str) -> list[tuple[str | None, str]]:
    """``text`` of a hyperparameter file cut into ``(key, text)`` parts, in order: each top-level key's entry with the
    comment and blank lines at the left margin right above it (a last part of key None holds trailing comments)."""
    parts: list[tuple[str | None, str]] = []
    pending = ""  # left-margin comments and blank lines: they head the entry that follows
    for line in text.splitlines(keepends=True):
        if not line.strip() or line.startswith("#"):
            pending += line
        elif not line[0].isspace():  # a top-level key
            parts.append((line.split(":", 1)[0].strip().strip("'\""), pending + line))
            pending = ""
        elif parts:  # an entry's indented line
            parts[-1] = (parts[-1][0], parts[-1][1] + pending + line)
            pending = ""
        else:
            pending += line
    if pending:
        parts.append((None, pending))
    return parts


def replace_section(text: str, env_id: str, section: str) -> str:
    """``text`` (a hyperparameter file, possibly empty) with ``env_id``'s entry and the comments above it replaced by
    ``section``, every other entry kept as written (a file holds one entry per env, and a study tunes one of them); a
    file without that entry gets ``section`` appended."""
    parts = _sections(text)
    if not any(key == env_id for key, _ in parts):
        joined = "".join(part for _, part in parts)
        return joined + ("\n" if joined and not joined.endswith("\n") else "") + section
    return "".join(section if key == env_id else part for key, part in parts)


def header(algo: str, env_id: str, conf: str, study_name: str, study: Any, argv: list[str]) -> str:
    budget = study_budget(study)
    per_trial = f"{budget['n_timesteps']} env steps" if budget["n_timesteps"] else "env steps not recorded"
    episodes = budget["eval_episodes"] or "rl-zoo3's default number of"
    scored = (f"scored on {episodes} validation episodes (seeds 2,000,000 + i) after each of "
              f"{budget['n_evaluations'] or 'its'} evaluations")
    lines = [
        f"{algo} on {env_id}, tuned with Optuna through rl-zoo3 (sb3-crowdnav-zoo train -optimize) from {conf}:",
        f"the best of {budget['complete']} complete trials of study {study_name!r} ({budget['pruned']} pruned"
        + (f", {budget['timed_out']} of them still training after "
           f"{' / '.join(f'{m:g}' for m in budget['trial_minutes'])} min (--trial-minutes)" if budget["timed_out"] else "")
        + f", {budget['failed']} failed), each trial {per_trial}, {scored}; the complete and pruned trials' wall "
        f"time {budget['trial_hours']:.1f} h in all;",
        f"best trial #{study.best_trial.number}, mean episode reward {study.best_trial.value:.4f}"
        + (": the file's own settings (--file-trial), which no sampled trial beat; the values below are the file's."
           if study.best_trial.user_attrs.get(FILE_TRIAL) else "."),
        *[f"The file's own settings (--file-trial, trial #{t.number}) scored {t.value:.4f}." for t in study.trials
          if t.user_attrs.get(FILE_TRIAL) and t.value is not None and t.number != study.best_trial.number],
        f"The study's command: {budget['command'] or 'not recorded'}",
        f"Written {datetime.date.today().isoformat()} by: sb3-crowdnav-zoo tuned {shlex.join(argv)}",
    ]
    return "".join(f"# {part}\n" for line in lines
                   for part in textwrap.wrap(line, 116, break_long_words=False, break_on_hyphens=False))


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog="sb3-crowdnav-zoo tuned", description=__doc__.splitlines()[0])
    parser.add_argument("--algo", required=True)
    parser.add_argument("--env", required=True, help="the env id: the file's top-level key")
    parser.add_argument("-conf", "--conf-file", dest="conf", required=True, help="the YAML file the study started from")
    parser.add_argument("--storage", required=True, help="the study's Optuna storage: a database URL (sqlite:///tune.db) or a "
                        "journal file (PATH.log)")
    parser.add_argument("--study-name", required=True)
    parser.add_argument("--out", required=True, help="the tuned YAML file to write (may be -conf itself)")
    args = parser.parse_args(argv)
    if not Path(args.out).resolve().parent.is_dir():  # refused before the study is read
        parser.exit(2, f"sb3-crowdnav-zoo tuned: error: --out {args.out!r}: its folder does not exist\n")
    from sb3_crowdnav.training.hyperparams import load_hyperparams

    try:
        base = load_hyperparams(args.conf, args.env)
        entry, study = tuned_hyperparams(args.algo, base, args.storage, args.study_name)
    except (ValueError, FileNotFoundError) as exc:
        parser.exit(2, f"sb3-crowdnav-zoo tuned: error: {' '.join(str(exc).split())}\n")
    section = header(args.algo, args.env, args.conf, args.study_name, study, argv)
    section += yaml.safe_dump({args.env: entry}, sort_keys=False, width=120)
    out = Path(args.out)
    out.write_text(replace_section(out.read_text() if out.is_file() else "", args.env, section))
    print(f"wrote {args.out}: trial #{study.best_trial.number} of study {args.study_name!r} "
          f"(mean episode reward {study.best_trial.value:.4f})")


__all__ = ["FILE_TRIAL", "enqueue_file_trial", "header", "main", "replace_section", "study_budget",
           "tuned_hyperparams"]
