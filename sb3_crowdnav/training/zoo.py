"""rl-zoo3 integration: ``sb3-crowdnav-zoo train|enjoy ...`` = ``python -m rl_zoo3.train|enjoy ...`` with APGValue added
(and ``sb3-crowdnav-zoo tuned``, :mod:`sb3_crowdnav.training.tuned`: a study's best trial as a hyperparameter file).

rl-zoo3's documented way of adding an algorithm is to add it to ``rl_zoo3.utils.ALGOS`` (and,
for Optuna tuning, a sampler to ``rl_zoo3.hyperparams_opt.HYPERPARAMS_SAMPLER``); this module
does exactly that and then hands the command line to rl-zoo3 unchanged, so every rl-zoo3 flag
works (``--storage sqlite:///tune.db --study-name apg -optimize`` spreads tuning over machines
through a shared database; ``--storage PATH.log``, a journal file, carries a study from machine to machine, and
``--fail-running`` marks the trials a killed tuning process left running as failed before it resumes;
``--file-trial`` queues one trial that runs the ``-conf`` file's own settings, so that a study's best is never worse
than the file it started from; ``--trial-minutes MIN`` prunes a trial still training after MIN minutes, its imitation
included, so that a study on a shared machine finishes: rl-zoo3's DQN space holds settings, batches of 2,048 at a
gradient step per env step, that take hours per trial here). A stored study's sampler is seeded with ``--seed`` plus
the trials the study holds, so that a resumed study draws new samples.
``--gym-packages sb3_crowdnav`` is added when missing, and ``--num-threads 1`` (one torch
thread, the package's training floor; rl-zoo3 leaves torch its default of every core) unless the command gives one.

Its evaluations (``--eval-freq``, which keeps ``best_model.zip``, and every Optuna trial's, which scores the trial)
play validation episodes: the eval envs are seeded with
:data:`~sb3_crowdnav.training.callbacks.VALIDATION_SEED_OFFSET` (env ``i``: 2,000,000 + i) whatever ``--seed`` is,
where rl-zoo3 seeds them as the training envs (:func:`experiment_manager`). Model and hyperparameter selection then
never scores the training episodes, and every trial of a study starts its evaluations from the same episodes.

Optuna tuning of ``dqn`` and ``qrdqn`` also samples ``n_steps`` (n-step returns, which the zoo's ``dqn`` and
``qrdqn`` build on this package's Dict observations with :class:`~sb3_crowdnav.nn.NStepDictReplayBuffer`).
The zoo's ``ppo``, ``a2c``, ``maskableppo`` and ``dqn`` take ``imitation_episodes`` (and ``imitation_epochs``,
``imitation_learning_rate``) in a hyperparameter file: they imitate that many ORCA-robot episodes before their RL, in
a run and in every Optuna trial, as ``sb3-crowdnav train --hyperparams`` does with the same file
(:class:`ImitationMixin`).

Its ``ppo``, ``a2c`` and ``dqn`` are SB3's algorithms, and ``qrdqn``, ``recurrentppo`` (also rl-zoo3's ``ppo_lstm``)
and ``maskableppo`` sb3-contrib's, that also know ``policy: 'ApgPolicy'`` (the APG
encoder's :data:`~sb3_crowdnav.nn.APG_POLICIES`), so the package's hyperparameter files run here; SB3's
own classes, and plain ``python -m rl_zoo3.train``, are left as they are (there, write ``MultiInputPolicy``
with ``policy_kwargs: "dict(features_extractor_class=...)"``).

    sb3-crowdnav-zoo train --algo apg_value --env CrowdNav-v0 -conf zoo_hyperparams/apg_value.yml
    sb3-crowdnav-zoo enjoy --algo apg_value --env CrowdNav-v0 -f logs/ --no-render
    sb3-crowdnav-zoo train --algo ppo --env CrowdNav-v0 -conf zoo_hyperparams/ppo.yml
    sb3-crowdnav-zoo train --algo maskableppo --env CrowdNavWarehouse-v0 -conf zoo_hyperparams/maskableppo.yml
"""

from __future__ import annotations

import functools
import math
import sys
import time
from typing import Any, ClassVar

from sb3_contrib import QRDQN, MaskablePPO, RecurrentPPO
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.policies import BasePolicy

