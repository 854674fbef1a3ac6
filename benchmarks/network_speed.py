"""Forward time of the crowd encoders: ``python benchmarks/network_speed.py``.

Times one ``torch.no_grad()`` forward pass (median of many runs, one torch thread) of each
extractor followed by a value head ``create_mlp(features_dim, 1, [150, 100, 100])`` (ψ_M), on
batches of 80 joint states (one lookahead decision: 80 actions) and 1,280 (16 envs x 80), each
with 6 present pedestrians in 10 slots and T = 5 history steps.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import create_mlp

from sb3_crowdnav.nn import EXTRACTORS
from sb3_crowdnav.nn.layers import set_onednn_inference
from sb3_crowdnav.nn.perf import configure_cpu
from sb3_crowdnav.sim.observation import HUMAN_DIM, ROBOT_DIM, Human, Robot


def make_space(history_length: int, max_humans: int) -> spaces.Dict:
    big = np.float32(100.0)
    return spaces.Dict({
        "robot": spaces.Box(-big, big, (ROBOT_DIM,), np.float32),
        "humans": spaces.Box(-big, big, (history_length * max_humans * HUMAN_DIM,), np.float32),
        "humans_mask": spaces.Box(0.0, 1.0, (max_humans,), np.float32),
    })


def make_batch(batch: int, history_length: int, max_humans: int, present: int, seed: int = 0) -> dict[str, th.Tensor]:
    """Random joint states: robot near (0, -4) heading to (0, 4), ``present`` pedestrians within 4 m."""
    g = th.Generator().manual_seed(seed)
    robot = th.zeros(batch, ROBOT_DIM)
    robot[:, Robot.POS] = th.tensor([0.0, -4.0]) + 0.5 * th.randn(batch, 2, generator=g)
    robot[:, Robot.VEL] = 0.5 * th.randn(batch, 2, generator=g)
    robot[:, Robot.RADIUS] = 0.3
    robot[:, Robot.GOAL] = th.tensor([0.0, 4.0])
    robot[:, Robot.V_PREF] = 1.0
    robot[:, Robot.HEADING] = th.rand(batch, generator=g) * 6.28 - 3.14
    humans = th.zeros(batch, history_length, max_humans, HUMAN_DIM)
    humans[:, :, :present, Human.POS] = 4 * (th.rand(batch, history_length, present, 2, generator=g) - 0.5) * 2
    humans[:, :, :present, Human.VEL] = th.randn(batch, history_length, present, 2, generator=g)
    humans[:, :, :present, Human.RADIUS] = 0.3
    mask = th.zeros(batch, max_humans)
    mask[:, :present] = 1.0
    return {"robot": robot, "humans": humans.reshape(batch, -1), "humans_mask": mask}


def median_ms(fn, repeats: int, warmup: int = 20) -> tuple[float, float]:
    """Median wall time and median CPU time of this thread [ms]; the second ignores time lost to other processes."""
    for _ in range(warmup):
        fn()
    wall, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.thread_time()
        fn()
        wall.append(time.perf_counter() - start)
        cpu.append(time.thread_time() - start_cpu)
    return 1e3 * float(np.median(wall)), 1e3 * float(np.median(cpu))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (1 is fastest here)")
    parser.add_argument("--repeats", type=int, default=300)
    parser.add_argument("--batches", type=int, nargs="+", default=[80, 1280])
    parser.add_argument("--no-tune-malloc", action="store_true", help="keep glibc's default trimming (page faults)")
    parser.add_argument("--no-onednn", action="store_true", help="plain nn.Linear (MKL) also at inference")
    parser.add_argument("--bf16", action="store_true", help="run under torch.autocast('cpu', torch.bfloat16)")
    args = parser.parse_args()
    configure_cpu(args.threads, malloc=not args.no_tune_malloc)
    onednn = set_onednn_inference(not args.no_onednn)
    th.manual_seed(0)
    history_length, max_humans, present = 5, 10, 6
    space = make_space(history_length, max_humans)
    print(f"torch {th.__version__}, {th.get_num_threads()} thread(s), malloc tuned: {not args.no_tune_malloc}, "
          f"oneDNN inference: {onednn}, bf16 autocast: {args.bf16}")
    print(f"T={history_length}, {present} present of {max_humans} slots; median of {args.repeats} runs "
          "(a tenth for batches > 200), extractor + value head; cpu = this thread's CPU time")
    header = f"{'encoder':<8} {'features':>8} " + " ".join(f"{f'B={b} wall/cpu [ms]':>24}" for b in args.batches)
    print(header)
    print("-" * len(header))
    for name, cls in EXTRACTORS.items():
        extractor = cls(space).eval()
        head = th.nn.Sequential(*create_mlp(extractor.features_dim, 1, [150, 100, 100])).eval()
        cells = []
        for batch in args.batches:
            obs = make_batch(batch, history_length, max_humans, present)

            def forward(obs=obs, extractor=extractor, head=head) -> th.Tensor:
                with th.no_grad(), th.autocast("cpu", dtype=th.bfloat16, enabled=args.bf16):
                    return head(extractor(obs))

            repeats = args.repeats if batch <= 200 else max(20, args.repeats // 10)
            wall, cpu = median_ms(forward, repeats)
            cells.append(f"{wall:14.3f} / {cpu:7.3f}")
        print(f"{name:<8} {extractor.features_dim:>8} " + " ".join(cells))


if __name__ == "__main__":
    main()
