"""Env steps per second of ``CrowdNav-v0`` and ``CrowdNavWarehouse-v0`` (6 pedestrians/pickers, observation
building included, one process), measured in the same run, and their ratio.

Robots: a fixed action (straight on at full speed; the simulator, rewards and observation alone), random
actions held for 8 steps (drives into the warehouse's aisles and racks like an untrained policy), and the
ORCA robot policy deciding every step (in the warehouse: obstacle-aware, following the route). Episodes
are reset as they end, and the reset time is included (a warehouse reset draws a layout, plans routes and
places the pickers). The two envs' runs alternate, and the best of each is reported. Then the crowd models: each env
with ``crowd="social_force"`` against its ORCA crowd (a fixed action and random actions held for 8 steps, runs
alternating), as a ratio (skipped when JuPedSim is not installed). Usage::

    python benchmarks/env_speed.py [--steps 20000] [--repeats 3] [--reward crowdnav] [--breakdown] [--profile] [--cpu]
                                   [--variants]

A second table compares the crowd models of ``CrowdNav-v0`` in the same run: the ORCA crowd and ``crowd="replay"``
of a synthetic recording of as many people (generated on the fly: each walks back and forth across a 10 m street at
1.3 m/s, everyone present all the time, 0.4 s per sample), with the ratio replay / ORCA.

``--variants`` prints, instead of the tables, the default warehouse beside variants of it as ratios of ``CrowdNav-v0``'s
steps/s (same run, the three robots): every picker seeing the robot (``robot_visible=1.0``: one RVO2 simulator instead of
two for a crowd of seeing and distracted pickers), the pickers' ORCA obstacle horizon at 2 s instead of 5 s
(``orca_time_horizon_obst=2.0``, a change of how the pickers walk), the paper's robot, the paper's robot with the
default's people sensor (racks hide pickers, 8 m), and the paper's robot with that horizon: what the parts of the
default cost.

``--breakdown`` adds, per row and env, the steps per episode and the time of a reset and of a step without it
(with the tables only: ``--profile`` and ``--variants`` are refused with it and with each other).
``--cpu`` measures every rate and time in CPU seconds of this process (``time.process_time``) instead of wall-clock
seconds: steadier on a machine that other jobs load.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import OrcaPolicy
from sb3_crowdnav.sim.recording import write_recording
from sb3_crowdnav.sim.warehouse.config import PAPER_WAREHOUSE, PEOPLE_SENSOR_RANGE

FIXED_ACTION = 4 * 16  # full speed, straight on


RANDOM = "random"
ROBOTS = (("fixed action", 1, lambda e: None), ("random x 8", 1, lambda e: RANDOM),
          ("ORCA robot", 4, lambda e: OrcaPolicy.from_env(e, mapping="constrained")))  # (label, steps divided by, policy)


def run(env: gym.Env, steps: int, policy: OrcaPolicy | str | None, seed: int = 0,
        resets: list[float] | None = None, clock=time.perf_counter) -> tuple[float, float]:
    """Steps per wall-clock second and per CPU second of this process over ``steps`` env steps (resets included);
    the time of every reset by ``clock`` is appended to ``resets`` when given."""
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    action = FIXED_ACTION
    start, start_cpu = time.perf_counter(), time.process_time()
    for step in range(steps):
        if policy == RANDOM:
            action = int(rng.integers(env.action_space.n)) if step % 8 == 0 else action
        elif policy is not None:
            action = int(policy.predict(obs)[0])
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            began = clock()
            obs, _ = env.reset()
            if resets is not None:
                resets.append(clock() - began)
    return steps / (time.perf_counter() - start), steps / max(time.process_time() - start_cpu, 1e-9)


def breakdown(env: gym.Env, steps: int, policy: OrcaPolicy | str | None, cpu: bool = False) -> str:
    """Steps per episode, ms per reset and µs per step without resets (the policy's decision included)."""
    resets: list[float] = []
    rate = run(env, steps, policy, resets=resets, clock=time.process_time if cpu else time.perf_counter)[int(cpu)]
    per_step = (steps / rate - sum(resets)) / steps
    return f"{steps / max(len(resets), 1):.0f} steps/episode, {1e3 * np.mean(resets):.2f} ms/reset, " \
           f"{1e6 * per_step:.0f} us/step"


def best(envs: list[gym.Env], steps: int, policies: list, repeats: int, cpu: bool = False) -> list[float]:
    """The best steps/s of ``repeats`` runs of each env (wall-clock, or CPU time with ``cpu``), the envs' runs
    interleaved (a slower spell of a shared machine slows both)."""
    rates = [[run(env, steps, policy, seed=i)[int(cpu)] for env, policy in zip(envs, policies, strict=True)]
             for i in range(repeats)]
    return [max(column) for column in zip(*rates, strict=True)]


def synthetic_recording(path: Path, people: int, seconds: float = 600.0) -> Path:
    """A recording of ``people`` walking back and forth across a 10 m street at 1.3 m/s, 1 m apart, all the time."""
    times = np.arange(0.0, seconds, 0.4)
    phase = (1.3 * times[:, None] + 2.5 * np.arange(people)) % 20.0  # [m] along a 20 m round trip
    x = np.where(phase < 10.0, phase, 20.0 - phase) - 5.0
    y = np.broadcast_to(np.arange(people) - (people - 1) / 2, x.shape)
    write_recording(path, times, np.stack([x, y], axis=-1))
    return path


def compare_crowds(args: argparse.Namespace, orca: gym.Env, directory: str) -> None:
    """The ORCA crowd against a replay of a synthetic recording of as many people, same run, same robots."""
    path = synthetic_recording(Path(directory) / "synthetic.csv", args.num_humans)
    replay = gym.make("CrowdNav-v0", crowd="replay", crowd_kwargs={"path": str(path)}, reward=args.reward,
                      max_humans=max(10, args.num_humans)).unwrapped
    print(f"\n{'robot':<14}{'ORCA crowd':>16}{'replay':>16}{'ratio':>8}   (CrowdNav-v0, {args.num_humans} people)")
    for label, part, make in ROBOTS:
        steps = args.steps // part
        simulated, replayed = best([orca, replay], steps, [make(orca), make(replay)], args.repeats, args.cpu)
        print(f"{label:<14}{simulated:>12,.0f} /s{replayed:>12,.0f} /s{replayed / simulated:>8.2f}")
        if args.breakdown:
            for name, e in (("ORCA crowd", orca), ("replay", replay)):
                print(f"{'':<14}{name}: {breakdown(e, steps, make(e), args.cpu)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3, help="best of this many runs is reported")
    parser.add_argument("--reward", default="crowdnav", choices=["crowdnav", "comfort", "comfort_angular"])
    parser.add_argument("--num-humans", type=int, default=6)
    parser.add_argument("--breakdown", action="store_true", help="also time resets and steps apart")
    instead = parser.add_mutually_exclusive_group()  # each replaces the tables
    instead.add_argument("--profile", action="store_true", help="cProfile the warehouse's random x 8 run instead")
    parser.add_argument("--cpu", action="store_true", help="CPU time of this process instead of wall-clock time")
    instead.add_argument("--variants", action="store_true", help="the default warehouse beside variants of it instead")
    args = parser.parse_args()
    if args.breakdown and (args.profile or args.variants):
        parser.error("--breakdown belongs to the tables, which --profile and --variants replace")

    env = gym.make("CrowdNav-v0", num_humans=args.num_humans, reward=args.reward).unwrapped
    warehouse = gym.make("CrowdNavWarehouse-v0", num_humans=args.num_humans, reward=args.reward).unwrapped
    if args.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.runcall(run, warehouse, args.steps, RANDOM)
        pstats.Stats(prof).sort_stats("cumulative").print_stats(30)
        return
    if args.variants:
        variants(args, env)
        return
    print(f"{args.num_humans} pedestrians/pickers, reward={args.reward!r}, best of {args.repeats} runs, resets included, "
          f"{'CPU' if args.cpu else 'wall-clock'} time")
    # the warehouse with its defaults (a robot with a stop and acceleration and turn-rate limits, pickers who mostly see
    # it), and as before issue #31 (the paper's robot, 80 actions, no limits, pickers who never see it, seen through racks)
    paper = gym.make("CrowdNavWarehouse-v0", num_humans=args.num_humans, reward=args.reward, **PAPER_WAREHOUSE).unwrapped
    print(f"{'robot':<14}{'CrowdNav-v0':>16}{'warehouse':>16}{'ratio':>8}{'paper robot':>16}{'ratio':>8}")
    for label, part, make in ROBOTS:
        steps = args.steps // part
        envs = [env, warehouse, paper]
        open_floor, hall, hall_paper = best(envs, steps, [make(e) for e in envs], args.repeats, args.cpu)
        print(f"{label:<14}{open_floor:>12,.0f} /s{hall:>12,.0f} /s{hall / open_floor:>8.2f}"
              f"{hall_paper:>12,.0f} /s{hall_paper / open_floor:>8.2f}")
        if args.breakdown:
            for name, e in (("CrowdNav-v0", env), ("warehouse", warehouse), ("paper robot", paper)):
                print(f"{'':<14}{name}: {breakdown(e, steps, make(e), args.cpu)}")
    with tempfile.TemporaryDirectory() as directory:
        compare_crowds(args, env, directory)
    crowd_models(args, env, warehouse)


def variants(args: argparse.Namespace, env: gym.Env) -> None:
    """The default warehouse and variants of it, each as a ratio of ``CrowdNav-v0``'s steps/s (same run)."""
    sensor = {"occlusion": True, "people_sensor_range": PEOPLE_SENSOR_RANGE}  # the default's
    kinds = {"default warehouse": {}, "every picker sees": {"robot_visible": 1.0},
             "obstacle horizon 2 s": {"orca_time_horizon_obst": 2.0}, "paper robot": PAPER_WAREHOUSE,
             "paper robot, sensor": {**PAPER_WAREHOUSE, **sensor},
             "paper robot, 2 s": {**PAPER_WAREHOUSE, "orca_time_horizon_obst": 2.0}}
    envs = [env] + [gym.make("CrowdNavWarehouse-v0", num_humans=args.num_humans, reward=args.reward, **kwargs).unwrapped
                    for kwargs in kinds.values()]
    rates = {label: best(envs, args.steps // part, [make(e) for e in envs], args.repeats, args.cpu)
             for label, part, make in ROBOTS}
    print(f"{args.num_humans} pedestrians/pickers, reward={args.reward!r}, best of {args.repeats} runs, resets included, "
          f"{'CPU' if args.cpu else 'wall-clock'} time; ratios of CrowdNav-v0's steps/s")
    print(f"{'env':<22}" + "".join(f"{label:>22}" for label in rates))
    for i, name in enumerate(["CrowdNav-v0", *kinds]):
        print(f"{name:<22}" + "".join(f"{r[i]:>13,.0f} /s{r[i] / r[0]:>5.2f}" for r in rates.values()))


def crowd_models(args: argparse.Namespace, env: gym.Env, warehouse: gym.Env) -> None:
    """Social force against ORCA in each env, with a fixed action and with random actions held for 8 steps, the
    same run (issue #30's acceptance: social force at >= 0.5x ORCA's steps/s on the open floor)."""
    try:
        import jupedsim  # noqa: F401
    except ImportError:
        print("crowd models: skipped (JuPedSim is not installed; see docs/installation.md)")
        return
    print(f"\n{'crowd':<24}{'robot':<14}{'orca':>12}{'social_force':>16}{'ratio':>8}")
    for name, orca in (("CrowdNav-v0", env), ("CrowdNavWarehouse-v0", warehouse)):
        social = gym.make(name, num_humans=args.num_humans, reward=args.reward, crowd="social_force").unwrapped
        for label, policy in (("fixed action", None), ("random x 8", RANDOM)):
            rate_orca, rate_social = best([orca, social], args.steps, [policy, policy], args.repeats, args.cpu)
            print(f"{name:<24}{label:<14}{rate_orca:>10,.0f} /s{rate_social:>14,.0f} /s{rate_social / rate_orca:>8.2f}")


if __name__ == "__main__":
    main()