from sb3_crowdnav.nn.buffers import DictNStepMixin
from sb3_crowdnav.nn.policies import APG_POLICIES
from sb3_crowdnav.training import zoo_safety
from sb3_crowdnav.training.callbacks import VALIDATION_SEED_OFFSET
from sb3_crowdnav.training.hyperparams import IMITATION_DEFAULTS, check_imitation, imitate
from sb3_crowdnav.training.zoo_safety import SafeLoadMixin, SafeStoreDict

COMMANDS = ("train", "enjoy", "tuned")


def sample_apg_value_params(trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """Optuna search space for APGValue (the paper's values are inside every range)."""
    gamma = trial.suggest_categorical("gamma", [0.8, 0.85, 0.9, 0.95])
    return {
        "gamma": gamma,
        "learning_rate": trial.suggest_float("learning_rate", 1e-4, 1e-2, log=True),
        "batch_size": trial.suggest_categorical("batch_size", [32, 64, 100, 128, 256]),
        "target_update_interval": trial.suggest_categorical("target_update_interval", [500, 1000, 2000, 5000]),
        "exploration_final_eps": trial.suggest_float("exploration_final_eps", 0.0, 0.2),
        "exploration_episodes": trial.suggest_categorical("exploration_episodes", [500, 1000, 2000, 5000]),
        "imitation_episodes": trial.suggest_categorical("imitation_episodes", [0, 200, 1000]),
        "imitation_epochs": trial.suggest_categorical("imitation_epochs", [5, 20]),
        "gradient_steps": trial.suggest_categorical("gradient_steps", [1, 2]),
    }


N_STEPS_CHOICES = (1, 3, 5)  # n-step returns: the one-step target, and SG-D3QN's / Rainbow's range


def sample_dqn_params(trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """rl-zoo3's DQN search space plus ``n_steps`` in :data:`N_STEPS_CHOICES` (rl-zoo3 2.9's has no n-step returns)."""
    from rl_zoo3 import hyperparams_opt

    params = hyperparams_opt.sample_dqn_params(trial, n_actions, n_envs, additional_args)
    return {**params, "n_steps": trial.suggest_categorical("n_steps", list(N_STEPS_CHOICES))}


def sample_qrdqn_params(trial, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """rl-zoo3's QR-DQN search space plus ``n_steps`` in :data:`N_STEPS_CHOICES`."""
    from rl_zoo3 import hyperparams_opt

    params = hyperparams_opt.sample_qrdqn_params(trial, n_actions, n_envs, additional_args)
    return {**params, "n_steps": trial.suggest_categorical("n_steps", list(N_STEPS_CHOICES))}


class ImitationMixin:
    """The ORCA robot imitated before the first ``learn()``: the hyperparameters ``imitation_episodes`` (0: none),
    ``imitation_epochs`` and ``imitation_learning_rate`` of a file or an Optuna trial, as ``sb3-crowdnav train
    --hyperparams`` reads them (:func:`~sb3_crowdnav.training.hyperparams.imitate`: behaviour cloning for PPO, A2C and
    MaskablePPO, DQfD's loss with the demonstrations left in the replay buffer for DQN and QR-DQN). A model saved after
    it (or loaded) does not imitate again."""

    def __init__(self, *args: Any, imitation_episodes: int = IMITATION_DEFAULTS["imitation_episodes"],
                 imitation_epochs: int = IMITATION_DEFAULTS["imitation_epochs"],
                 imitation_learning_rate: float = IMITATION_DEFAULTS["imitation_learning_rate"], **kwargs: Any) -> None:
        check_imitation(imitation_episodes, imitation_epochs, imitation_learning_rate)
        self.imitation_episodes, self.imitation_epochs = imitation_episodes, imitation_epochs
        self.imitation_learning_rate = float(imitation_learning_rate)
        self.imitated = imitation_episodes == 0
        super().__init__(*args, **kwargs)

    def learn(self, *args: Any, **kwargs: Any) -> Any:
        if not self.imitated:
            imitate(self, self.env, "dqn" if isinstance(self, DQN | QRDQN) else "ppo", self.imitation_episodes,
                    self.imitation_epochs, self.imitation_learning_rate, self.verbose)
            self.imitated = True
        return super().learn(*args, **kwargs)


class ZooPPO(SafeLoadMixin, ImitationMixin, PPO):
    """SB3's PPO for which ``"ApgPolicy"`` names :class:`~sb3_crowdnav.nn.ApgActorCriticPolicy`, imitating first with
    ``imitation_episodes`` (:class:`ImitationMixin`)."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {**PPO.policy_aliases, "ApgPolicy": APG_POLICIES["ppo"]}


class ZooA2C(SafeLoadMixin, ImitationMixin, A2C):
    """SB3's A2C for which ``"ApgPolicy"`` names :class:`~sb3_crowdnav.nn.ApgActorCriticPolicy`, imitating first with
    ``imitation_episodes`` (:class:`ImitationMixin`)."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {**A2C.policy_aliases, "ApgPolicy": APG_POLICIES["a2c"]}


class ZooDQN(SafeLoadMixin, ImitationMixin, DictNStepMixin, DQN):
    """SB3's DQN for which ``"ApgPolicy"`` names :class:`~sb3_crowdnav.nn.ApgDQNPolicy`, ``n_steps > 1`` builds an
    :class:`~sb3_crowdnav.nn.NStepDictReplayBuffer` (:class:`~sb3_crowdnav.nn.DictNStepMixin`), and
    ``imitation_episodes`` imitates first (:class:`ImitationMixin`)."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {**DQN.policy_aliases, "ApgPolicy": APG_POLICIES["dqn"]}


class ZooQRDQN(SafeLoadMixin, ImitationMixin, DictNStepMixin, QRDQN):
    """sb3-contrib's QRDQN for which ``"ApgPolicy"`` names :class:`~sb3_crowdnav.nn.ApgQRDQNPolicy`, ``n_steps > 1``
    builds an :class:`~sb3_crowdnav.nn.NStepDictReplayBuffer` (:class:`~sb3_crowdnav.nn.DictNStepMixin`), and
    ``imitation_episodes`` imitates first (:class:`ImitationMixin`)."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {**QRDQN.policy_aliases, "ApgPolicy": APG_POLICIES["qrdqn"]}


class ZooRecurrentPPO(SafeLoadMixin, RecurrentPPO):
    """sb3-contrib's RecurrentPPO for which ``"ApgPolicy"`` names :class:`~sb3_crowdnav.nn.ApgRecurrentPolicy`."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {**RecurrentPPO.policy_aliases,
                                                              "ApgPolicy": APG_POLICIES["recurrentppo"]}


class ZooMaskablePPO(SafeLoadMixin, ImitationMixin, MaskablePPO):
    """sb3-contrib's MaskablePPO for which ``"ApgPolicy"`` names :class:`~sb3_crowdnav.nn.ApgMaskablePolicy`, imitating
    first with ``imitation_episodes`` (:class:`ImitationMixin`)."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {**MaskablePPO.policy_aliases,
                                                              "ApgPolicy": APG_POLICIES["maskableppo"]}


# this package's algorithm names; rl-zoo3's own name of RecurrentPPO (ppo_lstm) resolves "ApgPolicy" too
ZOO_ALGOS: dict[str, type] = {"ppo": ZooPPO, "a2c": ZooA2C, "dqn": ZooDQN, "qrdqn": ZooQRDQN,
                              "recurrentppo": ZooRecurrentPPO, "ppo_lstm": ZooRecurrentPPO, "maskableppo": ZooMaskablePPO}


def register() -> None:
    """Add ``apg_value``, ``recurrentppo`` and ``maskableppo`` to rl-zoo3's algorithm table (and APGValue to its tuning
    samplers), let its ``ppo``, ``a2c``, ``dqn``, ``qrdqn`` and ``ppo_lstm`` resolve ``"ApgPolicy"``
    (:data:`ZOO_ALGOS`; saved models load with SB3's and sb3-contrib's own classes), and let the tuning of ``dqn`` and
    ``qrdqn`` sample ``n_steps`` (:func:`sample_dqn_params`); idempotent."""
    try:
        from rl_zoo3 import hyperparams_opt, utils
    except ImportError as exc:  # pragma: no cover - depends on the extra
        raise ImportError("the rl-zoo3 integration needs the 'zoo' extra: pip install 'sb3_crowdnav[zoo]'") from exc
    from sb3_crowdnav.apg_value import APGValue

    utils.ALGOS["apg_value"] = APGValue
    utils.ALGOS.update(ZOO_ALGOS)
    hyperparams_opt.HYPERPARAMS_SAMPLER["apg_value"] = sample_apg_value_params
    hyperparams_opt.HYPERPARAMS_CONVERTER["apg_value"] = lambda params: params
    hyperparams_opt.HYPERPARAMS_SAMPLER["dqn"] = sample_dqn_params  # rl-zoo3's converter passes n_steps through
    hyperparams_opt.HYPERPARAMS_SAMPLER["qrdqn"] = sample_qrdqn_params
    for algo, like in (("recurrentppo", "ppo_lstm"), ("maskableppo", "ppo")):  # rl-zoo3 samples them as these
        hyperparams_opt.HYPERPARAMS_SAMPLER[algo] = hyperparams_opt.HYPERPARAMS_SAMPLER[like]
        hyperparams_opt.HYPERPARAMS_CONVERTER[algo] = hyperparams_opt.HYPERPARAMS_CONVERTER[like]


@functools.cache
def experiment_manager() -> type:
    """``ZooExperimentManager``: rl-zoo3's ``ExperimentManager`` whose eval envs play validation episodes (built
    on first use: rl-zoo3 is an optional extra)."""
    from rl_zoo3.exp_manager import ExperimentManager

    class ZooExperimentManager(ExperimentManager):
        """rl-zoo3's experiment manager with its eval envs seeded at :data:`VALIDATION_SEED_OFFSET` (training envs as
        rl-zoo3 seeds them: ``--seed``)."""

        def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
            zoo_safety.check_config(self.config)  # a YAML file only, its strings parsed and its classes checked (zoo_safety)
            hyperparams, saved = super().read_hyperparameters()
            return zoo_safety.checked_hyperparams(hyperparams), saved

        def hyperparameters_optimization(self) -> None:
            """Every trial's sampled ``policy_kwargs`` (rl-zoo3's: ``net_arch``, ``activation_fn``) over the file's,
            not instead of them (RecurrentPPO keeps the file's ``lstm_hidden_size``, QR-DQN its ``n_quantiles``): the
            sampler rl-zoo3's objective reads is wrapped for the whole study (its trials may run in threads)."""
            from rl_zoo3 import hyperparams_opt

            own = dict(self._hyperparams.get("policy_kwargs") or {})
            samplers = hyperparams_opt.HYPERPARAMS_SAMPLER  # the table rl-zoo3's objective reads
            sampler = samplers[self.algo]
            samplers[self.algo] = functools.partial(_over_policy_kwargs, sampler, own)
            try:
                super().hyperparameters_optimization()
            finally:
                samplers[self.algo] = sampler

        def _create_sampler(self, sampler_method: str) -> Any:
            """rl-zoo3's sampler, seeded with ``--seed`` plus the number of trials the stored study already holds
            (:func:`~sb3_crowdnav.training.tuned.stored_trial_count`): a resumed study does not draw its first
            random trials again (a new process would restart the sampler's generator at ``--seed``, and the
            start-up trials after a resume would repeat the first ones), and the same study state still gives the
            same samples."""
            from sb3_crowdnav.training.tuned import stored_trial_count

            seed = self.seed
            if self.storage is not None and self.study_name is not None and seed is not None:
                self.seed = seed + stored_trial_count(self.storage, self.study_name)
            try:
                return super()._create_sampler(sampler_method)
            finally:
                self.seed = seed

        def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> Any:
            """Training envs as rl-zoo3 builds them; eval envs seeded at the validation offset and, unless
            ``--eval-env-kwargs`` was given, with the training envs' keyword arguments, the file's ``env_kwargs``
            included (rl-zoo3 2.9 gives its eval envs only the command line's, so a file's world, e.g. the
            warehouse worlds of ``CrowdNavWorlds-v0``, would be scored in the env's default world)."""
            if not eval_env:
                return super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)
            training_seed, self.seed = self.seed, VALIDATION_SEED_OFFSET
            given = self.eval_env_kwargs
            if self._eval_env_kwargs_args is None:  # (rl-zoo3's record of --eval-env-kwargs)
                self.eval_env_kwargs = self.env_kwargs
            try:
                return super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)
            finally:
                self.seed, self.eval_env_kwargs = training_seed, given

    return ZooExperimentManager


