"""Every shipped model acts on a fixed set of observations exactly as recorded in ``tests/data/pretrained_actions.npz``.

The record holds observations of both envs (random actions from fixed seeds) and each shipped model's deterministic
action on each of them. A change to how model files are read (their stored settings upgraded at load) or to the
lookahead must leave every action the same; ``python tests/test_pretrained_actions.py`` writes the record again, for
a change that is meant to alter the shipped models' actions.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import sb3_crowdnav
from sb3_crowdnav.models import PRETRAINED, pretrained_env
from sb3_crowdnav.sim.warehouse.config import PAPER_WAREHOUSE

RECORD = Path(__file__).parent / "data" / "pretrained_actions.npz"
# env id, observations: the open floor, the paper-world warehouse and today's warehouse (its defaults)
ENVS = {"crowdnav": ("CrowdNav-v0", 300), "warehouse": ("CrowdNavWarehouse-v0", 200),
        "warehouse_today": ("CrowdNavWarehouse-v0", 200), "crowdnav_stop": ("CrowdNav-v0", 300)}
# the world the paper-world warehouse models were trained in: the paper's robot, pickers who do not see it (the
# recorded observations are of that world); today's warehouse is the env's defaults; the open floor's robot with a
# stop (apg_robust)
ENV_KWARGS = {"warehouse": PAPER_WAREHOUSE, "crowdnav_stop": {"actions": "with_stop"}}


def env_key(name: str) -> str:
    """The record's observations of the world ``name`` was trained for."""
    env_id, kwargs = pretrained_env(name)
    return next(key for key, (world_id, _) in ENVS.items() if world_id == env_id and ENV_KWARGS.get(key, {}) == kwargs)


def observations(env_id: str, n: int, seed: int = 29, **kwargs) -> dict[str, np.ndarray]:
    """``n`` observations of ``env_id`` (made with ``kwargs``) visited by uniformly random actions, batched per key."""
    env = gym.make(env_id, **kwargs)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    seen = []
    for episode in range(n):
        seen.append(obs)
        obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        if terminated or truncated:
            obs, _ = env.reset(seed=seed + 1 + episode)
    env.close()
    return {key: np.stack([o[key] for o in seen]) for key in seen[0]}


def record_actions() -> None:
    """Write the record from the installed package (run only for a change meant to alter the shipped models)."""
    arrays: dict[str, np.ndarray] = {}
    batches = {key: observations(env_id, n, **ENV_KWARGS.get(key, {})) for key, (env_id, n) in ENVS.items()}
    for key, batch in batches.items():
        arrays.update({f"{key}/{k}": v for k, v in batch.items()})
    for name in PRETRAINED:
        arrays[f"actions/{name}"] = np.asarray(sb3_crowdnav.pretrained(name).predict(batches[env_key(name)],
                                                                                      deterministic=True)[0])
    RECORD.parent.mkdir(exist_ok=True)
    np.savez_compressed(RECORD, **arrays)


@pytest.mark.parametrize("name", sorted(PRETRAINED))
def test_shipped_model_acts_as_recorded(name):
    record = np.load(RECORD)
    key = env_key(name)
    batch = {k.split("/", 1)[1]: record[k] for k in record.files if k.startswith(f"{key}/")}
    # all at once: the policy searches 16 observations at a time (ACTION_VALUE_CHUNK), so the two-step search of
    # apg_robust's 300 (81 actions, the best 8 of each over 81 more) stays near 1 GB instead of ~15
    actions = sb3_crowdnav.pretrained(name).predict(batch, deterministic=True)[0]
    expected = record[f"actions/{name}"]
    assert len(expected) == ENVS[key][1]
    np.testing.assert_array_equal(actions, expected)


if __name__ == "__main__":
    record_actions()
