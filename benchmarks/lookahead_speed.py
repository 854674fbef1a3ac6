"""Lookahead decision time of APGValue: one env, and per env with 16 envs batched.

Usage: python benchmarks/lookahead_speed.py [--env CrowdNav-v0] [--extractor apg] [--decisions 300]
    [--dtype float32|bfloat16] [--threads 1] [--planning-depth 2 [--planning-width 8]]
Prints median milliseconds, and the multiply-add rate of the encoder's per-(step, pedestrian) layers
(the work that cannot be shared between actions); one torch thread unless ``--threads``. In a world with the robot's
limits (the warehouse's defaults) it also times V on every (observation, action) row against V on the distinct
propagated states the lookahead evaluates, same observations, same run. With ``--planning-depth`` it also times the
single-env decision of that deeper search (``--planning-width``: the beam) on the same observations, and its ratio to
the one-step decision.
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
from sb3_crowdnav.apg_value.policies import STATIC_KEYS
from sb3_crowdnav.nn import EXTRACTORS, configure_cpu, layers, set_onednn_inference


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
    parser.add_argument("--env", default="CrowdNav-v0", choices=("CrowdNav-v0", "CrowdNavWarehouse-v0"))
    parser.add_argument("--extractor", default="apg", choices=sorted(EXTRACTORS))
    parser.add_argument("--decisions", type=int, default=300)
    parser.add_argument("--dtype", default="float32", choices=("float32", "bfloat16"),
                        help="lookahead precision (ValueLookaheadPolicy's lookahead_dtype)")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (the package's default: 1)")
    parser.add_argument("--planning-depth", type=int, help="also time a search of this depth (single env)")
    parser.add_argument("--planning-width", type=int, help="with --planning-depth: the beam's width")
    parser.add_argument("--onednn", choices=("default", "on", "off"), default="default",
                        help="oneDNN's fused linear kernel at inference (default: the package's choice for this CPU)")
    args = parser.parse_args()
    configure_cpu(num_threads=args.threads)  # torch threads + keep freed tensor memory (sb3_crowdnav.nn.perf)
    if args.onednn != "default":
        set_onednn_inference(args.onednn == "on")
    model = APGValue("ApgPolicy", args.env, imitation_episodes=0, seed=0,
                     policy_kwargs=dict(features_extractor_class=EXTRACTORS[args.extractor], lookahead_dtype=args.dtype))
    singles = observations(1, args.decisions, args.env)
    one = time_decisions(model, singles, single=True)
    sixteen = time_decisions(model, observations(16, max(args.decisions // 4, 20), args.env), single=False)
    policy = model.policy
    prop_times = []
    for o in observations(16, 20, args.env):
        t = time.perf_counter()
        policy.propagation(o["robot"], o["humans"], o["humans_mask"], {k: o[k] for k in STATIC_KEYS if k in o})
        prop_times.append(time.perf_counter() - t)
    t_prop = statistics.median(prop_times) * 1e3
    print(f"env={args.env} extractor={args.extractor} dtype={args.dtype} torch_threads={th.get_num_threads()} "
          f"humans={policy.max_humans} T={policy.history_length} actions={policy.world.n_actions} "
          f"cpu={th.backends.cpu.get_cpu_capability()} onednn_inference={set_onednn_inference(layers._ONEDNN['enabled'])}")
    print(f"single env decision: {one:.2f} ms (target < 3 ms; reference code ~92 ms)")
    print(f"16 envs batched: {sixteen:.2f} ms per call = {sixteen / 16:.3f} ms per env (target < 0.5 ms)")
    print(f"  of which propagation + reward model for 16 x {policy.world.n_actions} states: {t_prop:.2f} ms")
    if args.planning_depth is not None:
        policy.set_planning(args.planning_depth, args.planning_width)
        deeper = time_decisions(model, singles, single=True)
        policy.set_planning(1)
        print(f"single env decision at depth {args.planning_depth}, width {args.planning_width or 'all'}: "
              f"{deeper:.2f} ms ({deeper / one:.1f}x the one-step decision, same observations)")
    if policy.world.has_limits:
        every, distinct, counts = value_times(policy, singles)
        print(f"single env, V alone: every (observation, action) row {every:.2f} ms, the distinct states {distinct:.2f} "
              f"ms (ratio {distinct / every:.2f}; {np.mean(counts):.1f} distinct states of {policy.world.n_actions} "
              f"on average, {min(counts)}-{max(counts)})")
    if args.extractor == "apg" and args.env == "CrowdNav-v0":
        macs = apg_row_macs(model)
        rows = 80 * 6 * 5  # (action, pedestrian, history step) rows of one decision of CrowdNav-v0
        work = macs * rows
        print(f"APG per-row layers: {macs} multiply-adds per row, {work / 1e6:.0f} M per decision; "
              f"< 0.5 ms per env needs {work / 0.5e-3 / 1e9:.0f} G multiply-adds/s")
        print(f"  effective rate, all overheads included: single env {work / one / 1e6:.0f} G/s, "
              f"batched {work * 16 / sixteen / 1e6:.0f} G/s")


def value_times(policy, batch: list[dict[str, np.ndarray]]) -> tuple[float, float, list[int]]:
    """Median ms of V on every row and on the distinct rows of each observation's lookahead (alternating, the same
    propagations), and the number of distinct states per observation."""
    every, distinct, counts = [], [], []
    for obs in batch:
        prop = policy.propagation(obs["robot"], obs["humans"], obs["humans_mask"],
                                  {k: obs[k] for k in STATIC_KEYS if k in obs})
        for flag, times in ((False, every), (True, distinct)):
            t = time.perf_counter()
            tensors, _ = policy.lookahead_inputs(prop, distinct=flag)
            with th.inference_mode():
                policy.value_net(tensors)
            times.append(time.perf_counter() - t)
        counts.append(len(tensors["robot"]))
    return statistics.median(every) * 1e3, statistics.median(distinct) * 1e3, counts


def apg_row_macs(model: APGValue) -> int:
    """Multiply-adds per (state, pedestrian, step) row of the APG encoder: ψ_e, ψ_h's hidden layers, ψ_alpha."""
    fe = model.policy.value_net.features_extractor
    layers = [*fe.psi_e.layers, *fe.psi_h_hidden.layers, fe.psi_alpha_step, *fe.psi_alpha_rest.layers]
    return sum(layer.in_features * layer.out_features for layer in layers)


if __name__ == "__main__":
    main()
