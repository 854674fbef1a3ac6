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


def assert_graph_decides_as_policy(policy: ValueLookaheadPolicy, obs: dict[str, np.ndarray]) -> np.ndarray:
    """The decision graph (``LookaheadDecision``, in torch) gives the policy's action values to 1e-6 and their argmax;
    returns the graph's values."""
    from sb3_crowdnav.deploy.graph import LookaheadDecision

    expected = policy.action_values(obs)
    with th.no_grad():
        action, values = LookaheadDecision(policy).eval()({k: th.as_tensor(v) for k, v in obs.items()})
    np.testing.assert_allclose(values.numpy(), expected, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(action.numpy(), expected.argmax(axis=1))
    return values.numpy()
