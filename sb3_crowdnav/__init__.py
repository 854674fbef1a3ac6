"""sb3_crowdnav: crowd navigation with deep RL as a Stable-Baselines3 plugin.

``import sb3_crowdnav`` registers the Gymnasium envs (``CrowdNav-v0``, ``CrowdNavSquare-v0``,
``CrowdNavComfort-v0``, ``CrowdNavComfortAngular-v0``, ``CrowdNavWarehouse-v0``).
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


WAREHOUSE_ENV_IDS = {"CrowdNavWarehouse-v0": {}}


def _register() -> None:
    for ids, entry_point in ((ENV_IDS, "sb3_crowdnav.envs.crowd_nav:CrowdNavEnv"),
                             (WAREHOUSE_ENV_IDS, "sb3_crowdnav.envs.warehouse:CrowdNavWarehouseEnv")):
        for env_id, kwargs in ids.items():
            if env_id not in gym.registry:  # guarded: importing twice (or via "sb3_crowdnav:") is harmless
                # no max_episode_steps: the env truncates itself (time_limit / time_step; the warehouse by route)
                gym.register(id=env_id, entry_point=entry_point, kwargs=kwargs)


def _register_policy_aliases() -> None:
    """Let SB3's PPO/A2C and DQN accept ``"ApgPolicy"`` (the APG extractor by default).

    With the alias, an rl-zoo3 file can say ``policy: 'ApgPolicy'`` and tuning, which replaces
    ``policy_kwargs`` wholesale, cannot silently drop the extractor.
    """
    from stable_baselines3 import A2C, DQN, PPO

    from sb3_crowdnav.nn.policies import ApgActorCriticPolicy, ApgDQNPolicy

    for algo, policy in ((PPO, ApgActorCriticPolicy), (A2C, ApgActorCriticPolicy), (DQN, ApgDQNPolicy)):
        if "ApgPolicy" not in algo.policy_aliases:
            algo.policy_aliases = {**algo.policy_aliases, "ApgPolicy": policy}


_register()
_register_policy_aliases()

from sb3_crowdnav.apg_value import APGValue, ValueLookaheadPolicy  # noqa: E402
from sb3_crowdnav.envs.crowd_nav import CrowdNavEnv  # noqa: E402
from sb3_crowdnav.envs.warehouse import CrowdNavWarehouseEnv  # noqa: E402
from sb3_crowdnav.models import available_pretrained, pretrained  # noqa: E402
from sb3_crowdnav.nn import EXTRACTORS, ApgActorCriticPolicy, ApgDQNPolicy, ApgExtractor  # noqa: E402

__all__ = [
    "ENV_IDS",
    "EXTRACTORS",
    "WAREHOUSE_ENV_IDS",
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
    "__version__",
    "available_pretrained",
    "pretrained",
]
