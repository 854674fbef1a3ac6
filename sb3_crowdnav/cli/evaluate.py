"""``sb3-crowdnav evaluate``, ``benchmark`` and ``render``: policies on test episodes, tables and figures."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from sb3_crowdnav.cli.common import (
    UsageError,
    add_lookahead_options,
    check_crowd,
    check_env,
    check_lookahead,
    check_out,
    crowd_specs,
    env_kwargs_from_args,
    lookahead_settings,
    nonneg_int,
    positive_int,
    progress_enabled,
    single_crowd,
)
from sb3_crowdnav.cli.policy_checks import check_policy
from sb3_crowdnav.evaluation.policy_spec import GRAMMAR, PolicySpec
from sb3_crowdnav.evaluation.runner import LOOKAHEAD_KEYS, TEST_SEED_OFFSET

SAFETY_TITLE = "safety (the people's true state; min TTC capped at 10 s; see docs/evaluation.md):"


def _run_options(p: argparse.ArgumentParser, default_episodes: int = 500) -> None:
    g = p.add_argument_group("evaluation")
    g.add_argument("--episodes", type=positive_int, default=default_episodes,
                   help="number of test episodes (default: %(default)s)")
    g.add_argument("--workers", type=positive_int, default=1, help="worker processes (default: %(default)s)")
    g.add_argument("--seed-offset", type=nonneg_int, default=TEST_SEED_OFFSET,
                   help="seed of the first test episode; episode i uses seed-offset + i (default: %(default)s)")
    g.add_argument("--stochastic", action="store_true", help="sample actions instead of acting deterministically")
    g.add_argument("--allow-env-mismatch", action="store_true",
                   help="evaluate a model in another world (time step, kinematics, rotation range) than it was trained "
                        "for; refused otherwise")
    g.add_argument("--protective-field", type=_protective_field, metavar="D,CAP[,DEG]",
                   help="wrap every policy in a protective field: while an observed person's disc is within D m of the "
                        "robot's (within DEG degrees of its heading; default all around), commands faster than CAP m/s "
                        "are capped (sb3_crowdnav.safety)")
    add_lookahead_options(g, "the lookahead of every value model (APGValue) evaluated",
                          "the lookahead of every value model evaluated",
                          {**dict.fromkeys(LOOKAHEAD_KEYS, "each model's own"),
                           "pedestrian_model": "each model's own; refused when no policy is a value model"})


def _print_table(args: argparse.Namespace, table: Any, start: float, episodes: str) -> None:
    """Print the results and safety tables of ``evaluate`` / ``benchmark``, then the episodes, seeds and time."""
    print(table.to_markdown(), end="")
    print(f"\n{SAFETY_TITLE}\n\n{table.to_safety_markdown()}", end="")
    print(f"\n{args.episodes} {episodes} (seeds {args.seed_offset}-{args.seed_offset + args.episodes - 1}) "
          f"in {time.perf_counter() - start:.1f} s")
    if args.protective_field is not None:
        print(f"every policy behind a {args.protective_field}")


def _protective_field(text: str) -> Any:
    from sb3_crowdnav.safety import ProtectiveField

    try:
        return ProtectiveField.parse(text, name="value")
    except (TypeError, ValueError) as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("value must be ")) from None


def add_parsers(sub: Any, parents: list[argparse.ArgumentParser]) -> None:
    """Add ``evaluate``, ``benchmark`` and ``render`` to the subcommands ``sub``."""
    p = sub.add_parser("evaluate", parents=parents, help="evaluate one policy and print its results table",
                       description="Evaluate one policy on test episodes and print the Table-3 row "
                                   "(rates with Wilson 95 % intervals).")
    p.add_argument("--policy", required=True, help=GRAMMAR)
    _run_options(p)
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="also write results.md, results_safety.md, results.csv and episodes.csv here")
    p.set_defaults(func=_cmd_evaluate)

    p = sub.add_parser("benchmark", parents=parents, help="evaluate several policies: table + figures",
                       description="Evaluate every --policy on the same test episodes; write results.md/.csv, "
                                   "one episodes CSV per policy, trajectories.png (same seed for every policy), "
                                   "one GIF per policy, a value map for value-based models, and with --sweep "
                                   "the Table-4 sweep over the number of pedestrians. With --crowd A B ...: every "
                                   "policy in every crowd on the same seeds, one table policy x crowd "
                                   "(crowds.md/.csv) and one episodes CSV per policy and crowd, no figures.")
    p.add_argument("--policy", action="append", required=True,
                   help=f"{GRAMMAR}; repeat for several policies")
    _run_options(p)
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--sweep", type=nonneg_int, nargs="+", metavar="N",
                   help="also evaluate the first model policy (or the first policy) with N pedestrians each (Table 4)")
    p.add_argument("--figure-seed", type=nonneg_int, help="episode seed of the figures (default: --seed-offset)")
    p.add_argument("--gif", action=argparse.BooleanOptionalAction, default=None,
                   help="write GIFs (default: yes; not with --crowd)")
    p.set_defaults(func=_cmd_benchmark)

    p = sub.add_parser("render", parents=parents, help="draw one episode as GIF, MP4 or PNG",
                       description="Play one episode and write it as an animation (.gif, or .mp4 with "
                                   "imageio-ffmpeg) or as a trajectory figure (.png).")
    p.add_argument("--policy", required=True, help=GRAMMAR)
    p.add_argument("--seed", type=nonneg_int, default=TEST_SEED_OFFSET, help="episode seed (default: %(default)s)")
    p.add_argument("--out", type=Path, required=True, metavar="FILE", help="episode.gif, episode.mp4 or episode.png")
    p.add_argument("--fps", type=float, help="frames per second of an animation (default: real time, 1/Δt)")
    p.add_argument("--stochastic", action="store_true", help="sample actions instead of acting deterministically")
    p.add_argument("--allow-env-mismatch", action="store_true",
                   help="render a model in another world than it was trained for")
    p.set_defaults(func=_cmd_render)



# ------------------------------------------------------------------ helpers
def _labels(specs: list[Any]) -> list[str]:
    """One distinct table label per policy (or crowd): ``APG_RL``, ``APG_RL_2``, ..."""
    labels: list[str] = []
    for spec in specs:
        label, k = spec.label, 2
        while label in labels:
            label, k = f"{spec.label}_{k}", k + 1
        labels.append(label)
    return labels


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in label)


def _run(args: argparse.Namespace, spec: PolicySpec, env_kwargs: dict[str, Any], csv: Path | None,
         journals: list, **kwargs: Any):
    """The records of ``spec`` on the run's episodes. With ``csv`` (the episodes file the run writes), each finished
    episode is kept in its journal as it ends, a journal of an interrupted run of the same settings is resumed, the
    CSV is written at the end, and the journal is added to ``journals``, which the command removes once all its files
    are written (:mod:`~sb3_crowdnav.evaluation.journal`): a killed command resumes each of its runs."""
    from sb3_crowdnav.evaluation.journal import EpisodeJournal, journal_path
    from sb3_crowdnav.evaluation.runner import run_episodes
    from sb3_crowdnav.evaluation.tables import write_records_csv
    from sb3_crowdnav.version import __version__

    lookahead = lookahead_settings(args, spec)
    journal, played = None, {}
    if csv is not None:
        settings = {"env": args.env, "env_kwargs": env_kwargs, "episodes": args.episodes,
                    "seed_offset": args.seed_offset, "deterministic": not args.stochastic,
                    "protective_field": str(args.protective_field) if args.protective_field else None,
                    "lookahead": lookahead, "policy": str(spec), "policy_sha256": spec.file_sha256(),
                    "sb3_crowdnav": __version__}
        journal = EpisodeJournal(journal_path(csv), settings)
        try:
            played = journal.played()
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        if played:
            print(f"resuming: {len(played)} of the {args.episodes} episodes of {spec} kept from {journal.path}",
                  file=sys.stderr)
    records = run_episodes(spec, args.episodes, env_kwargs, env_id=args.env, seed_offset=args.seed_offset,
                           allow_env_mismatch=args.allow_env_mismatch, protective_field=args.protective_field,
                           lookahead=lookahead, workers=args.workers, deterministic=not args.stochastic,
                           progress=progress_enabled(args), torch_threads=args.threads, played=played,
                           on_record=journal.append if journal is not None else None, **kwargs)
    if csv is not None:
        write_records_csv(records, csv)
        journals.append(journal)
    return records


def _write_meta(out: Path, args: argparse.Namespace, env_kwargs: dict, specs: dict[str, PolicySpec], **extra) -> None:
    from sb3_crowdnav.version import __version__

    meta = {"command": args.command, "env": args.env, "env_kwargs": env_kwargs, "episodes": args.episodes,
            "seeds": [args.seed_offset, args.seed_offset + args.episodes - 1], "deterministic": not args.stochastic,
            "confidence_intervals": "Wilson score, 95 %", "sb3_crowdnav": __version__,
            "protective_field": str(args.protective_field) if args.protective_field else None,
            "lookahead": lookahead_settings(args), "policies": {label: str(spec) for label, spec in specs.items()},
            "policy_sha256": {label: spec.file_sha256() for label, spec in specs.items()}, **extra}
    (out / "meta.json").write_text(json.dumps(meta, indent=2, default=str) + "\n")


# ------------------------------------------------------------------ commands
def _cmd_evaluate(args: argparse.Namespace) -> int:
    from sb3_crowdnav.evaluation.metrics import summarize
    from sb3_crowdnav.evaluation.tables import results_table

    env_kwargs = env_kwargs_from_args(args)
    check_env(args.env, env_kwargs, single_crowd(args))
    spec = check_policy(args.policy, args.env, env_kwargs, args.allow_env_mismatch)
    check_lookahead(args, [spec])
    if args.out is not None:
        check_out(args.out)
    label = _labels([spec])[0]
    start = time.perf_counter()
    journals: list = []
    records = _run(args, spec, env_kwargs, args.out / "episodes.csv" if args.out is not None else None, journals)
    table = results_table({label: summarize(records)})
    _print_table(args, table, start, "episodes")
    if args.out is not None:
        table.save(args.out / "results")
        _write_meta(args.out, args, env_kwargs, {label: spec})
    _finish(journals)
    return 0


def _finish(journals: list) -> None:
    """Remove a command's journals: every file it writes is written."""
    for journal in journals:
        journal.finish()


