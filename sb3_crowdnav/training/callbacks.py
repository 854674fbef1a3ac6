"""The paper schedule's callback (stop after an episode budget, checkpoint, validate and keep the best model) and a
wall-time budget for hyperparameter-file runs."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sb3_crowdnav.evaluation import run_episodes, summarize
from sb3_crowdnav.sim.validation import check_choice, check_positive
from sb3_crowdnav.training.run_folder import (
    RunClock,
    SignalStop,
    atomic_write,
    buffer_path,
    checkpoint_path,
    kill_point,
    read_json,
    remove_stale,
    sha256,
    write_json,
)

VALIDATION_SEED_OFFSET = 2_000_000  # greedy validation episodes: disjoint from training and from the test seeds
SELECT_BY = ("success", "return")


def validate_file(load: Callable[[], Any], episodes: int, env_kwargs: dict[str, Any], env_id: str) -> dict[str, Any]:
    """The validation row of the model ``load()`` returns: ``episodes`` greedy episodes from
    :data:`VALIDATION_SEED_OFFSET` (the same episodes for every checkpoint of every run). The global random states
    (Python's, NumPy's, torch's) are given back afterwards, so that a run trains the same with or without it."""
    import random

    import numpy as np
    import torch

    start, py_state, np_state = time.time(), random.getstate(), np.random.get_state()
    try:
        with torch.random.fork_rng(devices=[]):
            s = summarize(run_episodes(load(), episodes, env_kwargs, env_id=env_id, seed_offset=VALIDATION_SEED_OFFSET))
    finally:
        random.setstate(py_state)
        np.random.set_state(np_state)
    return {"wall": time.time(), "eval_seconds": time.time() - start,
            "success": s.success_rate, "collision": s.collision_rate, "timeout": s.timeout_rate,
            "time": s.navigation_time, "gap": s.min_separation, "return": s.discounted_return,
            "comfort_time": s.comfort_zone_time, "heading": s.heading_change, "sharp_turns": s.sharp_turns}


def validation_rows(out: Path) -> list[dict[str, Any]]:
    """The rows of ``OUT/eval_curve.jsonl``, one per validated checkpoint (none without the file)."""
    curve = Path(out) / "eval_curve.jsonl"
    return [json.loads(line) for line in curve.read_text().splitlines()] if curve.exists() else []


def record_validation(out: Path, key: str, value: int, compute: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """The row of ``OUT/eval_curve.jsonl`` whose ``key`` is ``value`` (``episodes`` of a paper-schedule run,
    ``timesteps`` of a hyperparameter-file run): the one a resumed run wrote before, else ``compute()``'s, appended."""
    curve, rows = Path(out) / "eval_curve.jsonl", validation_rows(out)
    row = next((r for r in rows if r.get(key) == value), None)
    if row is None:
        row = {key: value, **compute()}
        rows.append(row)
        atomic_write(curve, lambda tmp: tmp.write_text("".join(json.dumps(r) + "\n" for r in rows)))
    return row


def selection_score(row: dict[str, Any], select_by: str = "success") -> list[float]:
    """What ranks a validation ``row`` (higher is better): its success, then minus its navigation time (``"success"``),
    or its mean discounted return (``"return"``)."""
    check_choice("select_by", select_by, SELECT_BY)
    if select_by == "return":
        return [row["return"]]
    return [row["success"], -row["time"] if row["time"] == row["time"] else 0.0]


def update_best(out: Path, row: dict[str, Any], source: Path, select_by: str = "success") -> bool:
    """Copy ``source`` (the model validated in ``row``) to ``OUT/best.zip`` and ``row`` to ``OUT/best.json`` when it
    beats the best so far: highest success, then shortest navigation time (``select_by="success"``), or highest
    mean discounted return (``"return"``). Returns whether it did."""
    score = selection_score(row, select_by)
    best = read_json(Path(out) / "best.json")
    if best is not None and best.get("select_by", "success") == select_by and score <= list(best["score"]):
        return False
    atomic_write(Path(out) / "best.zip", lambda tmp: shutil.copyfile(source, tmp))
    kill_point("best_zip")
    write_json(Path(out) / "best.json", {"score": score, "select_by": select_by, "sha256": sha256(Path(out) / "best.zip"),
                                         **row})
    kill_point("best_json")
    return True


def set_finished_lookahead(policy: Any, depth: int, width: int | None, cap_values: bool | None) -> None:
    """``policy`` (a ``ValueLookaheadPolicy``) searching as a finished run's files do: ``depth`` and ``width``, and the
    cap of V when ``cap_values`` is not None (None keeps the policy's)."""
    policy.set_planning(depth, width)
    if cap_values is not None:
        policy.set_cap_values(cap_values)


def finish_depth(out: Path, depth: int, log: Callable[[str], Any] = print, width: int | None = None,
                 cap_values: bool | None = None) -> None:
    """Give a finished run's ``OUT/final.zip`` and ``OUT/best.zip`` the lookahead ``depth`` (and ``width``) they act
    with (``ValueLookaheadPolicy.planning_depth`` / ``planning_width``; ``best.json`` records the new file's hash),
    and, when ``cap_values`` is not None, that cap of V (``ValueLookaheadPolicy.cap_values``). Training, its
    checkpoints and validations search one step: a deeper search costs several times a decision. Files acting so
    already are left as they are, so a rerun changes nothing."""
    from sb3_crowdnav.apg_value import APGValue

    for name in ("final.zip", "best.zip"):
        path = Path(out) / name
        if not path.exists():
            continue
        model = APGValue.load(path)
        cap = model.policy.cap_values if cap_values is None else cap_values
        if (model.policy.planning_depth, model.policy.planning_width, model.policy.cap_values) == (depth, width, cap):
            continue
        set_finished_lookahead(model.policy, depth, width, cap)
        atomic_write(path, model.save)
        if name == "best.zip" and (best := read_json(Path(out) / "best.json")) is not None:
            write_json(Path(out) / "best.json", {**best, "sha256": sha256(path), "planning_depth": depth,
                                                 **({"planning_width": width} if width is not None else {}),
                                                 **({"cap_values": cap} if cap is not None else {})})
        log(f"{path} acts with a lookahead of depth {depth}" + (f", width {width}" if width is not None else "")
            + (f", V capped: {cap}" if cap is not None else ""))


class EpisodeCheckpoint(BaseCallback):
    """Stop after ``max_episodes`` RL episodes in total; every ``every`` episodes checkpoint and validate.

    Validation: ``eval_episodes`` greedy episodes on fixed seeds (the ε-greedy rollout rates of the
    training log understate the greedy policy while ε is large) of the checkpoint's saved file (the
    model that ``best.zip`` then is; while training overlaps, the live model acts with a copy of V one
    training call stale), logged as ``eval/*`` and appended
    to ``OUT/eval_curve.jsonl``; every checkpoint is kept as ``OUT/checkpoint_<episodes>.zip``
    and the best one so far as ``OUT/best.zip``: highest success, then shortest navigation time
    (``select_by="success"``), or highest mean discounted return under the variant's own reward
    (``select_by="return"``, which counts the comfort and angular penalties of APG_CRL/APG_CARL).
    Validation episodes run with ``env_kwargs`` (the training reward and crowd). With a ``clock``, ``progress.json``
    also records the wall time the run has used (``wall_time_s``, over all its segments, validations included).

    SIGTERM and SIGINT stop training at the end of the current step (``stopped_by`` holds the signal);
    the caller then writes the checkpoint. A second signal acts as usual.

    Why not SB3's ``CheckpointCallback`` and ``EvalCallback``: the paper's schedule counts episodes,
    not env steps (an episode is 20-100 steps, so a step period drifts through the ε schedule), a
    checkpoint here is a consistent set (model, replay buffer, progress) written to temporary names
    first, and validation must run the package's episode runner on fixed seeds so that every
    checkpoint of every run is scored on the same episodes.
    """

    def __init__(self, out: Path, max_episodes: int, every: int, eval_episodes: int = 100,
                 select_by: str = "success", env_kwargs: dict[str, Any] | None = None,
                 env_id: str = "CrowdNav-v0", clock: RunClock | None = None) -> None:
        super().__init__()
        self.clock = clock  # the run's wall time, written to progress.json with every checkpoint when given
        check_choice("select_by", select_by, SELECT_BY)
        self.out, self.max_episodes, self.every, self.eval_episodes = Path(out), max_episodes, every, eval_episodes
        self.select_by, self.env_kwargs, self.env_id = select_by, dict(env_kwargs or {}), env_id
        self._last = -1
        self.validate_first = False  # validate the resumed checkpoint before training on (a kill skipped it)
        self.signals = SignalStop()  # stopped_by: the signal that stopped training early, if any

    def validate(self) -> None:
        """Validate the checkpoint of the current episode count (once: a row an interrupted attempt left is reused),
        update the best model, and mark the checkpoint validated in ``progress.json``."""
        model, n = self.model, self.model.episodes_done
        # the checkpoint's file, as best.zip copies it: inside learn() with overlap_training the model itself acts
        # with a copy of V one training call older than the V it saved
        row = record_validation(self.out, "episodes", n, lambda: {
            "timesteps": model.num_timesteps,
            **validate_file(lambda: type(model).load(checkpoint_path(self.out, n)), self.eval_episodes,
                            self.env_kwargs, self.env_id)})
        kill_point("eval")
        for key in ("success", "collision", "timeout", "time", "gap", "return"):
            model.logger.record(f"eval/{key}", row[key])
        update_best(self.out, row, checkpoint_path(self.out, n), self.select_by)
        progress = read_json(self.out / "progress.json") or {}
        progress["validated"] = sorted({*progress.get("validated", []), n})
        write_json(self.out / "progress.json", progress)
        print(f"validation after {n} RL episodes: success {row['success']:.2f}, "
              f"collision {row['collision']:.2f}, time {row['time']:.2f} s", flush=True)

    def save(self) -> None:
        """Write ``replay_buffer_<N>.npz`` then ``checkpoint_<N>.zip`` (each atomically), then ``progress.json``;
        remove older buffers (see :mod:`sb3_crowdnav.training.run_folder`)."""
        model, n = self.model, self.model.episodes_done
        atomic_write(buffer_path(self.out, n), model.save_replay_buffer)
        kill_point("buffer")
        atomic_write(checkpoint_path(self.out, n), model.save)
        kill_point("checkpoint")
        progress = read_json(self.out / "progress.json") or {}
        progress.update(episodes=n, timesteps=model.num_timesteps, time=time.time(),
                        checkpoint=checkpoint_path(self.out, n).name)
        if self.clock is not None:
            progress.update(wall_time_s=round(self.clock.total(), 1))
        write_json(self.out / "progress.json", progress)
        kill_point("progress")
        remove_stale(self.out, keep=n)

    @property
    def stopped_by(self) -> int | None:
        """The signal that stopped training early (SIGTERM or SIGINT), or None."""
        return self.signals.stopped_by

    def _on_training_start(self) -> None:
        self._last = self.model.episodes_done  # a resumed run does not checkpoint and validate its first episode count again
        self.signals.install()
        if self.validate_first and self.eval_episodes:
            self.validate_first = False
            self.validate()

    def _on_training_end(self) -> None:
        self.signals.restore()

    def _on_step(self) -> bool:
        if self.stopped_by is not None:
            return False
        episodes = self.model.episodes_done
        if episodes != self._last and episodes > 0 and episodes % self.every == 0:
            self._last = episodes
            self.save()
            if self.eval_episodes:
                self.validate()
        return episodes < self.max_episodes


class WallTimeBudget(BaseCallback):
    """Stop ``learn`` at the first env step after ``seconds`` of wall time since ``start`` (a ``time.perf_counter()``
    reading, so that an imitation phase before ``learn`` counts): a baseline gets the same wall time as the run it
    is compared with. ``stopped`` says whether the budget, not the timestep total, ended training."""

    def __init__(self, seconds: float, start: float | None = None):
        super().__init__()
        check_positive("seconds", seconds, " [s]")
        self.seconds, self.start, self.stopped = float(seconds), start, False

    def _on_training_start(self) -> None:
        if self.start is None:
            self.start = time.perf_counter()

    def _on_step(self) -> bool:
        self.stopped = time.perf_counter() - self.start >= self.seconds
        return not self.stopped
