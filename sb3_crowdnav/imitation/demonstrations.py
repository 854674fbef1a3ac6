"""The one collector of ORCA-robot demonstrations, for every algorithm that imitates before RL."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from sb3_crowdnav.sim.orca import OrcaPolicy
from sb3_crowdnav.sim.validation import check_int

StepCallback = Callable[[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray], np.ndarray, np.ndarray,
                         Sequence[dict[str, Any]]], None]


@dataclass
class Demonstrations:
    """Transitions of the demonstrator, episode after episode (each episode contiguous)."""

    observations: dict[str, np.ndarray]  # (n, ...) per key
    next_observations: dict[str, np.ndarray] | None  # (n, ...); the terminal observation at an episode's end
    actions: np.ndarray  # (n,) int
    rewards: np.ndarray  # (n,) float32
    terminated: np.ndarray  # (n,) bool: collision or success (not a time-limit truncation)
    episode_end: np.ndarray  # (n,) bool: last transition of its episode (terminated or truncated)
    outcomes: dict[str, int]

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def episodes(self) -> int:
        """Number of complete episodes."""
        return int(self.episode_end.sum())

    def discounted_returns(self, gamma: float, exponents: np.ndarray | None = None) -> np.ndarray:
        """Per-step discounted return to the end of the episode, (n,) float32.

        Step i is discounted by ``gamma ** exponents[i]``; without ``exponents`` by ``gamma`` (SB3's
        convention, one γ per step). APGValue passes Δt·v_pref of each state (its γ is per second).
        """
        returns = np.zeros(len(self), dtype=np.float32)
        g = 0.0
        for i in range(len(self) - 1, -1, -1):
            discount = gamma if exponents is None else gamma ** float(exponents[i])
            g = float(self.rewards[i]) + (0.0 if self.episode_end[i] else discount * g)
            returns[i] = g
        return returns


def collect_demonstrations(env: Any, episodes: int, mapping: str = "constrained", safety_space: float = 0.0, *,
                           on_step: StepCallback | None = None, keep_next_observations: bool = True,
                           on_episode: Callable[[int], None] | None = None) -> Demonstrations:
    """Run the ORCA robot in ``env`` until ``episodes`` episodes have finished; keep every transition of those.

    :param env: a VecEnv of CrowdNav envs (its auto-reset and ``terminal_observation`` are used), or one
        CrowdNav env, which is wrapped in a ``DummyVecEnv``
    :param episodes: number of complete episodes to keep (>= 1)
    :param mapping: :class:`OrcaPolicy`'s velocity-to-action mapping
    :param safety_space: extra radius the demonstrator keeps from pedestrians [m]
    :param on_step: called after every VecEnv step as ``on_step(obs, actions, new_obs, rewards, dones, infos)``
        (VecEnv arrays, all envs); APGValue stores the transitions in its replay buffer with it
    :param keep_next_observations: keep ``next_observations`` (Q-learning needs them; a value regression does not,
        and they double the memory)
    :param on_episode: called with the number of complete episodes each time one more is kept (progress reports)
    """
    check_int("episodes", episodes, 1)
    if not isinstance(env, VecEnv):
        if not hasattr(getattr(env, "unwrapped", None), "scene"):
            raise TypeError(f"env must be a CrowdNav env or a VecEnv of them, got {type(env).__name__}")
        single = env
        env = DummyVecEnv([lambda: single])
    demo = OrcaPolicy(env.get_attr("scene")[0], safety_space=safety_space, mapping=mapping)
    n = env.num_envs
    pending: list[list[tuple]] = [[] for _ in range(n)]
    kept: list[tuple] = []
    outcomes = {"success": 0, "collision": 0, "timeout": 0}
    done_episodes = 0
    obs = env.reset()
    keys = list(obs)
    while done_episodes < episodes:
        actions, _ = demo.predict(obs)
        new_obs, rewards, dones, infos = env.step(actions)
        if on_step is not None:
            on_step(obs, actions, new_obs, rewards, dones, infos)
        for i in range(n):
            nxt = None
            if keep_next_observations:
                nxt = infos[i]["terminal_observation"] if dones[i] else {k: new_obs[k][i] for k in keys}
            truncated = bool(infos[i].get("TimeLimit.truncated", False))
            pending[i].append(({k: obs[k][i] for k in keys}, nxt, int(actions[i]), float(rewards[i]),
                               bool(dones[i]) and not truncated, bool(dones[i])))
            if dones[i]:
                if done_episodes < episodes:
                    kept.extend(pending[i])
                    outcomes[infos[i]["outcome"]] += 1
                    done_episodes += 1
                    if on_episode is not None:
                        on_episode(done_episodes)
                pending[i] = []
        obs = new_obs
    return Demonstrations(
        observations={k: np.stack([t[0][k] for t in kept]) for k in keys},
        next_observations={k: np.stack([t[1][k] for t in kept]) for k in keys} if keep_next_observations else None,
        actions=np.array([t[2] for t in kept], dtype=np.int64),
        rewards=np.array([t[3] for t in kept], dtype=np.float32),
        terminated=np.array([t[4] for t in kept], dtype=bool),
        episode_end=np.array([t[5] for t in kept], dtype=bool),
        outcomes=outcomes,
    )
