"""The ground floor: numpy, pyrvo (ORCA), shapely and networkx (warehouse geometry and routes) only; no torch, no gymnasium."""

from sb3_crowdnav.sim.actions import N_ACTIONS, action_table, apply_action, nearest_action, wrap_angle
from sb3_crowdnav.sim.config import RewardConfig, SceneConfig
from sb3_crowdnav.sim.crowd import CROWD_MODELS, CrowdModel, RobotAgent
from sb3_crowdnav.sim.orca import OrcaPolicy
from sb3_crowdnav.sim.rewards import RewardTerms, closest_approach, compute_reward, walking_direction
from sb3_crowdnav.sim.simulator import CrowdSimulator
from sb3_crowdnav.sim.world import World

__all__ = [
    "CROWD_MODELS",
    "N_ACTIONS",
    "CrowdModel",
    "CrowdSimulator",
    "OrcaPolicy",
    "RewardConfig",
    "RewardTerms",
    "RobotAgent",
    "SceneConfig",
    "World",
    "action_table",
    "apply_action",
    "closest_approach",
    "compute_reward",
    "nearest_action",
    "walking_direction",
    "wrap_angle",
]
