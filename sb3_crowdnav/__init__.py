"""sb3_crowdnav: crowd navigation with deep RL as a Stable-Baselines3 plugin.

``import sb3_crowdnav`` registers the Gymnasium envs (``CrowdNav-v0``, ``CrowdNavSquare-v0``,
``CrowdNavComfort-v0``, ``CrowdNavComfortAngular-v0``).
"""

from __future__ import annotations

import gymnasium as gym

from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
from sb3_crowdnav.sim.orca import OrcaPolicy
from sb3_crowdnav.version import __version__

ENV_IDS = {
    "CrowdNav-v0": {},
    "CrowdNavSquare-v0": {"scenario": "square_crossing"},
    "CrowdNavComfort-v0": {"reward": "comfort"},
    "CrowdNavComfortAngular-v0": {"reward": "comfort_angular"},
}


def _register() -> None:
    for env_id, kwargs in ENV_IDS.items():
        if env_id not in gym.registry:  # guarded: importing twice (or via "sb3_crowdnav:") is harmless
            # no max_episode_steps: the env truncates itself at time_limit / time_step (100 steps by default)
            gym.register(id=env_id, entry_point="sb3_crowdnav.envs.crowd_nav:CrowdNavEnv", kwargs=kwargs)


_register()

from sb3_crowdnav.envs.crowd_nav import CrowdNavEnv  # noqa: E402

__all__ = ["ENV_IDS", "CrowdNavEnv", "OrcaPolicy", "RewardConfig", "SceneConfig", "__version__"]
