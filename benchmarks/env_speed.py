"""Env steps per second of ``CrowdNav-v0`` (6 pedestrians, observation building included, one process).

Two robots: a fixed action (straight on at full speed; the simulator, rewards and observation
alone) and the ORCA robot policy deciding every step. Episodes are reset as they end, and the
reset time is included. Usage::

    python benchmarks/env_speed.py [--steps 20000] [--repeats 3] [--reward crowdnav] [--profile]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import OrcaPolicy

FIXED_ACTION = 4 * 16  # full speed, straight on


def run(env: gym.Env, steps: int, policy: OrcaPolicy | None, seed: int = 0) -> tuple[float, float]:
    """Steps per wall-clock second and per CPU second of this process over ``steps`` env steps (resets included)."""
    obs, _ = env.reset(seed=seed)
    start, start_cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        action = FIXED_ACTION if policy is None else int(policy.predict(obs)[0])
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            obs, _ = env.reset()
    return steps / (time.perf_counter() - start), steps / max(time.process_time() - start_cpu, 1e-9)


def best(env: gym.Env, steps: int, policy: OrcaPolicy | None, repeats: int) -> str:
    rates = [run(env, steps, policy, seed=i) for i in range(repeats)]
    wall, cpu = max(r[0] for r in rates), max(r[1] for r in rates)
    return f"{wall:9,.0f} steps/s  ({cpu:9,.0f} per CPU-second)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3, help="best of this many runs is reported")
    parser.add_argument("--reward", default="crowdnav", choices=["crowdnav", "comfort", "comfort_angular"])
    parser.add_argument("--num-humans", type=int, default=6)
    parser.add_argument("--profile", action="store_true", help="print a cProfile of the fixed-action run instead")
    args = parser.parse_args()

    env = gym.make("CrowdNav-v0", num_humans=args.num_humans, reward=args.reward).unwrapped
    if args.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.runcall(run, env, args.steps, None)
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)
        return
    policy = OrcaPolicy.from_env(env)
    print(f"CrowdNav-v0, {args.num_humans} pedestrians, reward={args.reward!r}, best of {args.repeats} x {args.steps} steps")
    print(f"  fixed action : {best(env, args.steps, None, args.repeats)}")
    print(f"  ORCA robot   : {best(env, args.steps // 4, policy, args.repeats)}")


if __name__ == "__main__":
    main()
