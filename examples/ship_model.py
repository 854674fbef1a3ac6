"""Copy a trained checkpoint into the package as a shipped model (``sb3_crowdnav.pretrained(NAME)``).

    python examples/ship_model.py runs/apg_rl/best.zip apg_rl
    python examples/ship_model.py runs/apg_warehouse/best.zip apg_warehouse --pedestrian-model cautious
    python examples/ship_model.py runs/apg_warehouse/best.zip apg_warehouse --planning-depth 2
    python examples/ship_model.py runs/apg_robust/best.zip apg_robust --planning-depth 2 --planning-width 8
    python examples/ship_model.py runs/apg_warehouse/checkpoint_{6000,6500,7000,7500,8000}.zip apg_warehouse
    python examples/ship_model.py runs/a/checkpoint_7000.zip runs/b/checkpoint_6500.zip apg_warehouse --ensemble

Several checkpoints ship the mean of their weights (``sb3_crowdnav.training.average_checkpoints``: checkpoints
of one run), or with ``--ensemble`` a value ensemble, the mean of their values (``ensemble_models``: models of
different runs); either way with the first checkpoint's settings.

The optimiser's momentum buffers are dropped (they only matter to continue training, and a continued run
starts from its own checkpoint); weights and every constructor setting are kept. A ``best.zip`` is shipped
only if it is the file its ``best.json`` recorded (a damaged copy is refused). The file is read without
unpickling and written with its plain spaces and world (``sb3_crowdnav.json``); paste the printed SHA-256
into ``PRETRAINED_SHA256`` in ``sb3_crowdnav/models.py``, which checks it before every load.
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import json
from pathlib import Path

from sb3_crowdnav.evaluation.runner import with_lookahead
from sb3_crowdnav.models import PRETRAINED, WEIGHTS_DIR, load_model
from sb3_crowdnav.serialization import read_world, write_spaces
from sb3_crowdnav.training import average_checkpoints, ensemble_models


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoints", type=Path, nargs="+", metavar="checkpoint")
    p.add_argument("name", choices=sorted(PRETRAINED))
    p.add_argument("--pedestrian-model", choices=("constant_velocity", "cautious"),
                   help="ship a value model with this lookahead pedestrian model (default: the checkpoint's)")
    p.add_argument("--stopping-check", action=argparse.BooleanOptionalAction, default=None,
                   help="ship a value model with the lookahead's stopping-distance check on or off (default: the "
                        "checkpoint's)")
    p.add_argument("--planning-depth", type=int, metavar="D",
                   help="ship a value model whose lookahead searches D steps before V (default: the checkpoint's)")
    p.add_argument("--planning-width", type=int, metavar="K",
                   help="with a depth > 1, ship it searching the best K actions of each step deeper (default: the "
                        "checkpoint's)")
    p.add_argument("--ensemble", action="store_true",
                   help="several checkpoints: ship their value ensemble instead of their mean weights")
    args = p.parse_args()
    for checkpoint in args.checkpoints:
        record = checkpoint.with_name("best.json")
        if checkpoint.name == "best.zip" and record.exists():
            expected = json.loads(record.read_text()).get("sha256")
            if expected and hashlib.sha256(checkpoint.read_bytes()).hexdigest() != expected:
                p.error(f"{checkpoint} is not the file {record} recorded: damaged, not shipped")
    first = args.checkpoints[0]
    if args.ensemble and len(args.checkpoints) < 2:
        p.error("--ensemble: give two or more checkpoints")
    if len(args.checkpoints) > 1:
        if PRETRAINED[args.name] != "apg_value":
            p.error(f"checkpoint: combining several is for value models, {args.name} is {PRETRAINED[args.name]}")
        try:
            model = (ensemble_models if args.ensemble else average_checkpoints)(args.checkpoints)
        except ValueError as exc:
            p.error(str(exc))
    else:
        model = load_model(first, algo=PRETRAINED[args.name])
    model.policy.optimizer.state = collections.defaultdict(dict)
    if args.pedestrian_model:
        if not hasattr(model.policy, "set_pedestrian_model"):
            p.error(f"--pedestrian-model: {first} is not a value-lookahead model")
        model.policy.set_pedestrian_model(args.pedestrian_model)
    if args.stopping_check is not None:
        if not hasattr(model.policy, "set_stopping_check"):
            p.error(f"--stopping-check: {first} is not a value-lookahead model")
        model.policy.set_stopping_check(args.stopping_check)
    planning = {k: v for k, v in (("planning_depth", args.planning_depth), ("planning_width", args.planning_width))
                if v is not None}
    if planning:  # as evaluate's options: a depth of 1 alone drops the checkpoint's width
        try:
            with_lookahead(model, planning)
        except (TypeError, ValueError) as exc:
            p.error(f"{' / '.join('--' + k.replace('_', '-') for k in planning)}: {exc}")
    out = WEIGHTS_DIR / f"{args.name}.zip"
    model.save(out)
    # the world it was trained in, recorded with its spaces (a value model keeps its own in its policy_kwargs)
    world = None if PRETRAINED[args.name] == "apg_value" else read_world(first)
    write_spaces(out, model.observation_space, model.action_space, world=world)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB); PRETRAINED_SHA256[{args.name!r}] = "
          f"{hashlib.sha256(out.read_bytes()).hexdigest()!r}")


if __name__ == "__main__":
    main()
