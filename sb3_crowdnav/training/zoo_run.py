"""Checkpoints and resume of a hyperparameter-file run (``sb3-crowdnav train --hyperparams FILE --checkpoint-freq N``).

A run's folder holds, beside the final ``<algo>.zip``:

- ``checkpoints/<algo>_<steps>_steps.zip``: the model every ``checkpoint_freq`` env steps (and right after the
  imitation phase, at 0 steps), saved with its spaces as plain JSON so that it loads without unpickling;
- ``checkpoints/<algo>_replay_buffer_<steps>_steps.npz``: an off-policy algorithm's replay buffer beside the newest
  checkpoint, as plain arrays (:func:`~sb3_crowdnav.apg_value.buffers.save_buffer`; older ones are removed);
- ``progress.json``: what the run is (algorithm, env, seed, hyperparameters, env keywords, the timesteps and wall
  time asked) and how far it got (timesteps, wall time used over all its segments, the newest checkpoint,
  ``finished``);
- ``run.lock`` while a process trains in it (:class:`~sb3_crowdnav.training.run_folder.RunLock`).

Running the same command again resumes from the newest checkpoint: SB3's ``learn(reset_num_timesteps=False)`` for
the timesteps left, the replay buffer reloaded, the learning-rate and exploration schedules where they were, and a
wall-time budget counting the time already used. A finished run is not trained again. The envs restart from new
episodes, so a resumed run is a valid run, not the same run to the bit as one never stopped: the replay buffer's last
transition of each env is marked truncated (SB3's ``timeouts``), so that an n-step return never runs from the
interrupted episode into the first transitions of the resumed one.

SIGTERM or SIGINT during ``learn`` stops the run at the end of the current env step and writes a checkpoint of that
step first, then :class:`TrainingInterrupted` is raised (the CLI exits with 128 + the signal); a second signal acts
as usual. A stopped off-policy run keeps every transition but the one of that step and skips the gradient steps of
the rollout it cut short; a stopped on-policy run (PPO) loses its rollout so far, whose steps are counted. Its
checkpoint is validated when the run resumes. A different command in
the same folder (another algorithm, env, seed, hyperparameters or budget) is refused. DQfD's demonstrations, which sit
beside its replay buffer, are collected again on resume from the same seeds (the ORCA robot's episodes are the same).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sb3_crowdnav.training.run_folder import RunClock, SignalStop, atomic_write, kill_point, read_json, write_json

PROGRESS = "progress.json"
CHECKPOINTS = "checkpoints"


def checkpoint_file(out: Path, algo: str, steps: int) -> Path:
    return out / CHECKPOINTS / f"{algo}_{steps}_steps.zip"


def buffer_file(out: Path, algo: str, steps: int) -> Path:
    return out / CHECKPOINTS / f"{algo}_replay_buffer_{steps}_steps.npz"


def latest_checkpoint(out: Path, algo: str, off_policy: bool) -> int | None:
    """The steps of the newest complete checkpoint (an off-policy one with its replay buffer), or None."""
    pattern = re.compile(rf"{re.escape(algo)}_(\d+)_steps\.zip")
    found = sorted((int(m.group(1)) for p in (out / CHECKPOINTS).glob("*.zip") if (m := pattern.fullmatch(p.name))),
                   reverse=True)
    return next((n for n in found if not off_policy or buffer_file(out, algo, n).is_file()), None)


def save_checkpoint(model: Any, out: Path, algo: str, clock: RunClock, identity: dict[str, Any],
                    validation: Validation | None = None) -> None:
    """Write the model (then an off-policy replay buffer) under temporary names, then ``progress.json``; remove
    older buffers; then validate the checkpoint with ``validation``, if given. A kill at any point leaves the previous
    checkpoint whole (a resumed run validates its checkpoint first, unless it was)."""
    from sb3_crowdnav.apg_value.buffers import save_buffer

    steps = int(model.num_timesteps)
    (out / CHECKPOINTS).mkdir(parents=True, exist_ok=True)
    buffer = getattr(model, "replay_buffer", None)
    if buffer is not None:
        atomic_write(buffer_file(out, algo, steps), lambda tmp: save_buffer(buffer, tmp))

    atomic_write(checkpoint_file(out, algo, steps), lambda tmp: save_model(model, tmp))
    write_json(out / PROGRESS, {"run": identity, "timesteps": steps, "wall_time_s": round(clock.total(), 1),
                                "checkpoint": checkpoint_file(out, algo, steps).name, "finished": False})
    for old in (out / CHECKPOINTS).glob(f"{algo}_replay_buffer_*_steps.npz"):
        if old != buffer_file(out, algo, steps):
            old.unlink(missing_ok=True)
    kill_point("zoo_checkpoint")
    if validation is not None:
        validation(steps, checkpoint_file(out, algo, steps))


class Validation:
    """Validate a hyperparameter-file run's checkpoints as a paper-schedule run's are: ``episodes`` greedy episodes
    from the validation seeds (:func:`~sb3_crowdnav.training.callbacks.validate_file`), one row per checkpoint in
    ``OUT/eval_curve.jsonl`` (keyed by ``timesteps``; a resumed run reuses the rows), and the best so far (highest
    success, then shortest time) copied to ``OUT/best.zip`` with its row in ``OUT/best.json``. The model is loaded from
    its file as ``sb3-crowdnav evaluate`` loads it (a MaskablePPO model with its wall masks)."""

    def __init__(self, out: Path, algo: str, episodes: int, env_id: str, env_kwargs: dict[str, Any]) -> None:
        self.out, self.algo, self.episodes, self.env_id, self.env_kwargs = Path(out), algo, episodes, env_id, env_kwargs

    def __call__(self, steps: int, path: Path) -> dict[str, Any]:
        from sb3_crowdnav.training.callbacks import record_validation, update_best, validate_file

        row = record_validation(self.out, "timesteps", steps, lambda: validate_file(
            lambda: str(path), self.episodes, self.env_kwargs, self.env_id))
        kill_point("zoo_eval")
        update_best(self.out, row, path)
        print(f"validation after {steps} steps: success {row['success']:.2f}, collision {row['collision']:.2f}, "
              f"time {row['time']:.2f} s", flush=True)
        return row


def save_model(model: Any, path: Path) -> None:
    """``model.save(path)`` with its spaces and world as plain JSON (it loads without unpickling)."""
    from sb3_crowdnav.serialization import write_spaces

    model.save(path)
    write_spaces(path, model.observation_space, model.action_space, model.get_env())


class TrainingInterrupted(Exception):
    """A signal stopped a checkpointed run; its checkpoint of ``steps`` env steps is written (the same call again
    resumes from it)."""

    def __init__(self, signum: int, steps: int, checkpoint: Path) -> None:
        super().__init__(f"stopped by signal {signum} after {steps} steps; checkpoint {checkpoint} written, run the same "
                         "command again to resume")
        self.signum, self.steps, self.checkpoint = signum, steps, checkpoint


class ZooCheckpoint(BaseCallback):
    """Save a checkpoint (:func:`save_checkpoint`) every ``every`` env steps, counted over all envs, at the start of
    the first rollout past each multiple: there every transition collected is stored and every gradient step of
    the previous rollout taken (PPO's rollout buffer is empty, an off-policy replay buffer complete).

    While ``learn`` runs, SIGTERM and SIGINT stop training at the end of the current env step (``stopped_by`` holds
    the signal; the caller writes the checkpoint); a second signal acts as usual."""

    def __init__(self, out: Path, algo: str, every: int, clock: RunClock, identity: dict[str, Any],
                 validation: Validation | None = None) -> None:
        super().__init__()
        self.out, self.algo, self.every, self.clock, self.identity = Path(out), algo, int(every), clock, identity
        self.validation = validation
        self._next = 0
        self.signals = SignalStop()

    @property
    def stopped_by(self) -> int | None:
        """The signal that stopped training early (SIGTERM or SIGINT), or None."""
        return self.signals.stopped_by

    def _on_training_start(self) -> None:
        self._next = (self.model.num_timesteps // self.every + 1) * self.every
        self.signals.install()

    def _on_training_end(self) -> None:
        self.signals.restore()

    def _on_rollout_start(self) -> None:
        if self.model.num_timesteps >= self._next:
            save_checkpoint(self.model, self.out, self.algo, self.clock, self.identity, self.validation)
            self._next = (self.model.num_timesteps // self.every + 1) * self.every

    def _on_step(self) -> bool:
        return self.stopped_by is None


def truncate_last(buffer: Any) -> None:
    """Mark the newest transition of each env in ``buffer`` (an SB3 replay buffer) truncated where it is not terminal:
    the run resumes with new episodes, so the next transition stored is not its successor (SB3's n-step sampling
    stops at a truncation and bootstraps from that transition's next observation; a one-step target reads
    ``dones * (1 - timeouts)``, unchanged)."""
    if buffer.pos == 0 and not buffer.full:
        return
    last = (buffer.pos - 1) % buffer.buffer_size
    buffer.timeouts[last] = np.logical_or(buffer.timeouts[last], np.logical_not(buffer.dones[last]))


def resume_model(out: Path, algo: str, steps: int, env: Any, seed: int, verbose: int, imitation_episodes: int) -> Any:
    """The checkpoint of ``steps`` (:mod:`~sb3_crowdnav.training.zoo_run`) with its replay buffer, and DQfD's
    demonstrations collected again."""
    from sb3_crowdnav.models import load_model

    model = load_model(checkpoint_file(out, algo, steps), env=env, algo=algo, tensorboard_log=str(out / "tb"),
                       verbose=verbose)
    model.set_random_seed(seed + steps)  # the resumed segment's own draws, the same on every resume
    if getattr(model, "replay_buffer", None) is not None:
        from sb3_crowdnav.apg_value.buffers import load_buffer

        load_buffer(model.replay_buffer, buffer_file(out, algo, steps))
        truncate_last(model.replay_buffer)
    if algo == "dqfd":  # the demonstrations beside the buffer: the same ORCA episodes again
        from sb3_crowdnav import imitation

        model.set_demonstrations(imitation.collect_demonstrations(env, imitation_episodes))
        env.reset()
    return model


class RunMismatchError(ValueError):
    """The folder holds a run of another command."""


def read_progress(out: Path, identity: dict[str, Any]) -> dict[str, Any]:
    """The run's ``progress.json`` ({} for a new folder); :class:`RunMismatchError` when it records another run."""
    progress = read_json(out / PROGRESS) or {}
    recorded = progress.get("run")
    if recorded is not None and recorded != identity:
        changed = sorted(k for k in set(recorded) | set(identity) if recorded.get(k) != identity.get(k))
        raise RunMismatchError(f"{out} holds another run ({', '.join(changed)} differ from this command's: "
                         f"{', '.join(f'{k}={recorded.get(k)!r}' for k in changed)}); rerun it as it was, or use "
                         "another --out")
    return progress


def finish(out: Path, model: Any, clock: RunClock, identity: dict[str, Any]) -> None:
    write_json(out / PROGRESS, {"run": identity, "timesteps": int(model.num_timesteps),
                                "wall_time_s": round(clock.total(), 1), "checkpoint": None, "finished": True})


__all__ = ["RunMismatchError", "TrainingInterrupted", "Validation", "ZooCheckpoint", "buffer_file", "checkpoint_file",
           "finish", "latest_checkpoint", "read_progress", "resume_model", "save_checkpoint", "save_model", "truncate_last"]