def wall_time_eval_callback(minutes: float) -> type:
    """rl-zoo3's ``TrialEvalCallback`` that also stops its trial ``minutes`` after it was built (rl-zoo3's objective
    builds it just before ``learn``, so a model's imitation counts): learning ends at the next step, the trial is
    pruned as rl-zoo3 prunes one (its validations so far reported) and its ``pruned_after_minutes`` attribute says
    why."""
    from rl_zoo3.callbacks import TrialEvalCallback

    from sb3_crowdnav.training.tuned import TRIAL_MINUTES

    class WallTimeTrialEvalCallback(TrialEvalCallback):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.deadline = time.monotonic() + 60.0 * minutes

        def _on_step(self) -> bool:
            if time.monotonic() > self.deadline:
                self.is_pruned = True  # rl-zoo3's objective raises TrialPruned after learn
                self.trial.set_user_attr(TRIAL_MINUTES, minutes)
                return False
            return super()._on_step()

    return WallTimeTrialEvalCallback


def _trial_minutes(command: str, rest: list[str]) -> tuple[list[str], float | None]:
    """``--trial-minutes MIN``: the line without it and MIN, checked (a positive number of minutes, with ``train
    -optimize``; else one line and exit 2); the line as it is and None without the flag."""
    if not any(arg == "--trial-minutes" or arg.startswith("--trial-minutes=") for arg in rest):
        return rest, None
    value = _option(rest, "--trial-minutes")
    optimize = "-optimize" in rest or "--optimize-hyperparameters" in rest
    try:
        minutes = float(value) if value is not None else math.nan
    except ValueError:
        minutes = math.nan
    if command != "train" or not optimize or not (math.isfinite(minutes) and minutes > 0):
        print(f"sb3-crowdnav-zoo: error: --trial-minutes: a positive number of minutes for train -optimize, got "
              f"{value!r}" + ("" if command == "train" and optimize else " (not tuning)"), file=sys.stderr)
        raise SystemExit(2)
    out, skip = [], False
    for arg in rest:
        if skip:
            skip = False
        elif arg == "--trial-minutes":
            skip = True
        elif not arg.startswith("--trial-minutes="):
            out.append(arg)
    return out, minutes


