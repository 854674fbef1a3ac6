"""The paper's training schedule for every variant, with checkpoints, resume, validation and best-model selection.

``sb3-crowdnav train --variant apg_rl --out runs/apg_rl`` runs it from the command line; from Python::

    from sb3_crowdnav.training import ScheduleConfig, train_schedule

    if __name__ == "__main__":  # the learner process (overlap="process", the default) starts by ``spawn``
        result = train_schedule("runs/apg_rl", ScheduleConfig(variant="apg_rl"))  # 3,000 IL + 10,000 RL episodes
        result = train_schedule("runs/apg_rl", ScheduleConfig(variant="apg_rl"))  # again: resumes, or nothing left

The run folder (:mod:`sb3_crowdnav.training.run_folder` has the file protocol) holds:

- ``imitation.zip`` / ``imitation_replay_buffer.npz``: the model after imitation (``from_imitation`` restarts a
  variant from it; a run killed after imitation resumes from it);
- ``checkpoint_<N>.zip`` every ``checkpoint_episodes`` RL episodes (all kept) and ``replay_buffer_<N>.npz``
  (the newest only), ``progress.json`` (with ``wall_time_s``: the wall time the run has used, imitation and
  validations included, summed over the segments of a resumed run; the time since the last checkpoint of a killed
  segment is lost with its episodes, and a run started ``from_imitation`` counts from its RL);
- ``eval_curve.jsonl``, ``best.json``, ``best.zip``: the greedy validation at each checkpoint and the best
  model so far (:class:`~sb3_crowdnav.training.callbacks.EpisodeCheckpoint`);
- ``final.zip`` after the last episode; TensorBoard logs in ``tb/``; ``run.lock`` while a process writes.

Every file is written to a temporary name and renamed; a process killed at any moment (even SIGKILL) resumes
with the same call from the newest checkpoint whose replay buffer exists, validates a checkpoint whose
validation it missed, repairs a ``best.zip`` that does not match ``best.json``, and loses nothing but the
episodes since that checkpoint. A second process on the same folder stops at once (``run.lock``; a lock left
by a dead process is taken over). Running a finished run again does nothing.

A resumed run draws new training episodes (its envs are seeded ``seed + 7919 × episodes done``) instead of
replaying the first ones, so a run stopped and resumed is a valid run but not the same run, to the bit, as an
uninterrupted one. To continue a run on another machine, the newest ``checkpoint_<N>.zip`` is enough (add
``progress.json``, ``eval_curve.jsonl``, ``best.json`` and ``best.zip`` to keep the validation curve and the
selection); without ``replay_buffer_<N>.npz`` (~200 MB) the resumed run starts with an empty buffer and makes
no gradient step until it has collected ``refill_steps`` new transitions.

SIGTERM or SIGINT during RL stops the run at the end of the current step and writes the checkpoint first
(:attr:`ScheduleResult.stopped_by`; the CLI exits with 128 + the signal).
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch as th
from stable_baselines3.common.env_util import make_vec_env

from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.apg_value.checks import VALUE_TARGETS
from sb3_crowdnav.apg_value.overlap import OVERLAP_KINDS
from sb3_crowdnav.apg_value.policies import ValueLookaheadPolicy
from sb3_crowdnav.apg_value.propagation import PropagationModel, check_stopping_check
from sb3_crowdnav.apg_value.search import check_cap_values, check_planning
from sb3_crowdnav.sim.validation import check_bool, check_choice, check_instance, check_int, check_number, check_probability
from sb3_crowdnav.training.callbacks import SELECT_BY, EpisodeCheckpoint, finish_depth, set_finished_lookahead
from sb3_crowdnav.training.recordings import check_recordings, with_recordings
from sb3_crowdnav.training.run_folder import (
    RunClock,
    RunLock,
    atomic_write,
    buffer_path,
    checkpoint_path,
    checkpoints,
    kill_point,
    latest_checkpoint,
    read_json,
    remove_stale,
    sha256,
    write_json,
)
from sb3_crowdnav.training.variants import PAPER_SCHEDULE, VARIANTS, Variant

OPTIMIZERS = {"adam": (th.optim.Adam, {}), "sgd": (th.optim.SGD, {"momentum": 0.9})}
LOOKAHEAD_DTYPES = ValueLookaheadPolicy.LOOKAHEAD_DTYPES
PEDESTRIAN_MODELS = PropagationModel.PEDESTRIAN_MODELS
STEPS_PER_EPISODE_BOUND = 200  # the step budget given to learn(); the episode budget stops training first


@dataclass(frozen=True)
class ScheduleConfig:
    """The paper's schedule (Table 1 and §3) and the knobs of a run; every value is checked at construction.

    :param variant: a key of :data:`VARIANTS`
    :param rl_episodes: RL episodes in total (None: the variant's; the paper: 10,000; ``apg_warehouse``: 7,000;
        ``apg_robust``: 3,000; ``apg_warehouse_paper``: 6,000)
    :param imitation_episodes: ORCA-robot episodes collected before RL (3,000)
    :param imitation_epochs: passes of the imitation regression (None: the variant's; 10, ``apg_warehouse``: 5,
        ``apg_robust``: 3)
    :param imitation_learning_rate: its learning rate (Table 1: 0.01)
    :param n_envs: training envs (one batched lookahead)
    :param num_humans: pedestrians of the training and validation episodes, or a (min, max) range drawn per episode
        (None: the variant's; 6, ``apg_robust``: 0 to 10)
    :param env_kwargs: more keyword arguments of the env, over the variant's own (its reward and ``num_humans``
        are set here)
    :param seed: training seed (envs ``seed, seed + 1, ...``)
    :param learning_rate: RL learning rate (Table 1: 0.001)
    :param train_freq: one gradient step every this many env steps (None: the variant's; ``apg_rl``,
        ``apg_robust`` and ``apg_warehouse``: 8, the others: 4)
    :param buffer_size: replay capacity [transitions]
    :param checkpoint_episodes: checkpoint (and validate) every this many RL episodes (None: the variant's; 500,
        ``apg_robust``: 750)
    :param eval_episodes: greedy validation episodes at each checkpoint (0: none)
    :param select_by: ``"success"`` (then shortest time) or ``"return"`` under the variant's own reward
        (use it for the comfort variants)
    :param bootstrap_timeouts: see :class:`~sb3_crowdnav.apg_value.APGValue`
    :param exploration_episodes: RL episodes over which ε decays from ``exploration_initial_eps`` to
        ``exploration_final_eps`` (None: the variant's; the paper: 5,000; ``apg_warehouse_paper``: 3,000;
        ``apg_warehouse``: 3,500; ``apg_robust``: 1,500)
    :param exploration_initial_eps: ε at the first RL episode (the paper: 0.5; lower it to fine-tune a trained
        model given as ``from_imitation``)
    :param exploration_final_eps: ε after ``exploration_episodes`` (the paper: 0.1)
    :param pedestrian_model: the acting lookahead's pedestrian model (see
        :class:`~sb3_crowdnav.apg_value.ValueLookaheadPolicy`); None: the model's own (``"constant_velocity"``
        for a new one)
    :param stopping_check: the acting lookahead's stopping-distance check (``ValueLookaheadPolicy``'s
        ``stopping_check``: also charge the actions it cannot brake from); None: the variant's (``apg_warehouse``:
        on), else the model's own (off for a new one); True is refused before any work in a world without
        ``max_acceleration``
    :param optimizer: RL optimiser, ``"adam"`` (APGValue's default) or ``"sgd"`` (momentum 0.9, the field's code)
    :param value_target: see :class:`~sb3_crowdnav.apg_value.APGValue`
    :param overlap: ``APGValue(overlap_training=...)``: gradient steps on the second core while acting, in a
        ``"process"`` (the default) or a ``"thread"`` (also ``True``; the same run to the bit, slower on 2 cores);
        ``False``: after each env step on the acting core (another run)
    :param refill_steps: resuming without the replay buffer, or starting from a ``from_imitation`` model without
        ``imitation_replay_buffer.npz`` beside it, env steps collected before the first gradient step
    :param lookahead_dtype: precision of the acting lookahead, ``"float32"`` or ``"bfloat16"``
    :param planning_depth: the lookahead depth of the finished run's ``best.zip`` and ``final.zip`` (``finish_depth``;
        training, checkpoints and validations search one step); None: the variant's (``apg_warehouse`` and
        ``apg_robust``: 2, else 1)
    :param planning_width: with a depth > 1, how many actions of each step that search expands
        (``ValueLookaheadPolicy.planning_width``); None: the variant's (``apg_robust``: 8), else every one
    :param cap_values: the finished run's ``best.zip`` and ``final.zip`` cap V at the largest return a state can have
        (``ValueLookaheadPolicy.cap_values``: True also on the paper's open floor, False never; training and its
        checkpoints keep the world's rule); None: the variant's if it sets one (none does), else the world's rule
    :param recordings: recorded scenes to train among as well, each a replay crowd's settings
        ``PATH[,frame_rate=F][,key=value...]`` (``sb3-crowdnav train --recording``; the grammar of ``--crowd
        replay:...``): each becomes one more world of ``CrowdNavWorlds-v0`` beside the variant's (``crowd="replay"``,
        with ``tracked="nearest"`` and ``lead_in=1`` unless given), drawn with the same probability as each of
        them. Only for a variant that trains on the open floor in ``CrowdNavWorlds-v0`` (``apg_robust``). No
        recording ships with the package; keep held-out scenes out of training
    :param ensemble: train this many member runs (one imitation, each member its own seed and this schedule) and
        make their best checkpoints one value ensemble (:mod:`sb3_crowdnav.training.ensemble`); 1: one run
    :param ensemble_checkpoints: the best checkpoints by validation each member gives the ensemble (more than 1 needs
        as many validations)
    """

    variant: str = "apg_rl"
    rl_episodes: int | None = None
    imitation_episodes: int = 3_000
    imitation_epochs: int | None = None
    imitation_learning_rate: float = 0.01
    num_humans: int | tuple[int, int] | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    n_envs: int = 1
    seed: int = 0
    learning_rate: float = 1e-3
    train_freq: int | None = None
    buffer_size: int = 100_000
    value_target: Literal["td", "greedy_td", "lookahead"] = "td"
    optimizer: Literal["adam", "sgd"] = "adam"
    checkpoint_episodes: int | None = None
    eval_episodes: int = 100
    bootstrap_timeouts: bool = True
    exploration_episodes: int | None = None
    exploration_initial_eps: float = 0.5
    exploration_final_eps: float = 0.1
    pedestrian_model: str | None = None
    stopping_check: bool | None = None
    refill_steps: int = 5_000
    select_by: Literal["success", "return"] = "success"
    overlap: bool | Literal["thread", "process"] = "process"
    lookahead_dtype: Literal["float32", "bfloat16"] = "float32"
    ensemble: int = 1
    ensemble_checkpoints: int = 1
    planning_depth: int | None = None
    planning_width: int | None = None
    cap_values: bool | None = None
    recordings: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name, allowed in (("variant", tuple(VARIANTS)), ("select_by", SELECT_BY), ("optimizer", tuple(OPTIMIZERS)),
                              ("value_target", VALUE_TARGETS), ("lookahead_dtype", LOOKAHEAD_DTYPES)):
            check_choice(name, getattr(self, name), allowed)
        for name, default in {**PAPER_SCHEDULE, **self.spec.schedule}.items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, default)
        for name, minimum in (("rl_episodes", 1), ("imitation_episodes", 0), ("imitation_epochs", 0), ("n_envs", 1),
                              ("seed", 0), ("train_freq", 1), ("buffer_size", 1),
                              ("checkpoint_episodes", 1), ("eval_episodes", 0), ("exploration_episodes", 1),
                              ("refill_steps", 0), ("ensemble", 1), ("ensemble_checkpoints", 1), ("planning_depth", 1)):
            check_int(name, getattr(self, name), minimum)
        check_planning(self.planning_depth, self.planning_width)
        check_cap_values(self.cap_values)
        validations = self.rl_episodes // self.checkpoint_episodes if self.eval_episodes else 0
        if self.ensemble_checkpoints > max(validations, 1):
            raise ValueError(f"ensemble_checkpoints must be at most the run's validations ({validations}: "
                             f"rl_episodes // checkpoint_episodes with eval_episodes > 0), got {self.ensemble_checkpoints}")
        for count in self.num_humans if isinstance(self.num_humans, tuple) else (self.num_humans,):
            check_int("num_humans", count, 0)
        check_number("learning_rate", self.learning_rate)
        check_probability("exploration_initial_eps", self.exploration_initial_eps)
        check_probability("exploration_final_eps", self.exploration_final_eps)
        if self.pedestrian_model is not None:
            check_choice("pedestrian_model", self.pedestrian_model, PEDESTRIAN_MODELS)
        if self.stopping_check is not None:
            check_bool("stopping_check", self.stopping_check)
        check_number("imitation_learning_rate", self.imitation_learning_rate)
        check_bool("bootstrap_timeouts", self.bootstrap_timeouts)
        if not (isinstance(self.overlap, bool) or self.overlap in OVERLAP_KINDS):
            raise ValueError(f"overlap must be a bool or one of {OVERLAP_KINDS}, got {self.overlap!r}")
        check_instance("env_kwargs", self.env_kwargs, dict, "a dict")
        object.__setattr__(self, "recordings", check_recordings(self.variant, self.spec.env_id,
                                                                {**self.spec.env_kwargs, **self.env_kwargs},
                                                                self.recordings))
        reward = self.env_kwargs.get("reward", self.spec.reward)
        if reward != self.spec.reward:
            raise ValueError(f"env_kwargs['reward'] = {reward!r}: variant {self.variant!r} trains with "
                             f"reward {self.spec.reward!r}")

    @property
    def spec(self) -> Variant:
        return VARIANTS[self.variant]

    @property
    def training_env_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of the training and validation envs."""
        kwargs = {"reward": self.spec.reward, "num_humans": self.num_humans, **self.spec.env_kwargs,
                  **{k: v for k, v in self.env_kwargs.items() if k != "reward"}}
        return with_recordings(kwargs, self.recordings)


