"""sb3_crowdnav: crowd navigation with deep RL as a Stable-Baselines3 plugin.

``import sb3_crowdnav`` registers the Gymnasium envs (``CrowdNav-v0``, ``CrowdNavSquare-v0``,
``CrowdNavComfort-v0``, ``CrowdNavComfortAngular-v0``, ``CrowdNavWarehouse-v0``, ``CrowdNavWorlds-v0``) and changes nothing
else: SB3's algorithms take the APG encoder as a class (``PPO(ApgActorCriticPolicy, env)``,
``DQN(ApgDQNPolicy, env)``), and torch's thread count is the caller's (``sb3_crowdnav.nn.configure_cpu``).
"""

from __future__ import annotations

import gymnasium as gym

from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
from sb3_crowdnav.sim.orca import OrcaPolicy
from sb3_crowdnav.sim.world import World
from sb3_crowdnav.version import __version__

ENV_IDS = {
    "CrowdNav-v0": {},
    "CrowdNavSquare-v0": {"scenario": "square_crossing"},
    "CrowdNavComfort-v0": {"reward": "comfort"},
    "CrowdNavComfortAngular-v0": {"reward": "comfort_angular"},
}


WAREHOUSE_ENV_IDS = {"CrowdNavWarehouse-v0": {}}
WORLDS_ENV_IDS = {"CrowdNavWorlds-v0": {}}


def _register() -> None:
    for ids, entry_point in ((ENV_IDS, "sb3_crowdnav.envs.crowd_nav:CrowdNavEnv"),
                             (WAREHOUSE_ENV_IDS, "sb3_crowdnav.envs.warehouse:CrowdNavWarehouseEnv"),
                             (WORLDS_ENV_IDS, "sb3_crowdnav.envs.worlds:CrowdNavWorldsEnv")):
        for env_id, kwargs in ids.items():
            if env_id not in gym.registry:  # guarded: importing twice (or via "sb3_crowdnav:") is harmless
                # no max_episode_steps: the env truncates itself (time_limit / time_step; the warehouse by route)
                gym.register(id=env_id, entry_point=entry_point, kwargs=kwargs)


_register()

from sb3_crowdnav.apg_value import APGValue, ValueLookaheadPolicy  # noqa: E402
from sb3_crowdnav.envs.crowd_nav import CrowdNavEnv  # noqa: E402
from sb3_crowdnav.envs.warehouse import CrowdNavWarehouseEnv  # noqa: E402
from sb3_crowdnav.models import available_pretrained, pretrained  # noqa: E402
from sb3_crowdnav.nn import EXTRACTORS, ApgActorCriticPolicy, ApgDQNPolicy, ApgExtractor  # noqa: E402

__all__ = [
    "ENV_IDS",
    "EXTRACTORS",
    "WAREHOUSE_ENV_IDS",
    "WORLDS_ENV_IDS",
    "APGValue",
    "ApgActorCriticPolicy",
    "ApgDQNPolicy",
    "ApgExtractor",
    "CrowdNavEnv",
    "CrowdNavWarehouseEnv",
    "OrcaPolicy",
    "RewardConfig",
    "SceneConfig",
    "ValueLookaheadPolicy",
    "World",
    "__version__",
    "available_pretrained",
    "pretrained",
]
