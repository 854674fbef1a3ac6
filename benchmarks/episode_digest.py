"""SHA-256 digests of seeded episodes of ``CrowdNavWarehouse-v0`` and ``CrowdNav-v0``: a speed-up must leave them equal.

Usage: python benchmarks/episode_digest.py [--save FILE] [--check FILE] [--scale 1]

Groups (6 pedestrians/pickers; the first episode of a group is reset with its seed, the others go on from the env's
generator, as training does): generated layouts with random actions held for 8 steps (60 episodes) and with the ORCA
robot (``mapping="constrained"``, 15); the layout file ``examples/warehouse_layout.yaml`` with the
``comfort_angular`` reward and the route shaping (``progress_reward=0.1``), random (20) and ORCA (5); the open floor
with ``comfort_angular``, random (10) and ORCA (3). Every reset's observation and info and every step's observation
(all keys: dtype, shape, bytes), reward, terminated/truncated flags and info (outcome, reward terms, episode
statistics; floats by ``repr``, exact) go into the group's hash. The warehouse groups run the paper's robot
(``actions="paper", max_acceleration=None, max_turn_rate=None``, the warehouse's defaults before the kinematic
limits) among pickers who do not see it (``robot_visible=False``, the default before the pickers saw the robot), seen
through racks at any range (``occlusion=False, people_sensor_range=None``, before the people sensor), so their digests
are those recorded before. Four more groups run today's defaults: the warehouse (occlusion, the stop and the limits,
pickers of whom a share see the robot), random (60) and ORCA (10), social force pickers, random (30), and the open
floor's measured-speed population with the stop, random (10). Prints one digest per group and the total;
``--save`` writes them as JSON, ``--check`` compares with such a file and exits 1 on any mismatch; ``--scale``
multiplies every group's episodes (a stricter check; its digests differ from the default's).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav import OrcaPolicy
from sb3_crowdnav.sim.population import MEASURED_POPULATION

LAYOUT_FILE = Path(__file__).resolve().parent.parent / "examples" / "warehouse_layout.yaml"
RANDOM, ORCA = "random", "orca"
# the warehouse's robot before #31, among pickers who do not see it (the warehouse's default before them)
PAPER_ROBOT = {"actions": "paper", "max_acceleration": None, "max_turn_rate": None, "robot_visible": False,
               "occlusion": False, "people_sensor_range": None}

# (name, env id, env kwargs, robot, episodes, seed)
GROUPS: list[tuple[str, str, dict[str, Any], str, int, int]] = [
    ("warehouse random x 8", "CrowdNavWarehouse-v0", PAPER_ROBOT, RANDOM, 60, 0),
    ("warehouse ORCA", "CrowdNavWarehouse-v0", PAPER_ROBOT, ORCA, 15, 1),
    ("layout file random x 8", "CrowdNavWarehouse-v0",
     {"layout": str(LAYOUT_FILE), "reward": "comfort_angular", "progress_reward": 0.1, **PAPER_ROBOT}, RANDOM, 20, 2),
    ("layout file ORCA", "CrowdNavWarehouse-v0",
     {"layout": str(LAYOUT_FILE), "reward": "comfort_angular", "progress_reward": 0.1, **PAPER_ROBOT}, ORCA, 5, 3),
    ("open floor random x 8", "CrowdNav-v0", {"reward": "comfort_angular"}, RANDOM, 10, 4),
    ("open floor ORCA", "CrowdNav-v0", {"reward": "comfort_angular"}, ORCA, 3, 5),
    ("warehouse defaults random x 8", "CrowdNavWarehouse-v0", {}, RANDOM, 60, 6),
    ("warehouse defaults ORCA", "CrowdNavWarehouse-v0", {}, ORCA, 10, 7),
    ("warehouse social force random x 8", "CrowdNavWarehouse-v0", {"crowd": "social_force"}, RANDOM, 30, 8),
    ("open floor measured random x 8", "CrowdNav-v0", {**MEASURED_POPULATION, "actions": "with_stop"}, RANDOM, 10, 9),
]


def _plain(value: Any) -> str:
    """An exact, stable text of an info value (floats by repr, dicts sorted, arrays by bytes)."""
    if isinstance(value, dict):
        return "{" + ",".join(f"{k!r}:{_plain(value[k])}" for k in sorted(value)) + "}"
    if isinstance(value, np.ndarray):
        return f"array({value.dtype},{value.shape},{value.tobytes().hex()})"
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        value = value.item()
    return repr(value)


def _feed(h: Any, obs: dict[str, np.ndarray]) -> None:
    for key in sorted(obs):
        a = np.ascontiguousarray(obs[key])
        h.update(f"{key}:{a.dtype}:{a.shape}:".encode())
        h.update(a.tobytes())


def digest_group(env_id: str, kwargs: dict[str, Any], robot: str, episodes: int, seed: int) -> tuple[str, int]:
    """The group's SHA-256 (hex) and its number of steps."""
    env = gym.make(env_id, num_humans=6, **kwargs).unwrapped
    policy = OrcaPolicy.from_env(env, mapping="constrained") if robot == ORCA else None
    rng = np.random.default_rng(seed)
    h, steps = hashlib.sha256(), 0
    for episode in range(episodes):
        obs, info = env.reset(seed=seed if episode == 0 else None)
        _feed(h, obs)
        h.update(_plain(info).encode())
        action, done, t = 0, False, 0
        while not done:
            if policy is not None:
                action = int(policy.predict(obs)[0])
            elif t % 8 == 0:
                action = int(rng.integers(env.action_space.n))
            obs, reward, terminated, truncated, info = env.step(action)
            _feed(h, obs)
            h.update(f"{reward!r}|{terminated}|{truncated}|{_plain(info)}".encode())
            done, t = terminated or truncated, t + 1
        steps += t
    env.close()
    return h.hexdigest(), steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--save", type=Path, help="write the digests to this JSON file")
    parser.add_argument("--check", type=Path, help="compare with a JSON file of --save; exit 1 on a mismatch")
    parser.add_argument("--scale", type=int, default=1, help="run this many times the episodes of every group")
    args = parser.parse_args()

    digests, total = {}, hashlib.sha256()
    for name, env_id, kwargs, robot, episodes, seed in GROUPS:
        began = time.process_time()
        episodes *= args.scale
        digests[name], steps = digest_group(env_id, kwargs, robot, episodes, seed)
        total.update(digests[name].encode())
        print(f"{name:<34}{episodes:>4} episodes {steps:>6} steps  {digests[name]}  "
              f"({time.process_time() - began:.1f} s CPU)")
    digests["total"] = total.hexdigest()
    print(f"{'total':<59}{digests['total']}")
    if args.save:
        args.save.write_text(json.dumps(digests, indent=2) + "\n")
    if args.check:
        saved = json.loads(args.check.read_text())
        wrong = [name for name in digests if saved.get(name) != digests[name]]
        print("identical to " + str(args.check) if not wrong else f"MISMATCH with {args.check}: {', '.join(wrong)}")
        sys.exit(1 if wrong else 0)


if __name__ == "__main__":
    main()
