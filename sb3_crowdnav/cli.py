"""The ``sb3-crowdnav`` command line: ``evaluate``, ``benchmark``, ``render`` and ``train``.

Run ``sb3-crowdnav <command> --help`` for the options of each command. Policies are given as
``orca`` (``orca-constrained``), ``random`` (or ``random:SEED``), ``pretrained:NAME`` or the path
of a saved model ``.zip`` (APGValue, DQN, PPO; the algorithm is detected). Test episode ``i``
uses ``env.reset(seed=1_000_000 + i)`` (``--seed-offset``), disjoint from training seeds.
Bad arguments exit with status 2 and a
one-line message.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, NoReturn

from sb3_crowdnav.evaluation.runner import DEFAULT_ENV_ID, TEST_SEED_OFFSET

ALGOS = ("apg_value", "dqn", "dqfd", "ppo")


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line (no usage block), exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _int_at_least(minimum: int, allowed: str):
    """An argparse type: an integer >= ``minimum``, with ``allowed`` in the error message."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"expected {allowed}, got {text!r}")
        return value

    return parse


_positive_int = _int_at_least(1, "a positive integer")
_nonneg_int = _int_at_least(0, "an integer >= 0")


# ------------------------------------------------------------------ shared options
def _env_options() -> argparse.ArgumentParser:
    p = _Parser(add_help=False)
    g = p.add_argument_group("environment")
    g.add_argument("--env", default=DEFAULT_ENV_ID, help="Gymnasium env id (default: %(default)s)")
    g.add_argument("--humans", type=_nonneg_int, metavar="N", help="number of pedestrians (env default: 6)")
    g.add_argument("--max-humans", type=_positive_int, metavar="N",
                   help="observation capacity; must match a trained model's (env default: 10)")
    g.add_argument("--reward", choices=("crowdnav", "comfort", "comfort_angular"),
                   help="reward function (env default: crowdnav)")
    g.add_argument("--visible", action="store_true", help="pedestrians see and avoid the robot")
    g.add_argument("--kinematics", choices=("unicycle", "holonomic"), help="robot kinematics (env default: unicycle)")
    g.add_argument("--human-policy", choices=("orca", "linear"), help="pedestrian motion (env default: orca)")
    g.add_argument("--env-kwargs", metavar="DICT",
                   help="more env keyword arguments as a Python literal, e.g. \"dict(time_limit=30)\"")
    return p


def _common_options() -> argparse.ArgumentParser:
    p = _Parser(add_help=False)
    p.add_argument("--threads", type=_positive_int, default=1, help="torch threads per process (default: 1)")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="show a progress bar (default: when stderr is a terminal)")
    return p


def _run_options(p: argparse.ArgumentParser, default_episodes: int = 500) -> None:
    g = p.add_argument_group("evaluation")
    g.add_argument("--episodes", type=_positive_int, default=default_episodes,
                   help="number of test episodes (default: %(default)s)")
    g.add_argument("--workers", type=_positive_int, default=1, help="worker processes (default: %(default)s)")
    g.add_argument("--seed-offset", type=_nonneg_int, default=TEST_SEED_OFFSET,
                   help="seed of the first test episode; episode i uses seed-offset + i (default: %(default)s)")
    g.add_argument("--stochastic", action="store_true", help="sample actions instead of acting deterministically")


