"""On which side of a pedestrian does a policy pass closest: in front (where Eq. 11 penalises) or behind?

    python examples/closest_approach.py --policy pretrained:apg_rl --policy pretrained:apg_crl \
        --policy pretrained:apg_carl --episodes 200

For every test episode (seeds 1,000,000 + i, greedy actions) the script finds the step whose end has the
smallest surface distance between the robot and any pedestrian, and asks whether the robot was then in that
pedestrian's front half-plane (x0 >= 0 in the pedestrian frame of Eq. 9-11, the half of the comfort ellipse
that the comfort rewards penalise) or behind it, with the reward's own walking direction
(:func:`sb3_crowdnav.sim.rewards.walking_direction` on the observation's history). Distances are taken at the end of
each step, so the mean can sit slightly above the harness's ``min_separation``, which checks the closest
approach during the step.

Each policy runs on the env with its own reward (``--reward NAME=REWARD`` overrides; the defaults follow the
shipped models' names), which matters only for the reward column, not the trajectory: the robot is invisible
and the pedestrians ignore it.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav import CrowdNavEnv
from sb3_crowdnav.evaluation.runner import TEST_SEED_OFFSET, make_policy, policy_label
from sb3_crowdnav.nn import configure_cpu
from sb3_crowdnav.sim.observation import HUMAN_DIM, Human, Robot
from sb3_crowdnav.sim.rewards import walking_direction

DEFAULT_REWARDS = {"apg_crl": "comfort", "apg_carl": "comfort_angular"}


def closest_approach(obs: dict[str, np.ndarray]) -> tuple[float, bool]:
    """Smallest surface distance to a present pedestrian in an observation, and whether it is in front."""
    robot = obs["robot"]
    mask = obs["humans_mask"] > 0
    hist = obs["humans"].reshape(-1, len(mask), HUMAN_DIM)
    if not mask.any():
        return math.inf, False
    newest = hist[-1]
    dist = np.linalg.norm(newest[:, Human.POS] - robot[Robot.POS], axis=1) - newest[:, Human.RADIUS] - robot[Robot.RADIUS]
    dist = np.where(mask, dist, np.inf)
    j = int(np.argmin(dist))
    direction = walking_direction(hist[:, :, Human.VEL], newest[:, Human.POS], robot[Robot.POS])[j]
    return float(dist[j]), float(np.dot(robot[Robot.POS] - newest[j, Human.POS], direction)) >= 0.0


def episode_closest(policy, env: CrowdNavEnv, seed: int) -> tuple[float, bool]:
    obs, _ = env.reset(seed=seed)
    best = (math.inf, False)
    while True:
        action, _ = policy.predict(obs, deterministic=True)
        obs, _, terminated, truncated, _ = env.step(int(np.asarray(action).reshape(-1)[0]))
        here = closest_approach(obs)
        if here[0] < best[0]:
            best = here
        if terminated or truncated:
            return best


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", action="append", required=True, help="a policy spec, as for sb3-crowdnav evaluate")
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--reward", action="append", default=[], metavar="NAME=REWARD",
                   help="env reward for a policy label (default: comfort for apg_crl, comfort_angular for apg_carl)")
    args = p.parse_args()
    if args.episodes < 1:
        p.error(f"--episodes must be >= 1, got {args.episodes}")
    rewards = dict(DEFAULT_REWARDS)
    for item in args.reward:
        name, sep, reward = item.partition("=")
        if not sep:
            p.error(f"--reward takes NAME=REWARD, got {item!r}")
        rewards[name] = reward
    configure_cpu(num_threads=1)
    print("| policy | episodes | closest approach in front | behind | mean closest surface distance [m] |")
    print("|---|---|---|---|---|")
    for spec in args.policy:
        label = policy_label(spec)
        env = CrowdNavEnv(reward=rewards.get(spec.partition(":")[2] or spec, "crowdnav"))
        policy = make_policy(spec, env)
        results = [episode_closest(policy, env, TEST_SEED_OFFSET + i) for i in range(args.episodes)]
        front = sum(f for _, f in results)
        dists = [d for d, _ in results if math.isfinite(d)]
        print(f"| {label} | {len(results)} | {front} ({front / len(results):.0%}) | {len(results) - front} | "
              f"{np.mean(dists):.3f} |", flush=True)


if __name__ == "__main__":
    main()
