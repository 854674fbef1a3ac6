"""The paper's training schedule for every variant, with checkpoints, resume, validation and best-model selection.

``sb3-crowdnav train --variant apg_rl --out runs/apg_rl`` runs it from the command line;
from Python::

    from sb3_crowdnav.training import ScheduleConfig, train_schedule

    result = train_schedule("runs/apg_rl", ScheduleConfig(variant="apg_rl"))  # 3,000 IL + 10,000 RL episodes
    result = train_schedule("runs/apg_rl", ScheduleConfig(variant="apg_rl"))  # again: resumes, or does nothing left

The run folder holds:

- ``imitation.zip`` / ``imitation_replay_buffer.pkl``: the model after imitation (``from_imitation`` restarts a
  variant from it);
- ``checkpoint.zip`` / ``replay_buffer.pkl`` / ``progress.json``: the last checkpoint, every
  ``checkpoint_episodes`` RL episodes (written to temporary names first, so an interrupted save keeps the
  previous checkpoint), plus a copy ``checkpoint_<episodes>.zip`` each time;
- ``eval_curve.jsonl``, ``best.json``, ``best.zip``: the greedy validation at each checkpoint and the best
  model so far (:class:`~sb3_crowdnav.training.callbacks.EpisodeCheckpoint`);
- ``final.zip`` after the last episode; TensorBoard logs in ``tb/``.

Running the same call again resumes from ``checkpoint.zip``. A resumed run draws new training episodes
(its envs are seeded ``seed + 7919 × episodes done``) instead of replaying the first ones, so a run
stopped and resumed is a valid run but not the same run, to the bit, as an uninterrupted one.
To continue a run on another machine, ``checkpoint.zip`` and ``progress.json`` are enough (add
``eval_curve.jsonl``, ``best.json`` and ``best.zip`` to keep the validation curve and the selection);
without ``replay_buffer.pkl`` (~200 MB) the resumed run starts with an empty buffer and makes no gradient
step until it has collected ``refill_steps`` new transitions.

SIGTERM or SIGINT during RL stops the run at the end of the current step and writes the checkpoint first
(:attr:`ScheduleResult.stopped_by`; the CLI exits with 128 + the signal).
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch as th
from stable_baselines3.common.env_util import make_vec_env

from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.apg_value.checks import VALUE_TARGETS
from sb3_crowdnav.apg_value.policies import ValueLookaheadPolicy
from sb3_crowdnav.sim.config import check_choice, check_int, check_number
from sb3_crowdnav.training.callbacks import SELECT_BY, EpisodeCheckpoint


@dataclass(frozen=True)
class Variant:
    """A row of the paper's tables: the value network (a policy alias of APGValue), its env and reward."""

    policy: str
    reward: str = "crowdnav"
    env_id: str = "CrowdNav-v0"


VARIANTS = {
    "apg_rl": Variant("ApgPolicy"),
    "apg_crl": Variant("ApgPolicy", "comfort"),
    "apg_carl": Variant("ApgPolicy", "comfort_angular"),
    "cadrl": Variant("CadrlPolicy"),
    "sf_rl": Variant("SfPolicy"),
    "lm_rl": Variant("LmPolicy"),
    "lstm_rl": Variant("LstmRlPolicy"),
    "sarl": Variant("SarlPolicy"),
}
OPTIMIZERS = {"adam": (th.optim.Adam, {}), "sgd": (th.optim.SGD, {"momentum": 0.9})}
LOOKAHEAD_DTYPES = ValueLookaheadPolicy.LOOKAHEAD_DTYPES
STEPS_PER_EPISODE_BOUND = 200  # the step budget given to learn(); the episode budget stops training first


