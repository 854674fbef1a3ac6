"""Train one of the paper's variants with its schedule, from Python.

    python examples/train_paper.py --variant apg_rl --out runs/apg_rl   # 3,000 IL + 10,000 RL episodes (~1 h)
    python examples/train_paper.py --variant apg_rl --out runs/apg_rl   # run again: resumes from the last checkpoint

This is ``sb3-crowdnav train --variant apg_rl --out runs/apg_rl`` written with the Python API
(:func:`sb3_crowdnav.training.train_schedule`); every knob of the schedule is a field of
:class:`~sb3_crowdnav.training.ScheduleConfig`, and the command line has them all
(``sb3-crowdnav train --help``). A long run belongs in the background, started from a frozen copy
of the code if you keep editing it: ``nohup python examples/train_paper.py ... > run.log 2>&1 &``.
"""

from __future__ import annotations

import argparse
import sys

from sb3_crowdnav.training import VARIANTS, ScheduleConfig, train_schedule


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variant", choices=sorted(VARIANTS), default="apg_rl")
    p.add_argument("--out", required=True, help="run folder")
    p.add_argument("--rl-episodes", type=int, default=10_000)
    p.add_argument("--il-episodes", type=int, default=3_000)
    p.add_argument("--checkpoint-episodes", type=int, default=500)
    p.add_argument("--eval-episodes", type=int, default=100)
    args = p.parse_args(argv)
    try:
        config = ScheduleConfig(variant=args.variant, rl_episodes=args.rl_episodes, imitation_episodes=args.il_episodes,
                                checkpoint_episodes=args.checkpoint_episodes, eval_episodes=args.eval_episodes)
    except (TypeError, ValueError) as exc:
        p.error(str(exc))
    result = train_schedule(args.out, config)
    return 0 if result.stopped_by is None else 128 + result.stopped_by


if __name__ == "__main__":
    sys.exit(main())
