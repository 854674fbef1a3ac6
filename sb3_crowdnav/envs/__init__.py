from sb3_crowdnav.envs.crowd_nav import CrowdNavEnv

__all__ = ["CrowdNavEnv"]
