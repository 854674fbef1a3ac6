from sb3_crowdnav.envs.base import CrowdEnvBase
from sb3_crowdnav.envs.crowd_nav import CrowdNavEnv
from sb3_crowdnav.envs.statistics import EpisodeStatistics

__all__ = ["CrowdEnvBase", "CrowdNavEnv", "EpisodeStatistics"]