def _figure_episodes(args, specs, labels, env_kwargs, seed):
    from sb3_crowdnav.evaluation.runner import run_episodes

    return {label: run_episodes(spec, seeds=[seed], env_kwargs=env_kwargs, env_id=args.env,
                                allow_env_mismatch=args.allow_env_mismatch, protective_field=args.protective_field,
                                lookahead=lookahead_settings(args, spec), deterministic=not args.stochastic,
                                keep_trajectories=True, torch_threads=args.threads)[0]
            for spec, label in zip(specs, labels, strict=True)}


def _value_map(args, spec: PolicySpec, label: str, env_kwargs: dict[str, Any], seed: int, out: Path) -> Path | None:
    """Fig. 11 for a value-based model: the action values at the 8th step (2 s) of the figure episode."""
    import numpy as np

    from sb3_crowdnav.evaluation.plots import plot_value_map
    from sb3_crowdnav.evaluation.runner import make_env, make_policy

    env = make_env(args.env, env_kwargs)
    try:
        model = make_policy(spec, env, args.allow_env_mismatch, lookahead=lookahead_settings(args, spec))
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
    from sb3_crowdnav.evaluation.tables import results_table, sweep_table

    if args.crowd:
        return _crowd_benchmark(args)
    env_kwargs = env_kwargs_from_args(args)
    check_env(args.env, env_kwargs)
    specs = [check_policy(p, args.env, env_kwargs, args.allow_env_mismatch) for p in args.policy]
    check_lookahead(args, specs)
    for n in args.sweep or ():  # every crowd of the sweep can be made
        try:
            check_env(args.env, {**env_kwargs, "num_humans": n, "max_humans": max(max(args.sweep), 1)})
        except UsageError as exc:
            raise UsageError(f"--sweep {n}: {exc}") from None
    check_out(args.out)
    labels = _labels(specs)
    if args.sweep and max(args.sweep) > 0 and "num_humans" in env_kwargs:
        print("note: --sweep sets the number of pedestrians; --humans applies to the main table only", file=sys.stderr)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    summaries, journals = {}, []
    for spec, label in zip(specs, labels, strict=True):
        records = _run(args, spec, env_kwargs, out / f"episodes_{_slug(label)}.csv", journals, desc=label)
        summaries[label] = summarize(records)
    table = results_table(summaries)
    table.save(out / "results")
    _print_table(args, table, start, "episodes per policy")

    written = [out / "results.md", out / "results.csv", out / "results_safety.md",
               *(out / f"episodes_{_slug(label)}.csv" for label in labels)]
    seed = args.seed_offset if args.figure_seed is None else args.figure_seed
    episodes = _figure_episodes(args, specs, labels, env_kwargs, seed)
    written.append(plot_trajectories(episodes, out / "trajectories.png", title=f"test episode seed {seed}"))
    if args.gif is not False:
        for label, record in episodes.items():
            written.append(save_animation(record, out / f"episode_{_slug(label)}.gif"))
    for spec, label in zip(specs, labels, strict=True):
        if spec.is_model:
            path = _value_map(args, spec, label, env_kwargs, seed, out)
            if path is not None:
                written.append(path)

    if args.sweep:
        idx = next((i for i, s in enumerate(specs) if s.is_model), 0)
        sweep = run_sweep(specs[idx], args.sweep, args.episodes, env_kwargs, env_id=args.env,
                          allow_env_mismatch=args.allow_env_mismatch, lookahead=lookahead_settings(args, specs[idx]),
                          protective_field=args.protective_field,
                          seed_offset=args.seed_offset, workers=args.workers, deterministic=not args.stochastic,
                          progress=progress_enabled(args), torch_threads=args.threads)
        stable = sweep_table({n: summarize(r) for n, r in sweep.items()})
        stable.save(out / "sweep")
        print(f"\nnumber of pedestrians, {labels[idx]} (Table 4):\n")
        print(stable.to_markdown(), end="")
        written += [out / "sweep.md", out / "sweep.csv"]
    _write_meta(out, args, env_kwargs, dict(zip(labels, specs, strict=True)), figure_seed=seed, sweep=args.sweep)
    _finish(journals)
    print(f"\nwrote {', '.join(p.name for p in written)} and meta.json in {out}")
    return 0


