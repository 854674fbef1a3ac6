"""Decision time of an exported graph in ONNX Runtime beside the PyTorch model's, one thread each, in the same run.

Usage: python benchmarks/onnx_latency.py [--models apg_rl ...] [--decisions 200] [--batch 64] [--batches 20]
    [--optimization all|extended|basic|disabled] [--graphs DIR]

For every shipped model (default) on observations of test episodes of its world (an ORCA robot driving): the median
time of one decision for one observation (``predict(obs)``, what a robot's loop calls) and for a batch of ``--batch``
observations, PyTorch's ``model.predict(..., deterministic=True)`` (one torch thread, :func:`configure_cpu`) and
``OnnxPolicy.predict`` (one ONNX Runtime thread), the two timed alternately so that a change of the machine's speed
hits both. Prints the medians and PyTorch / ONNX Runtime (> 1: ONNX Runtime is faster).
Graphs are exported into ``--graphs`` (default: a temporary folder), or read from it when already there.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from lookahead_speed import observations  # (this folder: the script's own path comes first on sys.path)

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.deploy import OnnxPolicy, export_onnx
from sb3_crowdnav.deploy.runtime import OPTIMIZATION_LEVELS
from sb3_crowdnav.evaluation.runner import TEST_SEED_OFFSET
from sb3_crowdnav.models import available_pretrained, check_pretrained, pretrained, pretrained_env
from sb3_crowdnav.nn import configure_cpu


def timed(policy, obs) -> float:
    start = time.perf_counter()
    policy.predict(obs, deterministic=True)
    return time.perf_counter() - start


def medians(model, graph: OnnxPolicy, batches: list[dict[str, np.ndarray]], single: bool) -> tuple[float, float]:
    """Median decision times [ms] of PyTorch and ONNX Runtime, alternating."""
    torch_times, onnx_times = [], []
    for batch in batches:
        obs = {k: v[0] for k, v in batch.items()} if single else batch
        for _ in range(2):  # the second call of each is timed: the first may warm caches the other one cooled
            torch_time = timed(model, obs)
            onnx_time = timed(graph, obs)
        torch_times.append(torch_time)
        onnx_times.append(onnx_time)
    return statistics.median(torch_times) * 1e3, statistics.median(onnx_times) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=available_pretrained(), choices=available_pretrained())
    parser.add_argument("--decisions", type=int, default=200, help="single-observation decisions per model")
    parser.add_argument("--batch", type=int, default=64, help="observations per batched decision")
    parser.add_argument("--batches", type=int, default=20, help="batched decisions per model")
    parser.add_argument("--optimization", default="all", choices=sorted(OPTIMIZATION_LEVELS),
                        help="ONNX Runtime's graph optimisation level")
    parser.add_argument("--graphs", type=Path, help="folder of the .onnx files (default: a temporary one)")
    args = parser.parse_args()
    configure_cpu(1)  # one torch thread; ONNX Runtime gets one too (OnnxPolicy's default)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        graphs = args.graphs or Path(tmp)
        graphs.mkdir(parents=True, exist_ok=True)
        for name in args.models:
            env_id, env_kwargs = pretrained_env(name)
            path = graphs / f"{name}.onnx"
            if not path.exists():
                export_onnx(check_pretrained(name), path)
            model = pretrained(name)
            graph = OnnxPolicy(path, optimization=args.optimization)
            seen = (env_id, env_kwargs, TEST_SEED_OFFSET)
            one = medians(model, graph, observations(1, args.decisions, *seen), single=True)
            many = medians(model, graph, observations(args.batch, args.batches, *seen), single=False)
            rows.append((name, *one, *many))
            print(f"{name}: one {one[0]:.2f} / {one[1]:.2f} ms, batch {many[0]:.1f} / {many[1]:.1f} ms", flush=True)
    print(f"\nmedian decision time [ms], one thread each, ONNX Runtime optimisation {args.optimization!r}\n")
    print(f"| model | PyTorch, 1 obs | ONNX Runtime, 1 obs | ratio | PyTorch, {args.batch} obs | ONNX Runtime, "
          f"{args.batch} obs | ratio |")
    print("|---|---|---|---|---|---|---|")
    for name, t1, o1, tb, ob in rows:
        print(f"| {name} | {t1:.2f} | {o1:.2f} | {t1 / o1:.2f} | {tb:.1f} | {ob:.1f} | {tb / ob:.2f} |")
    print("\nratio: PyTorch / ONNX Runtime (> 1: ONNX Runtime is faster)")


if __name__ == "__main__":
    main()