@dataclass(frozen=True)
class ScheduleConfig:
    """The paper's schedule (Table 1 and §3) and the knobs of a run; every value is checked at construction.

    :param variant: a key of :data:`VARIANTS`
    :param rl_episodes: RL episodes in total (the paper: 10,000)
    :param imitation_episodes: ORCA-robot episodes collected before RL (3,000)
    :param imitation_epochs: passes of the imitation regression
    :param imitation_learning_rate: its learning rate (Table 1: 0.01)
    :param n_envs: training envs (one batched lookahead)
    :param num_humans: pedestrians of the training and validation episodes (6), or a (min, max) range
    :param env_kwargs: more keyword arguments of the env (the variant's reward and ``num_humans`` are set here)
    :param seed: training seed (envs ``seed, seed + 1, ...``)
    :param learning_rate: RL learning rate (Table 1: 0.001)
    :param train_freq: one gradient step every this many env steps
    :param buffer_size: replay capacity [transitions]
    :param checkpoint_episodes: checkpoint (and validate) every this many RL episodes
    :param eval_episodes: greedy validation episodes at each checkpoint (0: none)
    :param select_by: ``"success"`` (then shortest time) or ``"return"`` under the variant's own reward
        (use it for the comfort variants)
    :param bootstrap_timeouts: see :class:`~sb3_crowdnav.apg_value.APGValue`
    :param exploration_episodes: RL episodes over which ε decays from 0.5 to 0.1 (5,000)
    :param optimizer: RL optimiser, ``"adam"`` (APGValue's default) or ``"sgd"`` (momentum 0.9, the field's code)
    :param value_target: see :class:`~sb3_crowdnav.apg_value.APGValue`
    :param overlap: ``APGValue(overlap_training=True)``: gradient steps on the second core while acting
    :param refill_steps: resuming without the replay buffer, env steps collected before gradient steps resume
    :param lookahead_dtype: precision of the acting lookahead, ``"float32"`` or ``"bfloat16"``
    """

    variant: str = "apg_rl"
    rl_episodes: int = 10_000
    imitation_episodes: int = 3_000
    imitation_epochs: int = 10
    imitation_learning_rate: float = 0.01
    num_humans: int | tuple[int, int] = 6
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    n_envs: int = 1
    seed: int = 0
    learning_rate: float = 1e-3
    train_freq: int = 4
    buffer_size: int = 100_000
    value_target: Literal["td", "greedy_td", "lookahead"] = "td"
    optimizer: Literal["adam", "sgd"] = "adam"
    checkpoint_episodes: int = 500
    eval_episodes: int = 100
    bootstrap_timeouts: bool = True
    exploration_episodes: int = 5_000
    refill_steps: int = 5_000
    select_by: Literal["success", "return"] = "success"
    overlap: bool = False
    lookahead_dtype: Literal["float32", "bfloat16"] = "float32"

    def __post_init__(self) -> None:
        for name, allowed in (("variant", tuple(VARIANTS)), ("select_by", SELECT_BY), ("optimizer", tuple(OPTIMIZERS)),
                              ("value_target", VALUE_TARGETS), ("lookahead_dtype", LOOKAHEAD_DTYPES)):
            check_choice(name, getattr(self, name), allowed)
        for name, minimum in (("rl_episodes", 1), ("imitation_episodes", 0), ("imitation_epochs", 0), ("n_envs", 1),
                              ("seed", 0), ("train_freq", 1), ("buffer_size", 1),
                              ("checkpoint_episodes", 1), ("eval_episodes", 0), ("exploration_episodes", 1),
                              ("refill_steps", 0)):
            check_int(name, getattr(self, name), minimum)
        for count in self.num_humans if isinstance(self.num_humans, tuple) else (self.num_humans,):
            check_int("num_humans", count, 0)
        check_number("learning_rate", self.learning_rate)
        check_number("imitation_learning_rate", self.imitation_learning_rate)
        for name in ("bootstrap_timeouts", "overlap"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name} must be a bool, got {getattr(self, name)!r}")
        if not isinstance(self.env_kwargs, dict):
            raise TypeError(f"env_kwargs must be a dict, got {type(self.env_kwargs).__name__}")
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
        return {"reward": self.spec.reward, "num_humans": self.num_humans,
                **{k: v for k, v in self.env_kwargs.items() if k != "reward"}}


@dataclass
class ScheduleResult:
    """What :func:`train_schedule` leaves: the model, and the signal that stopped it early (None: it finished)."""

    model: APGValue
    stopped_by: int | None
    wall_time: float  # [s] of this call's RL phase


def _done_episodes(out: Path) -> int:
    """RL episodes of the checkpoint in ``out`` (0 without ``progress.json``)."""
    path = out / "progress.json"
    return json.loads(path.read_text())["episodes"] if path.exists() else 0


def _resume(out: Path, config: ScheduleConfig, env: Any, log: Any) -> APGValue:
    model = APGValue.load(out / "checkpoint.zip", env=env, tensorboard_log=str(out / "tb"),
                          overlap_training=config.overlap)
    log(f"resuming from {out / 'checkpoint.zip'} at episode {model._episode_num}, {model.num_timesteps} steps")
    if (out / "replay_buffer.pkl").exists():
        model.load_replay_buffer(out / "replay_buffer.pkl")
    else:  # a run carried to another machine without its (large) buffer: refill it before the next gradient step
        model.learning_starts = model.num_timesteps + config.refill_steps
        log(f"no replay buffer in {out}: collecting {config.refill_steps} transitions before training again")
    return model