def _crowd_benchmark(args: argparse.Namespace) -> int:
    """``benchmark --crowd A B ...``: every policy in every crowd on the same seeds, one table policy x crowd."""
    from sb3_crowdnav.evaluation.metrics import summarize
    from sb3_crowdnav.evaluation.tables import crowd_table

    # a sweep and figures are of one crowd: the table across crowds would not say which
    for option, given in (("--sweep", args.sweep), ("--figure-seed", args.figure_seed is not None),
                          ("--gif" if args.gif else "--no-gif", args.gif is not None)):
        if given:
            raise UsageError(f"{option} does not go with --crowd, which writes the policy x crowd table only (no figures, "
                             "no sweep); for those in one crowd run benchmark without --crowd and with --env-kwargs "
                             "\"dict(crowd='NAME')\"")
    env_kwargs = env_kwargs_from_args(args, crowd=False)
    check_env(args.env, env_kwargs)
    crowds = crowd_specs(args)
    crowd_kwargs = {label: check_crowd(args.env, env_kwargs, crowd)
                    for crowd, label in zip(crowds, _labels(crowds), strict=True)}
    specs = [check_policy(p, args.env, env_kwargs, args.allow_env_mismatch) for p in args.policy]
    check_lookahead(args, specs)
    check_out(args.out)
    labels = _labels(specs)
    out: Path = args.out
    start = time.perf_counter()
    summaries, written, journals = {}, [], []
    for spec, label in zip(specs, labels, strict=True):
        for crowd, kwargs in crowd_kwargs.items():
            csv = out / f"episodes_{_slug(label)}_{_slug(crowd)}.csv"
            summaries[(label, crowd)] = summarize(_run(args, spec, kwargs, csv, journals, desc=f"{label} in {crowd}"))
            written.append(csv)
    table = crowd_table(summaries)
    written[:0] = table.save(out / "crowds")
    print(table.to_markdown(), end="")
    print(f"\n{args.episodes} episodes per policy and crowd (seeds {args.seed_offset}-"
          f"{args.seed_offset + args.episodes - 1}) in {time.perf_counter() - start:.1f} s")
    if args.protective_field is not None:
        print(f"every policy behind a {args.protective_field}")
    _write_meta(out, args, env_kwargs, dict(zip(labels, specs, strict=True)),
                crowds={label: str(crowd) for label, crowd in zip(crowd_kwargs, crowds, strict=True)})
    _finish(journals)
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
    if args.fps is not None and not 0.1 <= args.fps <= 60:
        raise UsageError(f"--fps must be in [0.1, 60] frames per second, got {args.fps}")
    env_kwargs = env_kwargs_from_args(args)
    check_env(args.env, env_kwargs, single_crowd(args))
    spec = check_policy(args.policy, args.env, env_kwargs, args.allow_env_mismatch)
    check_out(args.out, is_file=True)
    label = _labels([spec])[0]
    record = run_episodes(spec, seeds=[args.seed], env_kwargs=env_kwargs, env_id=args.env,
                          allow_env_mismatch=args.allow_env_mismatch,
                          deterministic=not args.stochastic, keep_trajectories=True, torch_threads=args.threads)[0]
    if suffix == ".png":
        plot_trajectories({label: record}, args.out, title=f"seed {args.seed}")
    else:
        save_animation(record, args.out, fps=args.fps)
    print(f"{label}, seed {args.seed}: {record.outcome} after {record.navigation_time:.2f} s -> {args.out}")
    return 0
