"""``sb3-crowdnav train``: the paper's schedule (``--variant NAME``) or an rl-zoo3 hyperparameter file (``--hyperparams``).

A ``--variant`` run is the paper's schedule of that variant: ORCA imitation, then RL by episodes, checkpoints,
validation and the best model; run it again to resume. A ``--hyperparams FILE --algo ALGO`` run reads an
rl-zoo3-format file (top-level key = env id; ``n_timesteps``, ``policy``, ``policy_kwargs``, ``env_kwargs``,
``n_envs`` and the algorithm's arguments). Both write ``DIR/config.json`` and TensorBoard logs in ``DIR/tb``. Env
options given on the command line override the file's ``env_kwargs``.

``examples/train_paper.py`` of earlier versions took the same flags as ``--variant`` runs do here; its
spellings ``--il-episodes``, ``--il-epochs``, ``--il-learning-rate`` and ``--num-humans`` are kept as
aliases of ``--imitation-episodes``, ``--imitation-epochs``, ``--imitation-learning-rate`` and ``--humans``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sb3_crowdnav.cli import common
from sb3_crowdnav.cli.common import UsageError
from sb3_crowdnav.training.run_folder import write_json

ALGOS = ("apg_value", "dqn", "dqfd", "ppo", "qrdqn", "recurrentppo", "maskableppo")
# flags of a --variant run (the paper's schedule) with the ScheduleConfig field each one sets
SCHEDULE_FLAGS = {
    "rl_episodes": "--rl-episodes", "n_envs": "--n-envs", "learning_rate": "--learning-rate",
    "train_freq": "--train-freq", "buffer_size": "--buffer-size", "checkpoint_episodes": "--checkpoint-episodes",
    "eval_episodes": "--eval-episodes", "bootstrap_timeouts": "--no-bootstrap-timeouts",
    "exploration_episodes": "--exploration-episodes", "select_by": "--select-by", "optimizer": "--optimizer",
    "value_target": "--value-target", "from_imitation": "--from-imitation", "overlap": "--overlap",
    "refill_steps": "--refill-steps", "lookahead_dtype": "--lookahead-dtype",
    "exploration_initial_eps": "--epsilon-start", "exploration_final_eps": "--epsilon-end",
    "pedestrian_model": "--pedestrian-model", "stopping_check": "--stopping-check", "ensemble": "--ensemble",
    "ensemble_checkpoints": "--ensemble-checkpoints", "planning_depth": "--planning-depth",
    "planning_width": "--planning-width", "cap_values": "--cap-values", "recordings": "--recording",
}
SHARED_FLAGS = ("eval_episodes",)  # schedule flags that a --hyperparams run takes too
HYPERPARAMS_FLAGS = {"algo": "--algo", "timesteps": "--timesteps", "checkpoint_freq": "--checkpoint-freq",
                     "wall_time": "--wall-time"}


def add_parser(sub: Any, parents: list[argparse.ArgumentParser]) -> None:
    """Add ``train`` to the subcommands ``sub``."""
    from sb3_crowdnav.apg_value.checks import VALUE_TARGETS
    from sb3_crowdnav.apg_value.overlap import OVERLAP_KINDS
    from sb3_crowdnav.training.callbacks import SELECT_BY
    from sb3_crowdnav.training.schedule import LOOKAHEAD_DTYPES, OPTIMIZERS, VARIANTS
    from sb3_crowdnav.training.variants import describe_default

    p = common.add_command(sub, "train", parents, __doc__,
                           "train a paper variant (--variant) or from an rl-zoo3 YAML (--hyperparams)")
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--variant", choices=sorted(VARIANTS), help="a variant of the paper's tables, trained with its schedule")
    mode.add_argument("--hyperparams", type=Path, metavar="YAML", help="rl-zoo3 hyperparameter file (give --algo)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder (a --variant run resumes from it)")
    p.add_argument("--seed", type=common.nonneg_int, default=0, help="training seed; envs use seed, seed+1, ... (default: 0)")
    p.add_argument("--verbose", type=int, choices=(0, 1, 2), help="SB3 verbosity (default: 1 with --variant, else 0)")
    p.add_argument("--imitation-episodes", "--il-episodes", dest="imitation_episodes", type=common.nonneg_int,
                   help="ORCA-robot episodes imitated first (default: 3000 with --variant; 0 with --hyperparams, "
                        "where it is for ppo, a2c, maskableppo, dqn, qrdqn and dqfd)")
    p.add_argument("--imitation-epochs", "--il-epochs", dest="imitation_epochs", type=common.nonneg_int,
                   help=f"passes over the demonstrations (default: {describe_default('imitation_epochs')}; 10 with "
                        "--hyperparams)")
    p.add_argument("--imitation-learning-rate", "--il-learning-rate", dest="imitation_learning_rate",
                   type=common.positive_float,
                   help="learning rate of the imitation (default: 0.01 with --variant, Table 1; 0.001 with --hyperparams)")

    g = p.add_argument_group("the paper's schedule (--variant)")
    g.add_argument("--rl-episodes", type=common.positive_int,
                   help=f"RL episodes in total (default: {describe_default('rl_episodes')})")
    g.add_argument("--n-envs", type=common.positive_int, help="training envs, one batched lookahead (default: 1)")
    g.add_argument("--learning-rate", type=common.positive_float, help="RL learning rate (default: 0.001, Table 1)")
    g.add_argument("--train-freq", type=common.positive_int,
                   help=f"one gradient step every this many env steps (default: {describe_default('train_freq')})")
    g.add_argument("--buffer-size", type=common.positive_int, help="replay capacity [transitions] (default: 100000)")
    g.add_argument("--checkpoint-episodes", type=common.positive_int,
                   help=f"checkpoint and validate every N RL episodes (default: {describe_default('checkpoint_episodes')})")
    g.add_argument("--eval-episodes", type=common.nonneg_int,
                   help="greedy validation episodes per checkpoint, 0: none (default: 100; with --hyperparams "
                        "and --checkpoint-freq it validates every checkpoint and keeps the best as OUT/best.zip, "
                        "default 0)")
    g.add_argument("--no-bootstrap-timeouts", dest="bootstrap_timeouts", action="store_const", const=False,
                   help="end timed-out episodes with zero future value (the field's reference code)")
    g.add_argument("--exploration-episodes", type=common.positive_int,
                   help=f"RL episodes of the ε decay (default: {describe_default('exploration_episodes')})")
    g.add_argument("--epsilon-start", dest="exploration_initial_eps", type=common.probability, metavar="EPS",
                   help="ε at the first RL episode (default: 0.5, the paper; lower it to fine-tune a model given "
                        "with --from-imitation)")
    g.add_argument("--epsilon-end", dest="exploration_final_eps", type=common.probability, metavar="EPS",
                   help="ε after the decay (default: 0.1, the paper)")
    g.add_argument("--select-by", choices=SELECT_BY,
                   help="best.zip: highest validation success then shortest time (default), or highest return under "
                        "the variant's own reward (use for apg_crl / apg_carl)")
    g.add_argument("--optimizer", choices=sorted(OPTIMIZERS), help="RL optimiser (default: adam; sgd: momentum 0.9)")
    g.add_argument("--value-target", choices=VALUE_TARGETS, help="what V is regressed on in RL (default: td)")
    g.add_argument("--from-imitation", type=Path, metavar="ZIP",
                   help="start RL from a saved post-imitation model, or from any trained value model (fine-tuning)")
    g.add_argument("--overlap", nargs="?", const="thread", choices=(*OVERLAP_KINDS, "off"),
                   metavar="{process,thread,off}",
                   help="gradient steps on the second core while acting (APGValue overlap_training): in a process "
                        "(default), in a thread (also a bare --overlap; the same run to the bit, slower), or off "
                        "(after each env step, on the acting core: another run)")
    g.add_argument("--refill-steps", type=common.nonneg_int,
                   help="resuming without OUT/replay_buffer_<N>.npz, or --from-imitation without "
                        "imitation_replay_buffer.npz beside it: env steps collected before training (default: 5000)")
    g.add_argument("--lookahead-dtype", choices=LOOKAHEAD_DTYPES, help="precision of the acting lookahead (default: float32)")
    common.add_lookahead_options(
        g, "the acting lookahead", "the lookahead of the finished run's best.zip and final.zip",
        {"pedestrian_model": "the model's own; constant_velocity for a new one",
         "stopping_check": "the model's own; off for a new one",
         "planning_depth": f"{describe_default('planning_depth')}; training and its validations search one step",
         "planning_width": "the variant's, else every one",
         "cap_values": "the world's rule: on with racks or progress shaping"})
    g.add_argument("--recording", dest="recordings", action="append", metavar="PATH[,frame_rate=F]",
                   help="a recorded scene to train among as well (repeat), the settings of --crowd replay:PATH[,...] "
                        "(tracked=nearest and lead_in=1 unless given): one more world beside the variant's, as "
                        "likely as each of them (apg_robust only; keep held-out scenes out)")
    g.add_argument("--ensemble", type=common.positive_int, metavar="K",
                   help="train K member runs (one imitation; member k with seed SEED + 1000 k and the schedule given) "
                        "and save their best checkpoints as one value ensemble in OUT/best.zip (default: 1, one run)")
    g.add_argument("--ensemble-checkpoints", type=common.positive_int, metavar="C",
                   help="each member's C best checkpoints by validation go into the ensemble (default: 1, its "
                        "best.zip; C > 1 also with --ensemble 1)")

    g = p.add_argument_group("hyperparameter files (--hyperparams)")
    g.add_argument("--algo", choices=ALGOS, help="algorithm (required with --hyperparams)")
    g.add_argument("--timesteps", type=common.positive_int, help="total timesteps (default: n_timesteps of the file)")
    g.add_argument("--checkpoint-freq", type=common.nonneg_int,
                   help="save a checkpoint in DIR/checkpoints/ every this many env steps (and after the imitation); "
                        "the same command again resumes from the newest (default: 0, only the final model)")
    g.add_argument("--wall-time", type=common.positive_float, metavar="MIN",
                   help="stop training after this many minutes of wall time in all (imitation and resumed segments "
                        "included), whatever the timesteps reached: a baseline with the wall time of the run it is "
                        "compared with (config.json records the timesteps reached and the wall time used)")
    p.set_defaults(func=cmd_train)


def _refuse(args: argparse.Namespace, flags: dict[str, str], mode: str) -> None:
    given = [flag for name, flag in flags.items() if getattr(args, name) is not None]
    if given:
        raise UsageError(f"{given[0]} is not used with {mode}")


def cmd_train(args: argparse.Namespace) -> int:
    if args.variant is not None:
        return _train_variant(args, _variant_config(args))
    return _train_hyperparams(args, _hyperparams_config(args))


def check_train(args: argparse.Namespace) -> None:
    """Every check ``train`` makes of its arguments, without writing or training anything (``sweep`` checks each
    cell with it before the first one starts); a bad argument raises :class:`UsageError`."""
    if args.variant is not None:
        _variant_config(args)
    else:
        _hyperparams_config(args)


def _variant_config(args: argparse.Namespace) -> Any:
    """The checked :class:`~sb3_crowdnav.training.schedule.ScheduleConfig` of a ``--variant`` run."""
    from sb3_crowdnav.training.schedule import VARIANTS, ScheduleConfig

    _refuse(args, HYPERPARAMS_FLAGS, "--variant (it is for --hyperparams runs)")
    variant = VARIANTS[args.variant]
    if args.env is not None and args.env != variant.env_id:
        raise UsageError(f"--env {args.env}: variant {args.variant} trains on {variant.env_id}")
    env_kwargs = common.env_kwargs_from_args(args)
    num_humans = env_kwargs.pop("num_humans", None)
    given = {name: getattr(args, name) for name in (*SCHEDULE_FLAGS, "imitation_episodes", "imitation_epochs",
                                                     "imitation_learning_rate", "seed")}
    given = {k: v for k, v in given.items() if v is not None and k != "from_imitation"}
    if given.get("overlap") == "off":
        given["overlap"] = False
    if num_humans is not None:
        given["num_humans"] = num_humans
    try:
        config = ScheduleConfig(variant=args.variant, env_kwargs=env_kwargs, **given)
    except (TypeError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    common.check_env(variant.env_id, config.training_env_kwargs, common.single_crowd(args))
    if config.stopping_check:
        _check_stopping(variant.env_id, config.training_env_kwargs)
    if args.from_imitation is not None and not args.from_imitation.is_file():
        raise UsageError(f"--from-imitation: no saved model at {str(args.from_imitation)!r}")
    return config


def _check_stopping(env_id: str, env_kwargs: dict[str, Any]) -> None:
    """``--stopping-check`` needs a world with an acceleration limit: refused before any work otherwise."""
    import gymnasium as gym

    from sb3_crowdnav.apg_value.propagation import check_stopping_check

    env = gym.make(env_id, **env_kwargs)
    try:
        check_stopping_check(True, env.unwrapped.world)
    except ValueError as exc:
        raise UsageError(f"--stopping-check: {exc}") from None
    finally:
        env.close()


def _train_variant(args: argparse.Namespace, config: Any) -> int:
    from sb3_crowdnav.training.schedule import config_dict, train_schedule

    common.check_out(args.out)
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "config.json", json.loads(json.dumps(config_dict(config), default=str)))
    from sb3_crowdnav.training.run_folder import RunLockedError

    try:
        result = train_schedule(args.out, config, from_imitation=args.from_imitation, threads=args.threads)
    except RunLockedError as exc:
        raise UsageError(str(exc)) from None
    return 0 if result.stopped_by is None else 128 + result.stopped_by


def _dry_run(algo: str, cfg: dict[str, Any], env_id: str, env_kwargs: dict[str, Any]) -> None:
    """Build the algorithm once on one env: a bad value (``learning_rate: abc``, ``batch_size: -1``) is refused
    before any imitation or training starts."""
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_crowdnav.models import algorithms
    from sb3_crowdnav.training.hyperparams import algorithm_kwargs, env_wrapper_class

    try:
        env = make_vec_env(env_id, n_envs=1, env_kwargs=env_kwargs, wrapper_class=env_wrapper_class(algo))
    except ValueError as exc:  # MaskablePPO's wall masks in a world without walls
        raise UsageError(f"--algo {algo} --env {env_id}: {exc}") from None
    try:
        algorithms()[algo](cfg["policy"], env, **algorithm_kwargs(algo, cfg, env))
    except (AssertionError, TypeError, ValueError, KeyError) as exc:
        raise UsageError(f"--hyperparams: {algo} refuses them: {exc}") from None
    finally:
        env.close()


def _hyperparams_config(args: argparse.Namespace) -> dict[str, Any]:
    """The checked file, env and imitation settings of a ``--hyperparams`` run (the algorithm built once)."""
    from sb3_crowdnav.models import algorithms
    from sb3_crowdnav.training.hyperparams import imitation_settings, load_hyperparams, prepare

    _refuse(args, {k: v for k, v in SCHEDULE_FLAGS.items() if k not in SHARED_FLAGS},
            "--hyperparams (it is for --variant runs)")
    if args.eval_episodes and not args.checkpoint_freq:
        raise UsageError("--eval-episodes with --hyperparams validates every checkpoint: give --checkpoint-freq too")
    if args.algo is None:
        raise UsageError(f"--hyperparams needs --algo, one of {', '.join(ALGOS)}")
    if args.algo not in algorithms():
        raise UsageError(f"--algo {args.algo}: the algorithm cannot be imported in this installation")
    common.check_env(args.env, {})  # a crowd env at all, before its entry in the file is looked for
    try:
        hp = load_hyperparams(args.hyperparams, args.env)
        cfg = prepare(args.algo, hp)
    except (FileNotFoundError, TypeError, ValueError) as exc:
        raise UsageError(f"--hyperparams: {exc}") from None
    env_kwargs = {**cfg["env_kwargs"], **common.env_kwargs_from_args(args)}
    common.check_env(args.env, env_kwargs, common.single_crowd(args))
    if args.timesteps is None and cfg["n_timesteps"] is None:
        raise UsageError("give --timesteps or n_timesteps in the hyperparameter file")
    try:  # the command line's, else the file's, else the defaults (0 episodes, 10 epochs, 1e-3)
        imitation = imitation_settings(args.algo, cfg, imitation_episodes=args.imitation_episodes,
                                       imitation_epochs=args.imitation_epochs,
                                       imitation_learning_rate=args.imitation_learning_rate)
    except ValueError as exc:
        raise UsageError(f"--imitation-episodes / --imitation-epochs / --imitation-learning-rate (or the file's "
                         f"imitation_* keys): {exc}") from None
    _dry_run(args.algo, cfg, args.env, env_kwargs)
    return {"hp": hp, "cfg": cfg, "env_kwargs": env_kwargs, **imitation}


def _train_hyperparams(args: argparse.Namespace, checked: dict[str, Any]) -> int:
    from sb3_crowdnav.training.hyperparams import train_from_hyperparams

    hp, cfg, env_kwargs = checked["hp"], checked["cfg"], checked["env_kwargs"]
    imitation_episodes, imitation_epochs = checked["imitation_episodes"], checked["imitation_epochs"]
    from sb3_crowdnav.training.run_folder import RunLockedError, read_json
    from sb3_crowdnav.training.zoo_run import PROGRESS, RunMismatchError, TrainingInterrupted

    common.check_out(args.out)
    try:
        model, path = train_from_hyperparams(
            args.algo, hp, args.out, env_id=args.env, timesteps=args.timesteps, seed=args.seed,
            progress_bar=common.progress_enabled(args), verbose=args.verbose or 0,
            env_overrides=common.env_kwargs_from_args(args), imitation_episodes=imitation_episodes,
            imitation_epochs=imitation_epochs, imitation_learning_rate=checked["imitation_learning_rate"],
            checkpoint_freq=args.checkpoint_freq or 0, wall_time=None if args.wall_time is None else 60 * args.wall_time,
            eval_episodes=args.eval_episodes or 0)
    except RunLockedError as exc:
        raise UsageError(str(exc)) from None
    except RunMismatchError as exc:
        raise UsageError(f"--out: {exc}") from None
    except TrainingInterrupted as exc:
        print(str(exc), flush=True)
        return 128 + exc.signum
    config = {"algo": args.algo, "env": args.env, "hyperparams": hp, "env_kwargs": env_kwargs, "seed": args.seed,
              "timesteps": model.num_timesteps, "timesteps_asked": args.timesteps or cfg["n_timesteps"],
              "wall_time_budget_s": None if args.wall_time is None else 60 * args.wall_time,
              "imitation_episodes": imitation_episodes, "imitation_epochs": imitation_epochs,
              "wall_time_s": read_json(Path(args.out) / PROGRESS)["wall_time_s"]}
    write_json(Path(args.out) / "config.json", json.loads(json.dumps(config, default=str)))
    print(f"trained {args.algo} for {config['timesteps']} steps in {config['wall_time_s']} s -> {path} "
          f"(TensorBoard logs: {Path(args.out) / 'tb'})")
    return 0
