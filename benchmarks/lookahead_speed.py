"""Lookahead decision time of APGValue: one env, and per env with 16 envs batched.

Usage: python benchmarks/lookahead_speed.py [--extractor apg] [--decisions 300] [--dtype float32|bfloat16] [--threads 1]
Prints median milliseconds, and the multiply-add rate of the encoder's per-(step, pedestrian) layers
(the work that cannot be shared between actions); one torch thread unless ``--threads``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_vec_env

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.nn import EXTRACTORS, configure_cpu


def observations(n_envs: int, count: int, env_id: str = "CrowdNav-v0", env_kwargs: dict | None = None,
                 seed: int = 0) -> list[dict[str, np.ndarray]]:
    """``count`` batches of ``n_envs`` real mid-episode observations (an ORCA robot driving) of ``env_id``, its
    episodes from ``seed`` on (also used by onnx_latency.py)."""
    from sb3_crowdnav import OrcaPolicy

    vec = make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs)
    orca = OrcaPolicy.from_env(vec)
    obs = vec.reset()
    out = []
    for _ in range(count):
        out.append({k: v.copy() for k, v in obs.items()})
        obs, *_ = vec.step(orca.predict(obs)[0])
    vec.close()
    return out


def time_decisions(model: APGValue, batch: list[dict[str, np.ndarray]], single: bool) -> float:
    times = []
    for obs in batch:
        o = {k: v[0] for k, v in obs.items()} if single else obs
        t = time.perf_counter()
        model.predict(o, deterministic=True)
        times.append(time.perf_counter() - t)
    return statistics.median(times) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--extractor", default="apg", choices=sorted(EXTRACTORS))
    parser.add_argument("--decisions", type=int, default=300)
    parser.add_argument("--dtype", default="float32", choices=("float32", "bfloat16"),
                        help="lookahead precision (ValueLookaheadPolicy's lookahead_dtype)")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (the package's default: 1)")
    args = parser.parse_args()
    configure_cpu(num_threads=args.threads)  # torch threads + keep freed tensor memory (sb3_crowdnav.nn.perf)
    model = APGValue("ApgPolicy", "CrowdNav-v0", imitation_episodes=0, seed=0,
                     policy_kwargs=dict(features_extractor_class=EXTRACTORS[args.extractor], lookahead_dtype=args.dtype))
    one = time_decisions(model, observations(1, args.decisions), single=True)
    sixteen = time_decisions(model, observations(16, max(args.decisions // 4, 20)), single=False)
    prop = model.policy.propagation
    prop_times = []
    for o in observations(16, 20):
        t = time.perf_counter()
        prop(o["robot"], o["humans"], o["humans_mask"])
        prop_times.append(time.perf_counter() - t)
    t_prop = statistics.median(prop_times) * 1e3
    print(f"extractor={args.extractor} dtype={args.dtype} torch_threads={th.get_num_threads()} humans=6 T=5")
    print(f"single env decision: {one:.2f} ms (target < 3 ms; reference code ~92 ms)")
    print(f"16 envs batched: {sixteen:.2f} ms per call = {sixteen / 16:.3f} ms per env (target < 0.5 ms)")
    print(f"  of which propagation + reward model for 16 x 80 states: {t_prop:.2f} ms")
    if args.extractor == "apg":
        macs = apg_row_macs(model)
        rows = 80 * 6 * 5  # (action, pedestrian, history step) rows of one decision
        work = macs * rows
        print(f"APG per-row layers: {macs} multiply-adds per row, {work / 1e6:.0f} M per decision; "
              f"< 0.5 ms per env needs {work / 0.5e-3 / 1e9:.0f} G multiply-adds/s")
        print(f"  effective rate, all overheads included: single env {work / one / 1e6:.0f} G/s, "
              f"batched {work * 16 / sixteen / 1e6:.0f} G/s")


def apg_row_macs(model: APGValue) -> int:
    """Multiply-adds per (state, pedestrian, step) row of the APG encoder: ψ_e, ψ_h's hidden layers, ψ_alpha."""
    fe = model.policy.value_net.features_extractor
    layers = [*fe.psi_e.layers, *fe.psi_h_hidden.layers, fe.psi_alpha_step, *fe.psi_alpha_rest.layers]
    return sum(layer.in_features * layer.out_features for layer in layers)


if __name__ == "__main__":
    main()
