"""A value ensemble trained by one command: ``sb3-crowdnav train --ensemble K --ensemble-checkpoints C``
(``ScheduleConfig(ensemble=K, ensemble_checkpoints=C)``).

The run folder holds K member runs, ``OUT/member_0`` ... ``OUT/member_{K-1}``, each the variant's schedule with its
own seed, ``seed + 1000 k`` (its training episodes and its ε draws). Member 0 imitates the ORCA robot; the others
start their RL from its ``imitation.zip`` and its demonstrations, so the imitation is paid once (every member starts
from ``from_imitation`` when one is given). ``rl_episodes`` and the other schedule settings are each member's. Each
member gives its C best checkpoints by validation (the ranking of ``best.zip``: ``select_by``; C = 1: its
``best.zip``, or its ``final.zip`` without validation); then they become one model whose V is the mean of their
value networks (:func:`~sb3_crowdnav.training.averaging.ensemble_models`) acting with the run's ``planning_depth``,
validated on the same validation episodes and saved as ``OUT/best.zip``; the members' ``final.zip`` likewise become
``OUT/final.zip``. Nothing is chosen by hand. Checkpoints of one run err in fewer common states than one network
alone, those of independent runs in fewer still (docs/research_log.md).

``OUT/ensemble.json`` lists the members (folder, seed, the checkpoints taken and their validation rows) and the
ensemble's validation; ``OUT/progress.json`` sums the members' RL episodes, env steps and wall time (the imitation
once) and adds the assembly's. Run the same command again to resume: a finished member is not trained again, a
member cut short resumes from its last checkpoint, and a finished ensemble is left as it is.
"""

from __future__ import annotations

import dataclasses
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.training.averaging import ensemble_models
from sb3_crowdnav.training.callbacks import selection_score, set_finished_lookahead, validate_file, validation_rows
from sb3_crowdnav.training.run_folder import atomic_write, checkpoint_path, read_json, sha256, write_json

MEMBER_SEED_STRIDE = 1000  # member k trains with seed + 1000 k: its envs (seed + i) never meet another member's


def member_config(config: Any, k: int) -> Any:
    """The schedule of member ``k`` of ``config``'s ensemble: the same settings, one plain run, its own seed."""
    return dataclasses.replace(config, ensemble=1, ensemble_checkpoints=1, seed=config.seed + MEMBER_SEED_STRIDE * k)


def chosen_checkpoints(folder: Path, count: int, select_by: str) -> list[tuple[Path, dict[str, Any] | None]]:
    """The ``count`` best validated checkpoints of the run in ``folder`` with their validation rows, best first (ties:
    the later checkpoint); ``count`` = 1: its ``best.zip`` (``final.zip`` without validation)."""
    if count == 1:
        best = folder / "best.zip"
        return [(best, read_json(folder / "best.json"))] if best.exists() else [(folder / "final.zip", None)]
    rows = [r for r in validation_rows(folder) if checkpoint_path(folder, r["episodes"]).exists()]
    if len(rows) < count:
        raise ValueError(f"{folder} has {len(rows)} validated checkpoints, {count} are to be taken")
    rows.sort(key=lambda r: (selection_score(r, select_by), r["episodes"]), reverse=True)
    return [(checkpoint_path(folder, r["episodes"]), r) for r in rows[:count]]


def _at_depth(model: APGValue, config: Any) -> APGValue:
    """``model`` acting with the run's ``planning_depth`` (checkpoints, which the ensemble may take, search one step)."""
    set_finished_lookahead(model.policy, config.planning_depth, config.planning_width, config.cap_values)
    return model


def member_folders(out: Path, count: int) -> list[Path]:
    return [Path(out) / f"member_{k}" for k in range(count)]


def train_ensemble(out: Path, config: Any, from_imitation: str | Path | None, log: Any,
                   train_member: Callable[[Path, Any, str | Path | None], Any]) -> tuple[APGValue, int | None, float]:
    """Train (or resume) the members of ``config.ensemble`` in ``out`` by ``train_member(folder, member_config,
    from_imitation)`` (a :class:`~sb3_crowdnav.training.schedule.ScheduleResult`) and assemble them (see the module
    docstring); the ensemble, None and this call's wall time [s], or the model and signal of the member a signal
    stopped."""
    record = read_json(out / "ensemble.json")
    if record is not None and (out / "best.zip").exists() and sha256(out / "best.zip") == record.get("sha256"):
        log(f"{out} holds its finished ensemble of {len(record['members'])} runs: nothing to do")
        return APGValue.load(out / "best.zip"), None, 0.0
    start, folders = time.time(), member_folders(out, config.ensemble)
    for k, folder in enumerate(folders):
        # (a given post-imitation model starts every member; otherwise member 0's imitation does)
        imitation = from_imitation if from_imitation is not None or k == 0 else folders[0] / "imitation.zip"
        log(f"member {k} of {config.ensemble} in {folder}")
        result = train_member(folder, member_config(config, k), imitation)
        if result.stopped_by is not None:
            return result.model, result.stopped_by, time.time() - start
    began = time.time()
    chosen = [chosen_checkpoints(folder, config.ensemble_checkpoints, config.select_by) for folder in folders]
    atomic_write(out / "best.zip", _at_depth(ensemble_models([p for taken in chosen for p, _ in taken]), config).save)
    finals = [folder / "final.zip" for folder in folders]  # (a finished member's final.zip has the depth already)
    atomic_write(out / "final.zip", _at_depth(ensemble_models(finals), config).save if len(finals) > 1 else
                 lambda tmp: shutil.copyfile(finals[0], tmp))
    validation = validate_file(lambda: APGValue.load(out / "best.zip"), config.eval_episodes,
                               config.training_env_kwargs, config.spec.env_id) if config.eval_episodes else None
    members = [{"folder": folder.name, "seed": member_config(config, k).seed,
                "checkpoints": [{"model": path.name, "validation": row} for path, row in taken]}
               for k, (folder, taken) in enumerate(zip(folders, chosen, strict=True))]
    runs = [read_json(folder / "progress.json") or {} for folder in folders]
    write_json(out / "ensemble.json", {"members": members, "validation": validation, "sha256": sha256(out / "best.zip")})
    write_json(out / "progress.json", {
        "members": len(folders), "episodes": sum(r.get("episodes", 0) for r in runs),
        "timesteps": sum(r.get("timesteps", 0) for r in runs),
        "wall_time_s": round(sum(r.get("wall_time_s", 0.0) for r in runs) + time.time() - began, 1),
        "finished": True})
    if validation is not None:
        taken = [c["validation"] for m in members for c in m["checkpoints"]]
        log(f"ensemble of {len(taken)} networks from {len(folders)} runs: validation success "
            f"{validation['success']:.3f}, collision {validation['collision']:.3f} (each alone: " + ", ".join(
                f"{row['success']:.3f}" if row else "-" for row in taken) + ")")
    return APGValue.load(out / "best.zip"), None, time.time() - start
