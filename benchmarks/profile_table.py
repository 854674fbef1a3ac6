"""Where the acting thread's time goes during ``learn()``: a table from a py-spy raw profile.

    py-spy record --format raw --threads --rate 200 -o prof.raw -- \\
        python benchmarks/training_speed.py --overlap --epsilon 0.1 --from-pretrained apg_rl --rl-steps 3000
    python benchmarks/profile_table.py prof.raw

Samples of the main thread inside ``learn`` are put in the first bucket whose marker appears in the stack
(innermost first); the learner thread's samples are counted beside them.
"""

from __future__ import annotations

import argparse
import collections

BUCKETS = [  # (label, markers in the stack), first match wins, checked from the innermost frame outwards
    ("decision: V forward on the B x 80 propagated states", ("ValueNetwork.forward",)),
    ("decision: propagation model (numpy)", ("PropagationModel.__call__",)),
    ("decision: lookahead glue (tensors, argmax)", ("lookahead (", "action_values (")),
    ("waiting for the learner (join)", ("_join_learner", "Future.result", "wait (threading", "_reply (")),
    ("sending batches to the learner process", ("ProcessLearner.submit", "_as_numpy")),
    ("TD targets / batch sampling in the acting thread", ("batch_target", "_sample_batches", "td_target")),
    ("env step (simulator, ORCA, observation)", ("CrowdNavEnv.step", "step_wait")),
    ("replay buffer writes", ("_store_transition", "ReplayBuffer.add", ".add (sb3_crowdnav/apg_value/buffers")),
    ("SB3 loop, callbacks, logging", ("collect_rollouts", ".learn (")),
]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("raw")
    args = p.parse_args()
    acting, learner = collections.Counter(), 0
    for line in open(args.raw).read().splitlines():
        stack, _, count = line.rpartition(" ")
        frames = stack.split(";")
        if "apg-learner" in frames[0]:
            learner += int(count)
            continue
        if "MainThread" not in frames[0] or not any(".learn (" in f for f in frames):
            continue
        text = ";".join(reversed(frames))
        label = next((label for label, markers in BUCKETS if any(m in text for m in markers)), "other")
        acting[label] += int(count)
    total = sum(acting.values())
    print(f"acting thread inside learn(): {total} samples; learner thread: {learner} samples")
    print("| where the acting thread is | share |")
    print("|---|---|")
    for label, _ in [*BUCKETS, ("other", ())]:
        if acting[label]:
            print(f"| {label} | {acting[label] / total:.1%} |")


if __name__ == "__main__":
    main()
