"""Copy a trained checkpoint into the package as a shipped model (``sb3_crowdnav.pretrained(NAME)``).

    python examples/ship_model.py runs/apg_rl/best.zip apg_rl

The optimiser's momentum buffers are dropped (they only matter to continue training, and a
continued run starts from its own checkpoint); weights and every constructor setting are kept.
"""

from __future__ import annotations

import argparse
import collections
from pathlib import Path

from sb3_crowdnav.models import PRETRAINED, WEIGHTS_DIR, load_model


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", type=Path)
    p.add_argument("name", choices=sorted(PRETRAINED))
    args = p.parse_args()
    model = load_model(args.checkpoint, algo=PRETRAINED[args.name])
    model.policy.optimizer.state = collections.defaultdict(dict)
    out = WEIGHTS_DIR / f"{args.name}.zip"
    model.save(out)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