@dataclass
class ScheduleResult:
    """What :func:`train_schedule` leaves: the model, and the signal that stopped it early (None: it finished)."""

    model: APGValue
    stopped_by: int | None
    wall_time: float  # [s] of this call's RL phase


def _resume(out: Path, episodes: int, has_buffer: bool, config: ScheduleConfig, env: Any, log: Any) -> APGValue:
    path = checkpoint_path(out, episodes)
    try:
        model = APGValue.load(path, env=env, tensorboard_log=str(out / "tb"), overlap_training=config.overlap)
    except (ValueError, OSError, zipfile.BadZipFile) as exc:
        raise RuntimeError(f"cannot resume from {path}: {exc}; remove it to resume from the checkpoint before") from exc
    log(f"resuming from {path} at episode {model.episodes_done}, {model.num_timesteps} steps")
    own = {"train_freq": model.train_freq.frequency, "learning_rate": model.learning_rate,
           "exploration_episodes": model.exploration_episodes, "exploration_initial_eps": model.exploration_initial_eps,
           "exploration_final_eps": model.exploration_final_eps}
    kept = {name: value for name, value in own.items() if value != getattr(config, name)}
    for name, value in kept.items():  # a run keeps the settings it started with
        log(f"the run keeps its own {name}={value} (given or default: {getattr(config, name)})")
    recorded = read_json(out / "config.json")
    if kept and recorded is not None:  # config.json records what the run does
        write_json(out / "config.json", {**recorded, **kept})
    if has_buffer:
        model.load_replay_buffer(buffer_path(out, episodes))
    else:  # a run carried to another machine without its (large) buffer: refill it before the next gradient step
        model.learning_starts = model.num_timesteps + config.refill_steps
        log(f"no replay buffer in {out}: collecting {config.refill_steps} transitions before training again")
    return model


