"""How the warehouse's pickers get their jobs done under each crowd model: the share of picker-steps walking (faster
than 0.1 m/s) and the jobs completed (arrivals at a pick slot) per picker per minute, over the same episodes.

The robot drives random actions held for 8 steps (as ``env_speed.py``'s random row), invisible to the pickers by
default. Usage::

    python benchmarks/picker_jobs.py [--steps 4000] [--crowds orca social_force] [--robot-visible]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import sb3_crowdnav  # noqa: F401  (registers the envs)


def picker_jobs(crowd: str, steps: int, seed: int = 0, robot_visible: bool = False) -> tuple[float, float]:
    """The walking share of picker-steps and the jobs completed per picker per minute over ``steps`` env steps."""
    env = gym.make("CrowdNavWarehouse-v0", crowd=crowd, robot_visible=robot_visible).unwrapped
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    action, walking, picker_steps, jobs = 0, 0, 0, 0
    for step in range(steps):
        action = int(rng.integers(env.action_space.n)) if step % 8 == 0 else action
        pickers = env.sim.pickers
        before = pickers.standing.copy() if pickers is not None else None
        _, _, terminated, truncated, _ = env.step(action)
        if pickers is not None:
            n = env.sim.num_humans
            jobs += int((pickers.standing & ~before).sum())  # started standing at a slot: arrived
            walking += int((np.linalg.norm(env.sim.history[-1, :n, 2:4], axis=-1) > 0.1).sum())
            picker_steps += n
        if terminated or truncated:
            env.reset()
    minutes = picker_steps * env.scene.time_step / 60.0
    return walking / max(picker_steps, 1), jobs / max(minutes, 1e-9)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--crowds", nargs="+", default=["orca", "social_force"])
    parser.add_argument("--robot-visible", action="store_true")
    args = parser.parse_args()
    print(f"{'crowd':<16}{'walking share':>16}{'jobs / picker / min':>22}   ({args.steps} steps, seed {args.seed})")
    for crowd in args.crowds:
        share, rate = picker_jobs(crowd, args.steps, args.seed, args.robot_visible)
        print(f"{crowd:<16}{share:>16.2f}{rate:>22.2f}")


if __name__ == "__main__":
    main()
