"""Time of one gradient step of V (batch of real observations, Adam) on oneDNN's kernels against MKL's (``nn.Linear``).

Usage: python benchmarks/gradient_step.py [--batch 100] [--steps 30] [--repeats 3]

For ``CrowdNav-v0`` and ``CrowdNavWarehouse-v0`` (defaults), untrained ``ApgPolicy`` weights, observations of an ORCA
robot driving; the two kernels alternate (``sb3_crowdnav.nn.set_onednn_training``), one torch thread. Prints the best
of ``--repeats`` medians of each and their ratio (same run). Which one the package takes by default depends on the
CPU (``benchmarks/README.md``).
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch as th
from lookahead_speed import observations

from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.nn import configure_cpu, layers, set_onednn_training


def step_times(model: APGValue, batches: list[dict[str, th.Tensor]], steps: int) -> float:
    """Median ms of a gradient step of V (mean squared error to a constant) over ``steps`` steps."""
    net = model.policy.value_net
    optimizer = th.optim.Adam(net.parameters(), lr=1e-4)
    times = []
    for i in range(steps):
        batch = batches[i % len(batches)]
        start = time.perf_counter()
        loss = (net(batch).reshape(-1) - 0.1).pow(2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        times.append(time.perf_counter() - start)
    return statistics.median(times[len(times) // 5:]) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=100)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    configure_cpu(num_threads=1)
    default = layers._ONEDNN["training"]
    print(f"cpu={th.backends.cpu.get_cpu_capability()} default: {'oneDNN' if default else 'MKL'}; batch {args.batch}")
    for env_id in ("CrowdNav-v0", "CrowdNavWarehouse-v0"):
        model = APGValue("ApgPolicy", env_id, imitation_episodes=0, seed=0)
        batches = [{k: th.as_tensor(v, dtype=th.float32) for k, v in obs.items()}
                   for obs in observations(args.batch, 3, env_id)]
        best: dict[bool, float] = {}
        for _ in range(args.repeats):
            for onednn in (True, False):
                set_onednn_training(onednn)
                best[onednn] = min(best.get(onednn, float("inf")), step_times(model, batches, args.steps))
        set_onednn_training(default)
        print(f"{env_id}: oneDNN {best[True]:.2f} ms, MKL {best[False]:.2f} ms, MKL / oneDNN {best[False] / best[True]:.2f}")


if __name__ == "__main__":
    main()