def _check_best(out: Path, log: Any) -> None:
    """A ``best.zip`` that is not the file ``best.json`` recorded is restored from its checkpoint, or set aside."""
    best, path = read_json(out / "best.json"), out / "best.zip"
    if best is None or (path.exists() and sha256(path) == best.get("sha256")):
        return
    source = checkpoint_path(out, int(best["episodes"]))
    if source.exists():
        atomic_write(path, lambda tmp: shutil.copyfile(source, tmp))
        write_json(out / "best.json", {**best, "sha256": sha256(path)})
        log(f"{path} did not match best.json: restored from {source.name}")
    else:
        if path.exists():
            os.replace(path, out / "best.zip.damaged")
        (out / "best.json").unlink()
        log(f"{path} did not match best.json and {source.name} is gone: set aside as best.zip.damaged; the next "
            "validation chooses a new best")


def _from_imitation(path: Path, config: ScheduleConfig, env: Any, out: Path) -> APGValue:
    model = APGValue.load(path, env=env, tensorboard_log=str(out / "tb"), verbose=1,
                          bootstrap_timeouts=config.bootstrap_timeouts, learning_rate=config.learning_rate,
                          train_freq=config.train_freq, value_target=config.value_target,
                          exploration_episodes=config.exploration_episodes, overlap_training=config.overlap,
                          exploration_initial_eps=config.exploration_initial_eps,
                          exploration_final_eps=config.exploration_final_eps)
    optimizer_class, optimizer_kwargs = OPTIMIZERS[config.optimizer]
    if model.policy.optimizer_class is not optimizer_class:  # swap the RL optimiser; policy_kwargs follow (save/load)
        model.policy_kwargs.update(optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs)
        model.policy.optimizer_class, model.policy.optimizer_kwargs = optimizer_class, optimizer_kwargs
        model.policy.optimizer = optimizer_class(model.policy.value_net.parameters(), lr=config.learning_rate,
                                                 **optimizer_kwargs)
    if model.seed != config.seed:  # the run's own seed for its ε draws (an ensemble's members start from one model)
        model.seed = config.seed
        model.set_random_seed(config.seed)
    if (path.parent / "imitation_replay_buffer.npz").exists():
        model.load_replay_buffer(path.parent / "imitation_replay_buffer.npz")
    else:  # e.g. fine-tuning a trained model: no gradient step on a handful of transitions
        model.learning_starts = config.refill_steps
    return model