def _over_policy_kwargs(sampler: Any, own: dict[str, Any], *args: Any) -> dict[str, Any]:
    from sb3_crowdnav.training.tuned import FILE_TRIAL

    if getattr(args[0], "user_attrs", {}).get(FILE_TRIAL):  # --file-trial's trial: the file's settings as they are
        return {}
    params = sampler(*args)
    if isinstance(params.get("policy_kwargs"), dict):
        params = {**params, "policy_kwargs": {**own, **params["policy_kwargs"]}}
    return params


def _option(argv: list[str], name: str) -> str | None:
    """The value of ``name VALUE`` or ``name=VALUE`` in ``argv`` (None when absent)."""
    for i, arg in enumerate(argv):
        if arg == name and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(name + "="):
            return arg[len(name) + 1:]
    return None


def _on_stored_study(flag: str, does: str, command: str, rest: list[str], action: Any) -> Any:
    """Run ``action(storage, study_name)`` for the package's study flag ``flag`` (taken out before rl-zoo3 reads the
    line), which ``does`` something to a stored study: refused in one line (exit 2) unless the command is ``train``
    with ``-optimize``, ``--storage`` and ``--study-name``, and when the storage cannot be used."""
    storage, study_name = _option(rest, "--storage"), _option(rest, "--study-name")
    optimize = "-optimize" in rest or "--optimize-hyperparameters" in rest
    if command != "train" or not optimize or storage is None or study_name is None:
        print(f"sb3-crowdnav-zoo: error: {flag}: {does}: give it to train with -optimize, --storage and --study-name",
              file=sys.stderr)
        raise SystemExit(2)
    try:
        return action(storage, study_name)
    except Exception as exc:  # (an unusable storage: Optuna's and SQLAlchemy's errors alike, said in one line)
        print(f"sb3-crowdnav-zoo: error: --storage {storage!r}: {type(exc).__name__}: {' '.join(str(exc).split())}",
              file=sys.stderr)
        raise SystemExit(2) from None