def _from_imitation(path: Path, config: ScheduleConfig, env: Any, out: Path) -> APGValue:
    model = APGValue.load(path, env=env, tensorboard_log=str(out / "tb"), verbose=1,
                          bootstrap_timeouts=config.bootstrap_timeouts, learning_rate=config.learning_rate,
                          train_freq=config.train_freq, value_target=config.value_target,
                          exploration_episodes=config.exploration_episodes, overlap_training=config.overlap)
    optimizer_class, optimizer_kwargs = OPTIMIZERS[config.optimizer]
    if model.policy.optimizer_class is not optimizer_class:  # swap the RL optimiser; policy_kwargs follow (save/load)
        model.policy_kwargs.update(optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs)
        model.policy.optimizer_class, model.policy.optimizer_kwargs = optimizer_class, optimizer_kwargs
        model.policy.optimizer = optimizer_class(model.policy.value_net.parameters(), lr=config.learning_rate,
                                                 **optimizer_kwargs)
    if (path.parent / "imitation_replay_buffer.pkl").exists():
        model.load_replay_buffer(path.parent / "imitation_replay_buffer.pkl")
    return model


def _new(config: ScheduleConfig, env: Any, out: Path) -> APGValue:
    optimizer_class, optimizer_kwargs = OPTIMIZERS[config.optimizer]
    model = APGValue(config.spec.policy, env, seed=config.seed, imitation_episodes=config.imitation_episodes,
                     imitation_epochs=config.imitation_epochs, tensorboard_log=str(out / "tb"), verbose=1,
                     bootstrap_timeouts=config.bootstrap_timeouts, learning_rate=config.learning_rate,
                     train_freq=config.train_freq, buffer_size=config.buffer_size, value_target=config.value_target,
                     exploration_episodes=config.exploration_episodes,
                     imitation_learning_rate=config.imitation_learning_rate, overlap_training=config.overlap,
                     policy_kwargs=dict(optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs,
                                        lookahead_dtype=config.lookahead_dtype))
    model.learn(0, tb_log_name=config.variant)  # imitation pre-training only; kept so variants can restart from it
    model.save(out / "imitation.zip")
    model.save_replay_buffer(out / "imitation_replay_buffer.pkl")
    return model


def train_schedule(out: str | Path, config: ScheduleConfig | None = None, from_imitation: str | Path | None = None,
                   log: Any = None) -> ScheduleResult:
    """Run (or resume) the paper's schedule of ``config.variant`` in the folder ``out`` (see the module docstring).

    :param out: the run folder (created; an existing ``checkpoint.zip`` there is resumed)
    :param config: the schedule; the paper's APG_RL by default
    :param from_imitation: start RL from this saved post-imitation model instead of imitating again (its
        ``imitation_replay_buffer.pkl`` beside it is loaded when present); ignored when resuming
    :param log: ``log(message)`` for progress lines (default: ``print`` with flush)
    """
    config = ScheduleConfig() if config is None else config
    if not isinstance(config, ScheduleConfig):
        raise TypeError(f"config must be a ScheduleConfig, got {type(config).__name__}")
    log = log if log is not None else (lambda message: print(message, flush=True))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    resume = (out / "checkpoint.zip").exists()
    done_episodes = _done_episodes(out) if resume else 0
    env_kwargs = config.training_env_kwargs
    # a resumed run draws new training episodes instead of replaying the first ones
    env = make_vec_env(config.spec.env_id, n_envs=config.n_envs, seed=config.seed + 7919 * done_episodes,
                       env_kwargs=env_kwargs)
    if resume:
        model, reset = _resume(out, config, env, log), False
    elif from_imitation is not None:
        model, reset = _from_imitation(Path(from_imitation), config, env, out), True
    else:
        model, reset = _new(config, env, out), False
    model.policy.set_lookahead_dtype(config.lookahead_dtype)  # also for a resumed or from_imitation run
    callback = EpisodeCheckpoint(out, config.rl_episodes, config.checkpoint_episodes, config.eval_episodes,
                                 select_by=config.select_by, env_kwargs=env_kwargs, env_id=config.spec.env_id)
    start = time.time()
    model.learn(total_timesteps=config.rl_episodes * STEPS_PER_EPISODE_BOUND, callback=callback,
                reset_num_timesteps=reset, tb_log_name=config.variant, log_interval=50)
    callback.save()
    if callback.stopped_by is not None:
        log(f"stopped by signal {callback.stopped_by} after {model._episode_num} RL episodes, "
            f"{model.num_timesteps} steps; checkpoint written, run the same command again to resume")
    else:
        model.save(out / "final.zip")
        log(f"done: {model._episode_num} RL episodes, {model.num_timesteps} steps, {time.time() - start:.0f} s this run")
    return ScheduleResult(model, callback.stopped_by, time.time() - start)


def config_dict(config: ScheduleConfig) -> dict[str, Any]:
    """The config as plain JSON-able values (written to ``OUT/config.json`` by the CLI)."""
    return dataclasses.asdict(config)