def _new(config: ScheduleConfig, env: Any, out: Path) -> APGValue:
    optimizer_class, optimizer_kwargs = OPTIMIZERS[config.optimizer]
    model = APGValue(config.spec.policy, env, seed=config.seed, imitation_episodes=config.imitation_episodes,
                     imitation_epochs=config.imitation_epochs, tensorboard_log=str(out / "tb"), verbose=1,
                     bootstrap_timeouts=config.bootstrap_timeouts, learning_rate=config.learning_rate,
                     train_freq=config.train_freq, buffer_size=config.buffer_size, value_target=config.value_target,
                     exploration_episodes=config.exploration_episodes,
                     exploration_initial_eps=config.exploration_initial_eps,
                     exploration_final_eps=config.exploration_final_eps,
                     imitation_learning_rate=config.imitation_learning_rate, overlap_training=config.overlap,
                     policy_kwargs=dict(optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs,
                                        lookahead_dtype=config.lookahead_dtype))
    model.learn(0, tb_log_name=config.variant)  # imitation pre-training only; kept so variants can restart from it
    atomic_write(out / "imitation_replay_buffer.npz", model.save_replay_buffer)
    atomic_write(out / "imitation.zip", model.save)
    kill_point("imitation")
    return model


def train_schedule(out: str | Path, config: ScheduleConfig | None = None, from_imitation: str | Path | None = None,
                   log: Any = None, threads: int | None = 1) -> ScheduleResult:
    """Run (or resume) the paper's schedule of ``config.variant`` in the folder ``out`` (see the module docstring).

    :param out: the run folder (created; a run there is resumed)
    :param config: the schedule; the paper's APG_RL by default
    :param from_imitation: start RL from this saved post-imitation model instead of imitating again (its
        ``imitation_replay_buffer.npz`` beside it is loaded when present); ignored when resuming
    :param log: ``log(message)`` for progress lines (default: ``print`` with flush)
    :param threads: torch's intra-op threads, set for the whole process (``torch.set_num_threads``) and for the
        learner process; 1 is the fastest for these small networks on shared CPUs. None leaves the caller's.
    """
    config = ScheduleConfig() if config is None else config
    if not isinstance(config, ScheduleConfig):
        raise TypeError(f"config must be a ScheduleConfig, got {type(config).__name__}")
    if threads is not None:
        check_int("threads", threads, 1)
        th.set_num_threads(threads)  # the training floor's choice (the algorithm never changes it)
    log = log if log is not None else (lambda message: print(message, flush=True))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with RunLock(out):
        if config.ensemble > 1 or config.ensemble_checkpoints > 1:
            from sb3_crowdnav.training.ensemble import train_ensemble

            return ScheduleResult(*train_ensemble(out, config, from_imitation, log, lambda folder, member, start: (
                train_schedule(folder, member, from_imitation=start, log=log, threads=None))))
        return _train(out, config, from_imitation, log)


