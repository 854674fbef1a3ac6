"""`make demo`: the shipped APG model against ORCA (and PPO with the APG extractor, when shipped).

Runs the test protocol on the default `CrowdNav-v0` (6 pedestrians, invisible robot) and writes
`demo_output/results.md` (+ `.csv`), `demo_output/trajectories.png` and one GIF per policy.

    python examples/demo.py [--episodes 100] [--out demo_output]
"""

from __future__ import annotations

import argparse

from sb3_crowdnav import available_pretrained
from sb3_crowdnav.cli import main as cli


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--out", default="demo_output")
    args = p.parse_args()
    shipped = [name for name in ("apg_rl", "ppo_apg") if name in available_pretrained()]
    if not shipped:
        print("no trained model is shipped in this version: the demo runs the ORCA robot only")
    policies = ["orca", *(f"pretrained:{name}" for name in shipped)]
    argv = ["benchmark", "--episodes", str(args.episodes), "--out", args.out, "--workers", "2", "--no-progress"]
    for policy in policies:
        argv += ["--policy", policy]
    cli(argv)


if __name__ == "__main__":
    main()