def _fail_running(command: str, rest: list[str]) -> None:
    """``--fail-running``: the study's RUNNING trials, left so by a tuning process that was killed, are marked FAIL
    before the study resumes (:func:`~sb3_crowdnav.training.tuned.fail_running_trials`)."""
    from sb3_crowdnav.training.tuned import fail_running_trials

    study_name = _option(rest, "--study-name")
    for number in _on_stored_study("--fail-running", "resumes a study", command, rest, fail_running_trials):
        print(f"sb3-crowdnav-zoo: trial {number} of study {study_name!r} was left running: marked FAIL", file=sys.stderr)


def _file_trial(command: str, rest: list[str]) -> None:
    """``--file-trial``: queue one trial of the study that runs the ``-conf`` file's own settings, nothing sampled,
    scored like every other trial, so that ``tuned`` keeps the file's values when no sampled trial beats them
    (:func:`~sb3_crowdnav.training.tuned.enqueue_file_trial`: once per study)."""
    from sb3_crowdnav.training.tuned import enqueue_file_trial

    study_name = _option(rest, "--study-name")
    queued = _on_stored_study("--file-trial", "queues a trial in a stored study", command, rest, enqueue_file_trial)
    print(f"sb3-crowdnav-zoo: study {study_name!r}: " + ("a trial of the file's own settings queued" if queued else
          "has a trial of the file's own settings already"), file=sys.stderr)


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in COMMANDS:
        print(f"usage: sb3-crowdnav-zoo {{{','.join(COMMANDS)}}} [rl-zoo3 arguments]\n\n{__doc__}", file=sys.stderr)
        raise SystemExit(2)
    command, rest = argv[0], argv[1:]
    if command == "tuned":  # the package's own: a study's best trial as a hyperparameter file
        from sb3_crowdnav.training.tuned import main as tuned_main

        register()  # (the converters of the package's algorithms)
        return tuned_main(rest)
    if "--fail-running" in rest:
        rest = [arg for arg in rest if arg != "--fail-running"]
        _fail_running(command, rest)
    if "--file-trial" in rest:
        rest = [arg for arg in rest if arg != "--file-trial"]
        _file_trial(command, rest)
    rest, minutes = _trial_minutes(command, rest)
    if "--gym-packages" not in rest:
        rest += ["--gym-packages", "sb3_crowdnav"]
    if not any(arg == "--num-threads" or arg.startswith("--num-threads=") for arg in rest):
        rest += ["--num-threads", "1"]  # the training floor's one torch thread (rl-zoo3's default is torch's: every core)
    register()
    sys.argv = [f"rl_zoo3.{command}", *rest]
    from rl_zoo3 import utils

    utils.yaml = zoo_safety.safe_yaml_module()  # saved runs read as plain data (zoo_safety)
    try:
        if command == "train":
            from rl_zoo3 import exp_manager
            from rl_zoo3 import train as zoo_train

            zoo_train.ExperimentManager = experiment_manager()  # the name rl_zoo3.train.train() builds its manager from
            zoo_train.StoreDict = SafeStoreDict  # key:value options parsed, not eval'd
            callback = exp_manager.TrialEvalCallback  # the name rl-zoo3's objective builds a trial's callback from
            if minutes is not None:
                exp_manager.TrialEvalCallback = wall_time_eval_callback(minutes)
            try:
                zoo_train.train()
            except ValueError as exc:  # rl-zoo3 prints the best trial after a study, which has none yet
                if str(exc) != "No trials are completed yet.":
                    raise
                print(f"sb3-crowdnav-zoo train: the study {_option(rest, '--study-name')!r} has no complete trial yet "
                      "(every trial so far pruned or failed)", file=sys.stderr)
                raise SystemExit(1) from None
            finally:
                exp_manager.TrialEvalCallback = callback
        else:
            from rl_zoo3 import enjoy as zoo_enjoy

            zoo_enjoy.StoreDict, zoo_enjoy.yaml = SafeStoreDict, zoo_safety.safe_yaml_module()
            zoo_enjoy.enjoy()
    except zoo_safety.RefusedInput as exc:  # an input it would not run: one line, exit 2
        print(f"sb3-crowdnav-zoo {command}: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