def _train(out: Path, config: ScheduleConfig, from_imitation: str | Path | None, log: Any) -> ScheduleResult:
    progress = read_json(out / "progress.json") or {}
    latest = latest_checkpoint(out)
    if progress.get("finished") and latest is not None and latest[0] >= config.rl_episodes \
            and (out / "final.zip").exists():
        log(f"{out} has finished its {latest[0]} RL episodes: nothing to do")
        finish_depth(out, config.planning_depth, log, config.planning_width, config.cap_values)  # (killed before)
        return ScheduleResult(APGValue.load(out / "final.zip"), None, 0.0)
    imitated = (out / "imitation.zip").exists() and (out / "imitation_replay_buffer.npz").exists()
    clock = RunClock(progress.get("wall_time_s", 0.0) if latest is not None or imitated else 0.0)
    remove_stale(out, keep=latest[0] if latest else -1)
    _check_best(out, log)
    env_kwargs = config.training_env_kwargs
    # a resumed run draws new training episodes instead of replaying the first ones
    env = make_vec_env(config.spec.env_id, n_envs=config.n_envs, seed=config.seed + 7919 * (latest[0] if latest else 0),
                       env_kwargs=env_kwargs)
    if config.stopping_check:  # refused here, before imitation, in a world the check cannot act in
        check_stopping_check(True, env.get_attr("world")[0])
    if latest is not None:
        model, reset = _resume(out, *latest, config, env, log), False
    elif from_imitation is not None or imitated:  # a run killed after imitation resumes from it
        model, reset = _from_imitation(Path(from_imitation or out / "imitation.zip"), config, env, out), True
        reset = from_imitation is not None
    else:
        model, reset = _new(config, env, out), False
        write_json(out / "progress.json", {**progress, "wall_time_s": round(clock.total(), 1)})  # the imitation's
    model.policy.set_lookahead_dtype(config.lookahead_dtype)  # also for a resumed or from_imitation run
    if config.pedestrian_model is not None:
        model.policy.set_pedestrian_model(config.pedestrian_model)
    if config.stopping_check is not None:
        model.policy.set_stopping_check(config.stopping_check)
    callback = EpisodeCheckpoint(out, config.rl_episodes, config.checkpoint_episodes, config.eval_episodes,
                                 select_by=config.select_by, env_kwargs=env_kwargs, env_id=config.spec.env_id,
                                 clock=clock)
    n = model.episodes_done
    if latest is not None and progress.get("episodes") != n:  # killed after the checkpoint, before progress.json
        progress.update(episodes=n, timesteps=model.num_timesteps, checkpoint=checkpoint_path(out, n).name)
        write_json(out / "progress.json", progress)
    if latest is not None and config.eval_episodes and n % config.checkpoint_episodes == 0 and n > 0 \
            and n not in progress.get("validated", []):  # killed between saving this checkpoint and validating it
        callback.validate_first = True
    start = time.time()
    model.learn(total_timesteps=config.rl_episodes * STEPS_PER_EPISODE_BOUND, callback=callback,
                reset_num_timesteps=reset, tb_log_name=config.variant, log_interval=50)
    if model.episodes_done not in checkpoints(out):  # the last episodes since the last checkpoint
        callback.save()
    if callback.stopped_by is not None:
        log(f"stopped by signal {callback.stopped_by} after {model.episodes_done} RL episodes, "
            f"{model.num_timesteps} steps; checkpoint written, run the same command again to resume")
    else:
        atomic_write(out / "final.zip", model.save)
        kill_point("final")
        write_json(out / "progress.json", {**(read_json(out / "progress.json") or {}), "finished": True,
                                           "wall_time_s": round(clock.total(), 1)})
        log(f"done: {model.episodes_done} RL episodes, {model.num_timesteps} steps, {time.time() - start:.0f} s this run")
        finish_depth(out, config.planning_depth, log, config.planning_width, config.cap_values)
        set_finished_lookahead(model.policy, config.planning_depth, config.planning_width, config.cap_values)
    return ScheduleResult(model, callback.stopped_by, time.time() - start)


def config_dict(config: ScheduleConfig) -> dict[str, Any]:
    """The config as plain JSON-able values (written to ``OUT/config.json`` by the CLI), with the env's keyword
    arguments as the run uses them (the variant's own settings included) under ``training_env_kwargs``."""
    return {**dataclasses.asdict(config), "env_id": config.spec.env_id,
            "training_env_kwargs": config.training_env_kwargs}
