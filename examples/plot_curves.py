"""Plot greedy validation curves (``eval_curve.jsonl`` written by ``examples/train_paper.py``).

    python examples/plot_curves.py paper_results/*_eval_curve.jsonl --out paper_results/learning_curve.png

Each file is one run (label = file stem); success rate and mean navigation time of successful
episodes against RL episodes, 100 greedy validation episodes per point.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("curves", type=Path, nargs="+")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_s, ax_t) = plt.subplots(1, 2, figsize=(10, 3.6))
    for path in args.curves:
        rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        rows.sort(key=lambda r: r["episodes"])
        x = [r["episodes"] for r in rows]
        label = path.stem.replace("_eval_curve", "")
        ax_s.plot(x, [r["success"] for r in rows], marker="o", label=label)
        ax_t.plot(x, [r["time"] for r in rows], marker="o", label=label)
    ax_s.set(xlabel="RL episodes", ylabel="greedy success rate", ylim=(0, 1.02))
    ax_t.set(xlabel="RL episodes", ylabel="navigation time of successes [s]")
    for ax in (ax_s, ax_t):
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
