"""Where and why a policy fails: every collision classified at its colliding step, every timeout by what the robot saw.

    python examples/failure_analysis.py --policy pretrained:apg_rl --crowd social_force --episodes 100 --out runs/fail
    python examples/failure_analysis.py --env CrowdNavWarehouse-v0 --policy pretrained:apg_warehouse_paper --episodes 100 \\
        --env-kwargs "dict(actions='paper', max_acceleration=None, max_turn_rate=None, robot_visible=False, \\
                      occlusion=False, people_sensor_range=None)" --out runs/fail_warehouse

Every ``--policy`` (a spec as for ``sb3-crowdnav evaluate``; repeat for several) plays the same test episodes (seeds
1,000,000 + i) of ``--env`` with the env options and the one ``--crowd`` of ``sb3-crowdnav evaluate``
(:mod:`sb3_crowdnav.evaluation.failures` has the rules). ``OUT/failures.md`` has one section per policy: the collisions
with people by who closes on whom x the person's side, the shares seen, seen for the warning, avoidable in the
colliding step and with the warning (Wilson 95 % intervals), the obstacle collisions (the warehouse) and the timeouts
with nobody in view. ``OUT/failures.json`` has the same summaries and every failed episode's record, and
``OUT/collisions_LABEL.png`` the last seconds of one collision per most frequent class. Bad input exits with status 2
and one line, before any episode.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import Counter
from dataclasses import asdict
from pathlib import Path
from typing import Any

from sb3_crowdnav.cli.common import (
    Parser,
    UsageError,
    check_env,
    check_out,
    env_kwargs_from_args,
    env_options,
    nonneg_int,
    positive_float,
    positive_int,
    single_crowd,
)
from sb3_crowdnav.evaluation.failures import (
    CLOSERS,
    SIDES,
    FailureRecord,
    FailureRules,
    FailureSummary,
    analyse_episodes,
    summarize_failures,
)
from sb3_crowdnav.evaluation.plots import plot_collisions
from sb3_crowdnav.evaluation.policy_spec import PolicySpec
from sb3_crowdnav.evaluation.runner import DEFAULT_ENV_ID, TEST_SEED_OFFSET, make_env, make_policy
from sb3_crowdnav.training.callbacks import VALIDATION_SEED_OFFSET

SHARES = {  # the rows of the shares table: key of FailureSummary.shares -> what it counts
    "person_faster": "the person closing faster than the robot (not already overlapping)",
    "person": "closer: the person (more than 60 % of the closing speed)",
    "behind": "the person behind the robot (bearing above 135°)",
    "seen": "seen in the observation the robot acted on",
    "seen_warned": "seen for at least the warning ({warning:g} s)",
    "sees_robot": "the person sees the robot (avoids it in their crowd model)",
    "avoidable": "avoidable in the colliding step (some action)",
    "avoidable_with_warning": "avoidable with {warning:g} s of warning (a held or turn-then-straight plan)",
}


def check_policy(spec: str, env_id: str, env_kwargs: dict[str, Any], allow_env_mismatch: bool) -> PolicySpec:
    """The parsed spec, its policy made once in the env (a missing file, another world, other shapes: usage errors)."""
    try:
        parsed = PolicySpec.parse(spec, name="--policy")
        env = make_env(env_id, env_kwargs)
        try:
            make_policy(parsed, env, allow_env_mismatch)
        finally:
            env.close()
    except (TypeError, ValueError, OSError) as exc:
        raise UsageError(f"--policy {spec}: {exc}") from None
    return parsed


def share_text(share: Any) -> str:
    if not share.total:
        return "-"
    return f"{share.value:.2f} [{share.low:.2f}, {share.high:.2f}]"


def section(label: str, summary: FailureSummary, rules: FailureRules, figure: str | None) -> str:
    """One policy's Markdown: the closer x side table, the shares, obstacles, timeouts and the figure."""
    s = summary.shares
    lines = [f"## {label}", "", f"{summary.episodes} episodes: collisions {s['collision'].count} "
             f"({share_text(s['collision'])}), of them {summary.obstacle_collisions} with racks or walls; timeouts "
             f"{summary.timeouts} ({share_text(s['timeout'])}).", ""]
    if summary.collisions:
        lines += [f"Collisions with people ({summary.collisions}) by who closes on whom (rows) and the person's side "
                  "(columns):", "", "| closer \\ side | " + " | ".join(SIDES) + " | all |",
                  "|---|" + "---|" * (len(SIDES) + 1)]
        for closer in CLOSERS:
            row = [summary.table[closer][side] for side in SIDES]
            lines.append(f"| {closer} | " + " | ".join(map(str, row)) + f" | {sum(row)} |")
        columns = [sum(summary.table[c][side] for c in CLOSERS) for side in SIDES]
        lines += ["| all | " + " | ".join(map(str, columns)) + f" | {summary.collisions} |", "",
                  "| of the collisions with people | count | share [95 % interval] |", "|---|---|---|"]
        lines += [f"| {text.format(warning=rules.warning)} | {s[key].count} / {s[key].total} | {share_text(s[key])} |"
                  for key, text in SHARES.items()]
        lines += ["", f"The robot's speed in the colliding step: {summary.robot_speed:.2f} m/s (median).", ""]
    if summary.obstacle_collisions:
        lines += [f"Collisions with racks or walls: {summary.obstacle_collisions}, mean clearance "
                  f"{summary.obstacle_clearance:.3f} m; avoidable in the step {share_text(s['obstacle_avoidable'])}, "
                  f"with {rules.warning:g} s of warning {share_text(s['obstacle_avoidable_with_warning'])}.", ""]
    if summary.timeouts:
        nobody = s["nobody_in_view"]
        lines += [f"Timeouts: {summary.timeouts}; nobody in view for the last {rules.blind_window:g} s: {nobody.count} "
                  f"/ {nobody.total} ({share_text(nobody)}); distance left to the goal {summary.distance_left:.2f} m "
                  "(mean).", ""]
    if figure:
        lines += [f"![typical collisions of {label}]({figure})", "",
                  f"The last {rules.clip:g} s of one collision per most frequent class (red cross: where the discs "
                  "touch; numbers: seconds from the clip's start).", ""]
    return "\n".join(lines)


