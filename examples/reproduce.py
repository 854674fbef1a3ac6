"""Regenerate the paper's Tables 3-5 and figures from the shipped models (`make reproduce`).

    python examples/reproduce.py [--episodes 500] [--out results] [--workers 2]

Writes into OUT: `table3.md` (every shipped method + ORCA, with the paper's numbers beside ours),
`table4.md` (APG_RL trained with 6 pedestrians, tested with 3-10), `table5.md` (APG_RL / APG_CRL /
APG_CARL: time, three readings of the gap, comfort-zone time, heading change), the benchmark folder of `sb3-crowdnav benchmark`
(per-episode CSVs, trajectories.png, value maps, GIFs) and `learning_curves.png` when the
training logs are given with `--logs`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sb3_crowdnav import available_pretrained
from sb3_crowdnav.evaluation import results_table, run_episodes, run_sweep, summarize, sweep_table
from sb3_crowdnav.evaluation.plots import plot_learning_curves, plot_trajectories

# the paper's Tables 3-5 (500 tests, 6 pedestrians)
PAPER_T3 = {  # method: (success, collision, time, return, gap)
    "ORCA": (0.33, 0.66, 11.03, -0.0652, None),
    "CADRL": (0.59, 0.40, 10.68, 0.0738, None),
    "SF_RL": (0.96, 0.03, 11.86, 0.2608, None),
    "LM_RL": (0.99, 0.01, 10.97, 0.3190, None),
    "APG_RL": (0.99, 0.01, 10.81, 0.3196, 0.14),
    "APG_CRL": (0.99, 0.01, 10.96, None, 0.64),
    "APG_CARL": (0.99, 0.01, 10.77, None, 0.50),
}
PAPER_T4 = {3: (1.00, 10.20), 4: (1.00, 10.18), 5: (0.99, 10.81), 6: (0.99, 10.82), 7: (0.98, 12.30), 8: (0.91, 12.75)}
ORDER = ["apg_rl", "apg_crl", "apg_carl", "lm_rl", "sf_rl", "cadrl", "ppo_apg", "dqn_apg"]


def _fmt(x, digits=2):
    return "–" if x is None else f"{x:.{digits}f}"


def table3(summaries: dict) -> str:
    lines = ["| method | success (ours / paper) | collision | time [s] | return | gap [m] | heading change [rad] |",
             "|---|---|---|---|---|---|---|"]
    for name, s in summaries.items():
        p = PAPER_T3.get(name, (None,) * 5)
        lines.append(
            f"| {name} | {s.success_rate:.3f} / {_fmt(p[0])} | {s.collision_rate:.3f} / {_fmt(p[1])} | "
            f"{_fmt(s.navigation_time)} / {_fmt(p[2])} | {s.discounted_return:.4f} / {_fmt(p[3], 4)} | "
            f"{_fmt(s.min_separation)} / {_fmt(p[4])} | {_fmt(s.heading_change)} |")
    return "\n".join(lines)


def table5(summaries: dict) -> str:
    """The comfort variants: the paper's "gap" beside our episode minimum and the two in-zone averages.

    The paper's 0.14 m (APG_RL) is below the 0.2 m discomfort distance and its 0.64 / 0.50 m (APG_CRL /
    APG_CARL) fit inside the 0.7 m-wide comfort zone: they read as averages over the steps inside a zone (the
    field's "average min separate distance in danger"), so all three of ours are shown.
    """
    lines = ["| method | success (ours / paper) | time [s] (ours / paper) | gap: episode min [m] | "
             "gap: mean in discomfort [m] | gap: mean in comfort zones [m] | paper gap [m] | "
             "time in comfort zones [s] | heading change [rad] | sharp turns (>= π/2) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, s in summaries.items():
        p = PAPER_T3.get(name, (None,) * 5)
        lines.append(
            f"| {name} | {s.success_rate:.3f} / {_fmt(p[0])} | {_fmt(s.navigation_time)} / {_fmt(p[2])} | "
            f"{_fmt(s.min_separation)} | {_fmt(s.discomfort_separation)} | {_fmt(s.comfort_zone_separation)} | "
            f"{_fmt(p[4])} | {_fmt(s.comfort_zone_time)} | {_fmt(s.heading_change)} | {_fmt(s.sharp_turns)} |")
    return "\n".join(lines)


def table4(summaries: dict) -> str:
    lines = ["| N | success (ours / paper) | collision | time [s] (ours / paper) |", "|---|---|---|---|"]
    for n, s in summaries.items():
        p = PAPER_T4.get(n, (None, None))
        lines.append(f"| {n} | {s.success_rate:.3f} / {_fmt(p[0])} | {s.collision_rate:.3f} | "
                     f"{_fmt(s.navigation_time)} / {_fmt(p[1])} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=500)
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--sweep", type=int, nargs="+", default=[3, 4, 5, 6, 7, 8, 10])
    p.add_argument("--logs", type=Path, nargs="*", default=[], help="TensorBoard run folders for the learning curves")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    shipped = [n for n in ORDER if n in available_pretrained()]
    specs = {"ORCA": "orca", **{n.upper(): f"pretrained:{n}" for n in shipped}}

    records, summaries = {}, {}
    for name, spec in specs.items():
        records[name] = run_episodes(spec, args.episodes, workers=args.workers)
        summaries[name] = summarize(records[name])
        print(f"{name}: success {summaries[name].success_rate:.3f}", flush=True)
    results_table(summaries).save(args.out / "table3_full")
    (args.out / "table3.md").write_text(table3(summaries) + "\n")

    if "apg_rl" in shipped:
        sweep = run_sweep("pretrained:apg_rl", args.sweep, args.episodes, workers=args.workers)
        sweep_summaries = {n: summarize(r) for n, r in sweep.items()}
        sweep_table(sweep_summaries).save(args.out / "table4_full")
        (args.out / "table4.md").write_text(table4(sweep_summaries) + "\n")
    comfort = {k: v for k, v in summaries.items() if k.startswith("APG_")}
    if comfort:
        (args.out / "table5.md").write_text(table5(comfort) + "\n")

    seed = 1_000_000
    figs = {name: run_episodes(spec, 1, seeds=[seed], keep_trajectories=True)[0] for name, spec in specs.items()}
    plot_trajectories(figs, args.out / "trajectories.png")
    if args.logs:
        plot_learning_curves({Path(d).name: d for d in args.logs}, args.out / "learning_curves.png")
    for f in ("table3.md", "table4.md", "table5.md"):
        if (args.out / f).exists():
            print(f"\n## {f}\n" + (args.out / f).read_text())


if __name__ == "__main__":
    main()