def build_parser() -> argparse.ArgumentParser:
    """The ``sb3-crowdnav`` argument parser."""
    from sb3_crowdnav.version import __version__

    parser = _Parser(prog="sb3-crowdnav", description=__doc__.split("\n\n")[0].replace("``", ""),
                     formatter_class=argparse.RawDescriptionHelpFormatter,
                     epilog="Run 'sb3-crowdnav <command> --help' for the options of a command.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="command", required=True)
    env_opts, common = _env_options(), _common_options()

    p = sub.add_parser("evaluate", parents=[common, env_opts], help="evaluate one policy and print its results table",
                       description="Evaluate one policy on test episodes and print the Table-3 row "
                                   "(rates with Wilson 95 % intervals).")
    p.add_argument("--policy", required=True, help="orca, orca-constrained, random[:SEED], pretrained:NAME or PATH.zip")
    _run_options(p)
    p.add_argument("--out", type=Path, metavar="DIR", help="also write results.md, results.csv and episodes.csv here")
    p.set_defaults(func=_cmd_evaluate)

    p = sub.add_parser("benchmark", parents=[common, env_opts], help="evaluate several policies: table + figures",
                       description="Evaluate every --policy on the same test episodes; write results.md/.csv, "
                                   "one episodes CSV per policy, trajectories.png (same seed for every policy), "
                                   "one GIF per policy, a value map for value-based models, and with --sweep "
                                   "the Table-4 sweep over the number of pedestrians.")
    p.add_argument("--policy", action="append", required=True,
                   help="orca, orca-constrained, random[:SEED], pretrained:NAME or PATH.zip; repeat for several policies")
    _run_options(p)
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--sweep", type=_nonneg_int, nargs="+", metavar="N",
                   help="also evaluate the first model policy (or the first policy) with N pedestrians each (Table 4)")
    p.add_argument("--figure-seed", type=_nonneg_int, help="episode seed of the figures (default: --seed-offset)")
    p.add_argument("--gif", action=argparse.BooleanOptionalAction, default=True, help="write GIFs (default: yes)")
    p.set_defaults(func=_cmd_benchmark)

    p = sub.add_parser("render", parents=[common, env_opts], help="draw one episode as GIF, MP4 or PNG",
                       description="Play one episode and write it as an animation (.gif, or .mp4 with "
                                   "imageio-ffmpeg) or as a trajectory figure (.png).")
    p.add_argument("--policy", required=True, help="orca, orca-constrained, random[:SEED], pretrained:NAME or PATH.zip")
    p.add_argument("--seed", type=_nonneg_int, default=TEST_SEED_OFFSET, help="episode seed (default: %(default)s)")
    p.add_argument("--out", type=Path, required=True, metavar="FILE", help="episode.gif, episode.mp4 or episode.png")
    p.add_argument("--fps", type=float, help="frames per second of an animation (default: real time, 1/Δt)")
    p.add_argument("--stochastic", action="store_true", help="sample actions instead of acting deterministically")
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser("train", parents=[common, env_opts], help="train APGValue, DQN or PPO from a YAML file",
                       description="Train with an rl-zoo3-format hyperparameter file (top-level key = env id; "
                                   "n_timesteps, policy, policy_kwargs, env_kwargs, n_envs, and the algorithm's "
                                   "arguments). Saves DIR/<algo>.zip, DIR/config.json and TensorBoard logs in "
                                   "DIR/tb. Env options given here override the file's env_kwargs.")
    p.add_argument("--algo", required=True, choices=ALGOS, help="algorithm")
    p.add_argument("--hyperparams", required=True, type=Path, metavar="YAML", help="rl-zoo3 hyperparameter file")
    p.add_argument("--timesteps", type=_positive_int, help="total timesteps (default: n_timesteps of the file)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="training seed; envs use seed, seed+1, ... (default: 0)")
    p.add_argument("--verbose", type=int, default=0, choices=(0, 1, 2), help="SB3 verbosity (default: 0)")
    p.add_argument("--imitation-episodes", type=_nonneg_int, default=0,
                   help="PPO/A2C/DQN: first imitate this many ORCA-robot episodes (default: 0, none)")
    p.add_argument("--imitation-epochs", type=_positive_int, default=10, help="passes over the demonstrations (default: 10)")
    p.add_argument("--checkpoint-freq", type=_nonneg_int, default=0,
                   help="save DIR/checkpoints/ every this many env steps (default: 0, only the final model)")
    p.set_defaults(func=_cmd_train)
    return parser


# ------------------------------------------------------------------ helpers
class UsageError(Exception):
    """Bad user input found after parsing; reported in one line with exit status 2."""


def _env_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    from sb3_crowdnav.evaluation.training import safe_eval

    kwargs: dict[str, Any] = {}
    if args.env_kwargs:
        try:
            extra = safe_eval(args.env_kwargs, {"dict": dict})
        except ValueError as exc:
            raise UsageError(f"--env-kwargs: {exc}") from None
        if not isinstance(extra, dict):
            raise UsageError(f"--env-kwargs must be a dict, got {args.env_kwargs!r}")
        kwargs.update(extra)
    for name, key in (("humans", "num_humans"), ("max_humans", "max_humans"), ("reward", "reward"),
                      ("kinematics", "kinematics"), ("human_policy", "human_policy")):
        if getattr(args, name) is not None:
            kwargs[key] = getattr(args, name)
    if args.visible:
        kwargs["robot_visible"] = True
    return kwargs


def _check_env(env_id: str, kwargs: dict[str, Any]) -> None:
    import gymnasium as gym

    import sb3_crowdnav  # noqa: F401  (registers the envs)

    try:
        gym.make(env_id, **kwargs).close()
    except gym.error.Error as exc:
        raise UsageError(f"--env: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise UsageError(f"bad environment options: {exc}") from None


def _check_policy(spec: str) -> str:
    s = spec.strip()
    if s.lower() in ("orca", "orca-constrained"):
        return s.lower()
    if s.lower().startswith("pretrained:"):
        from sb3_crowdnav.pretrained_models import pretrained_path

        try:
            pretrained_path(s.partition(":")[2])
        except ValueError as exc:
            raise UsageError(f"--policy: {exc}") from None
        return s
    head, _, tail = s.partition(":")
    if head.lower() == "random":
        if tail and not tail.lstrip("-").isdigit():
            raise UsageError(f"--policy: a random policy is 'random' or 'random:SEED', got {spec!r}")
        return s.lower()
    from sb3_crowdnav.evaluation.models import detect_algorithm, resolve_model_path

    try:
        path = resolve_model_path(s)
        detect_algorithm(path)
    except (FileNotFoundError, ValueError) as exc:
        raise UsageError(
            f"--policy {spec!r}: expected orca, orca-constrained, random[:SEED], pretrained:NAME or a saved model .zip ({exc})"
        ) from None
    return str(path)


def _labels(specs: list[str]) -> list[str]:
    from sb3_crowdnav.evaluation.runner import policy_label

    labels: list[str] = []
    for spec in specs:
        label, k = policy_label(spec), 2
        while label in labels:
            label, k = f"{policy_label(spec)}_{k}", k + 1
        labels.append(label)
    return labels


def _progress(args: argparse.Namespace) -> bool:
    return sys.stderr.isatty() if args.progress is None else bool(args.progress)


def _is_model(spec: str) -> bool:
    return spec not in ("orca", "orca-constrained") and not spec.startswith("random")


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in label)


def _run(args: argparse.Namespace, spec: str, env_kwargs: dict[str, Any], **kwargs: Any):
    from sb3_crowdnav.evaluation.runner import run_episodes

    return run_episodes(spec, args.episodes, env_kwargs, env_id=args.env, seed_offset=args.seed_offset,
                        workers=args.workers, deterministic=not args.stochastic, progress=_progress(args),
                        torch_threads=args.threads, **kwargs)


def _write_meta(out: Path, args: argparse.Namespace, env_kwargs: dict[str, Any], **extra: Any) -> None:
    from sb3_crowdnav.version import __version__

    meta = {"command": args.command, "env": args.env, "env_kwargs": env_kwargs, "episodes": args.episodes,
            "seeds": [args.seed_offset, args.seed_offset + args.episodes - 1], "deterministic": not args.stochastic,
            "confidence_intervals": "Wilson score, 95 %", "sb3_crowdnav": __version__, **extra}
    (out / "meta.json").write_text(json.dumps(meta, indent=2, default=str) + "\n")


# ------------------------------------------------------------------ commands
def _cmd_evaluate(args: argparse.Namespace) -> int:
    from sb3_crowdnav.evaluation.metrics import summarize
    from sb3_crowdnav.evaluation.tables import results_table, write_records_csv

    env_kwargs = _env_kwargs(args)
    _check_env(args.env, env_kwargs)
    spec = _check_policy(args.policy)
    label = _labels([spec])[0]
    start = time.perf_counter()
    records = _run(args, spec, env_kwargs)
    table = results_table({label: summarize(records)})
    print(table.to_markdown(), end="")
    print(f"\n{args.episodes} episodes (seeds {args.seed_offset}-{args.seed_offset + args.episodes - 1}) "
          f"in {time.perf_counter() - start:.1f} s")
    if args.out is not None:
        table.save(args.out / "results")
        write_records_csv(records, args.out / "episodes.csv")
        _write_meta(args.out, args, env_kwargs, policies={label: spec})
    return 0


def _figure_episodes(args, specs, labels, env_kwargs, seed):
    from sb3_crowdnav.evaluation.runner import run_episodes

    return {label: run_episodes(spec, seeds=[seed], env_kwargs=env_kwargs, env_id=args.env,
                                deterministic=not args.stochastic, keep_trajectories=True,
                                torch_threads=args.threads)[0]
            for spec, label in zip(specs, labels, strict=True)}


def _value_map(args, spec: str, label: str, env_kwargs: dict[str, Any], seed: int, out: Path) -> Path | None:
    """Fig. 11 for a value-based model: the action values at the 8th step (2 s) of the figure episode."""
    import numpy as np

    from sb3_crowdnav.evaluation.plots import plot_value_map
    from sb3_crowdnav.evaluation.runner import make_env, make_policy

    env = make_env(args.env, env_kwargs)
    try:
        model = make_policy(spec, env)
        if not hasattr(getattr(model, "policy", None), "action_values"):
            return None
        obs, _ = env.reset(seed=seed)
        for _ in range(8):
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, _ = env.step(int(np.asarray(action).reshape(-1)[0]))
            if terminated or truncated:
                obs, _ = env.reset(seed=seed)
                break
        path = out / f"value_map_{_slug(label)}.png"
        plot_value_map(model, obs, path, scene=env.unwrapped.scene, title=f"{label}: action values")
        return path
    finally:
        env.close()


def _cmd_benchmark(args: argparse.Namespace) -> int:
    from sb3_crowdnav.evaluation.metrics import summarize
    from sb3_crowdnav.evaluation.plots import plot_trajectories, save_animation
    from sb3_crowdnav.evaluation.runner import run_sweep
    from sb3_crowdnav.evaluation.tables import results_table, sweep_table, write_records_csv

    env_kwargs = _env_kwargs(args)
    _check_env(args.env, env_kwargs)
    specs = [_check_policy(p) for p in args.policy]
    labels = _labels(specs)
    if args.sweep and max(args.sweep) > 0 and "num_humans" in env_kwargs:
        print("note: --sweep sets the number of pedestrians; --humans applies to the main table only", file=sys.stderr)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    summaries = {}
    for spec, label in zip(specs, labels, strict=True):
        records = _run(args, spec, env_kwargs, desc=label)
        summaries[label] = summarize(records)
        write_records_csv(records, out / f"episodes_{_slug(label)}.csv")
    table = results_table(summaries)
    table.save(out / "results")
    print(table.to_markdown(), end="")
    print(f"\n{args.episodes} episodes per policy (seeds {args.seed_offset}-{args.seed_offset + args.episodes - 1}) "
          f"in {time.perf_counter() - start:.1f} s")

    written = [out / "results.md", out / "results.csv", *(out / f"episodes_{_slug(label)}.csv" for label in labels)]
    seed = args.seed_offset if args.figure_seed is None else args.figure_seed
    episodes = _figure_episodes(args, specs, labels, env_kwargs, seed)
    written.append(plot_trajectories(episodes, out / "trajectories.png", title=f"test episode seed {seed}"))
    if args.gif:
        for label, record in episodes.items():
            written.append(save_animation(record, out / f"episode_{_slug(label)}.gif"))
    for spec, label in zip(specs, labels, strict=True):
        if _is_model(spec):
            path = _value_map(args, spec, label, env_kwargs, seed, out)
            if path is not None:
                written.append(path)

    if args.sweep:
        idx = next((i for i, s in enumerate(specs) if _is_model(s)), 0)
        sweep = run_sweep(specs[idx], args.sweep, args.episodes, env_kwargs, env_id=args.env,
                          seed_offset=args.seed_offset, workers=args.workers, deterministic=not args.stochastic,
                          progress=_progress(args), torch_threads=args.threads)
        stable = sweep_table({n: summarize(r) for n, r in sweep.items()})
        stable.save(out / "sweep")
        print(f"\nnumber of pedestrians, {labels[idx]} (Table 4):\n")
        print(stable.to_markdown(), end="")
        written += [out / "sweep.md", out / "sweep.csv"]
    _write_meta(out, args, env_kwargs, policies=dict(zip(labels, specs, strict=True)), figure_seed=seed, sweep=args.sweep)
    print(f"\nwrote {', '.join(p.name for p in written)} and meta.json in {out}")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from sb3_crowdnav.evaluation.plots import ffmpeg_available, plot_trajectories, save_animation
    from sb3_crowdnav.evaluation.runner import run_episodes

    suffix = args.out.suffix.lower()
    if suffix not in (".gif", ".mp4", ".png"):
        raise UsageError(f"--out must end in .gif, .mp4 or .png, got {str(args.out)!r}")
    if suffix == ".mp4" and not ffmpeg_available():
        raise UsageError("--out .mp4 needs ffmpeg through imageio-ffmpeg (pip install imageio-ffmpeg); or write a .gif")
    if args.fps is not None and not args.fps > 0:
        raise UsageError(f"--fps must be > 0, got {args.fps}")
    env_kwargs = _env_kwargs(args)
    _check_env(args.env, env_kwargs)
    spec = _check_policy(args.policy)
    label = _labels([spec])[0]
    record = run_episodes(spec, seeds=[args.seed], env_kwargs=env_kwargs, env_id=args.env,
                          deterministic=not args.stochastic, keep_trajectories=True, torch_threads=args.threads)[0]
    if suffix == ".png":
        plot_trajectories({label: record}, args.out, title=f"seed {args.seed}")
    else:
        save_animation(record, args.out, fps=args.fps)
    print(f"{label}, seed {args.seed}: {record.outcome} after {record.navigation_time:.2f} s -> {args.out}")
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    from sb3_crowdnav.evaluation.models import algorithms
    from sb3_crowdnav.evaluation.training import load_hyperparams, prepare, train

    if args.algo not in algorithms():
        raise UsageError(f"--algo {args.algo}: the algorithm cannot be imported in this installation")
    try:
        hp = load_hyperparams(args.hyperparams, args.env)
        cfg = prepare(args.algo, hp)
    except (FileNotFoundError, ValueError) as exc:
        raise UsageError(f"--hyperparams: {exc}") from None
    env_kwargs = {**cfg["env_kwargs"], **_env_kwargs(args)}
    _check_env(args.env, env_kwargs)
    if args.timesteps is None and cfg["n_timesteps"] is None:
        raise UsageError("give --timesteps or n_timesteps in the hyperparameter file")
    if args.imitation_episodes and args.algo not in ("ppo", "a2c", "dqn", "dqfd"):
        raise UsageError(f"--imitation-episodes is for ppo, a2c, dqn and dqfd; {args.algo} sets imitation_episodes in "
                         "its hyperparameter file")
    if args.algo == "dqfd" and not args.imitation_episodes:
        raise UsageError("--algo dqfd learns from demonstrations: give --imitation-episodes N")
    start = time.perf_counter()
    _, path = train(args.algo, hp, args.out, env_id=args.env, timesteps=args.timesteps, seed=args.seed,
                    progress_bar=_progress(args), verbose=args.verbose, env_overrides=_env_kwargs(args),
                    imitation_episodes=args.imitation_episodes, imitation_epochs=args.imitation_epochs,
                    checkpoint_freq=args.checkpoint_freq)
    config = {"algo": args.algo, "env": args.env, "hyperparams": hp, "env_kwargs": env_kwargs, "seed": args.seed,
              "timesteps": args.timesteps or cfg["n_timesteps"], "imitation_episodes": args.imitation_episodes,
              "imitation_epochs": args.imitation_epochs, "wall_time_s": round(time.perf_counter() - start, 1)}
    (Path(args.out) / "config.json").write_text(json.dumps(config, indent=2, default=str) + "\n")
    print(f"trained {args.algo} for {config['timesteps']} steps in {config['wall_time_s']} s -> {path} "
          f"(TensorBoard logs: {Path(args.out) / 'tb'})")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``sb3-crowdnav`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)

    from sb3_crowdnav.nn import configure_cpu

    configure_cpu(args.threads)  # small networks: one thread is fastest on shared cores (SPEC §7); keep freed memory
    try:
        return args.func(args)
    except UsageError as exc:
        parser.exit(2, f"sb3-crowdnav {args.command}: error: {exc}\n")
    except KeyboardInterrupt:
        parser.exit(130, "interrupted\n")


if __name__ == "__main__":
    sys.exit(main())
