"""Observations and value policies for the lookahead tests (the numpy lookahead, the exported graph, deeper searches)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch as th

from sb3_crowdnav.apg_value.policies import ValueLookaheadPolicy


def random_observations(env: gym.Env, count: int, seed: int = 0) -> dict[str, np.ndarray]:
    """``count`` observations of random-action episodes, batched."""
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    seen = []
    while len(seen) < count:
        seen.append(obs)
        obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        if terminated or truncated:
            obs, _ = env.reset()
    return {k: np.stack([o[k] for o in seen]) for k in seen[0]}


def value_policy(env: gym.Env, **kwargs) -> ValueLookaheadPolicy:
    """An untrained value policy for ``env``'s world (torch seeded: the same weights every time)."""
    th.manual_seed(0)
    return ValueLookaheadPolicy(env.observation_space, env.action_space, lambda _: 1e-3, world=env.unwrapped.world,
                                **kwargs)