def figure(records: list[FailureRecord], path: Path, panels: int, label: str) -> bool:
    """The first collision (lowest seed) of each of the ``panels`` most frequent classes; False without any."""
    collisions = [r for r in records if r.collision is not None]
    if not collisions or not panels:
        return False
    kind = {id(r): ("obstacle", "") if r.collision.hit == "obstacle" else (r.collision.closer, r.collision.side)
            for r in collisions}
    counts = Counter(kind.values())
    clips = {}
    for cls, count in counts.most_common(panels):
        r = next(r for r in collisions if kind[id(r)] == cls)
        c = r.collision
        what = "rack or wall" if cls[0] == "obstacle" else f"{c.closer} closes, {c.side}"
        seen = "" if cls[0] == "obstacle" else f", {'seen' if c.seen else 'unseen'}"
        avoid = "avoidable" if c.avoidable else "avoidable with warning" if c.avoidable_with_warning else "unavoidable"
        clips[f"{what} ({count} of {len(collisions)})\nseed {r.seed}{seen}, {avoid}"] = (r.clip, c.contact)
    plot_collisions(clips, path, title=f"{label}: typical collisions")
    return True


def plain(value: Any) -> Any:
    """``value`` with NaN and infinities as None (strict JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def parse(argv: list[str] | None) -> tuple[argparse.Namespace, str, dict[str, Any], FailureRules, list[PolicySpec]]:
    p = Parser(prog="failure_analysis.py", description=__doc__, parents=[env_options()],
               formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", action="append", required=True, metavar="SPEC", help="a policy spec (repeat)")
    p.add_argument("--episodes", type=positive_int, default=100, help="test episodes per policy (default: 100)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--workers", type=positive_int, default=1, help="worker processes (default: 1)")
    p.add_argument("--seed-offset", type=nonneg_int, default=TEST_SEED_OFFSET, help="seed of the first episode")
    p.add_argument("--allow-env-mismatch", action="store_true", help="run a model in another world than its own")
    p.add_argument("--warning", type=positive_float, default=1.0, help="[s] of the second avoidability test (1)")
    p.add_argument("--blind-window", type=positive_float, default=5.0, help="[s] nobody in view in a timeout (5)")
    p.add_argument("--figures", type=nonneg_int, default=4, help="panels of typical collisions per policy (4; 0: none)")
    args = p.parse_args(argv)
    env_id = args.env or DEFAULT_ENV_ID
    try:
        kwargs = env_kwargs_from_args(args)
        check_env(env_id, kwargs, single_crowd(args))
        check_out(args.out)
        rules = FailureRules(warning=args.warning, blind_window=args.blind_window)
        specs = [check_policy(spec, env_id, kwargs, args.allow_env_mismatch) for spec in args.policy]
    except (UsageError, ValueError) as exc:
        p.error(str(exc))
    return args, env_id, kwargs, rules, specs


def main(argv: list[str] | None = None) -> None:
    args, env_id, kwargs, rules, specs = parse(argv)
    from sb3_crowdnav.nn import configure_cpu

    configure_cpu(num_threads=1)
    sections, report = [], {"env": env_id, "env_kwargs": kwargs, "episodes": args.episodes,
                            "seed_offset": args.seed_offset, "rules": asdict(rules), "policies": {}}
    labels = Counter()
    for text, spec in zip(args.policy, specs, strict=True):
        labels[spec.label] += 1
        label = spec.label if labels[spec.label] == 1 else f"{spec.label}_{labels[spec.label]}"
        records = analyse_episodes(spec, args.episodes, kwargs, env_id=env_id, workers=args.workers, rules=rules,
                                   seed_offset=args.seed_offset, allow_env_mismatch=args.allow_env_mismatch)
        summary = summarize_failures(records, rules)
        name = f"collisions_{''.join(c if c.isalnum() or c in '-_' else '_' for c in label)}.png"
        drawn = figure(records, args.out / name, args.figures, label)
        sections.append(section(label, summary, rules, name if drawn else None))
        print(sections[-1], flush=True)
        report["policies"][label] = {"policy": text, "summary": asdict(summary),
                                     "failures": [r.to_dict() for r in records if r.outcome != "success"]}
    kind = {TEST_SEED_OFFSET: "test ", VALIDATION_SEED_OFFSET: "validation "}.get(args.seed_offset, "")
    head = (f"# Failure analysis\n\n`{env_id}` with {kwargs or 'its defaults'}, {args.episodes} {kind}episodes per "
            f"policy (seeds {args.seed_offset:,} + i); written by `examples/failure_analysis.py` "
            "(the rules: `sb3_crowdnav.evaluation.failures`).\n\n")
    (args.out / "failures.md").write_text(head + "\n".join(sections))
    (args.out / "failures.json").write_text(json.dumps(plain(report), indent=1, default=str) + "\n")
    print(f"wrote {args.out / 'failures.md'} and failures.json")


if __name__ == "__main__":
    main()
