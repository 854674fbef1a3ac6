"""Action masks for sb3-contrib's ``MaskablePPO`` from the lookahead's wall check.

An action is masked when the propagation model (:func:`~sb3_crowdnav.apg_value.propagation.wall_hits`: the env's
kinematics and limits, then the env's swept-disc test on the observed rack and wall segments) predicts that the robot
touches a rack or a wall during the next step. The rule is the lookahead's, read from the observation alone, so the
same mask is computed while training (:class:`WallActionMasker`, sb3-contrib's ``ActionMasker``) and while evaluating
(:class:`WallMaskedPolicy`, ``predict(..., action_masks=...)``).

Never every action: when every action is predicted to hit (the robot already touches a wall), no action is masked,
since a distribution over no action is undefined; the step's reward then says what happened.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from sb3_contrib.common.wrappers import ActionMasker

from sb3_crowdnav.apg_value.propagation import wall_hits
from sb3_crowdnav.sim.observation import OBSTACLE_KEYS, ROBOT_DIM
from sb3_crowdnav.sim.world import World

NO_WALLS = ("MaskablePPO's wall masks need a world of racks and walls (CrowdNavWarehouse-v0); {what} has none, where "
            "every action would stay allowed: train PPO there instead")


def wall_action_masks(world: World, observation: Mapping[str, Any]) -> np.ndarray:
    """Which actions are allowed (True) in ``observation``: those the lookahead does not predict to hit a rack or wall.

    :param world: the env's world (:attr:`CrowdEnvBase.world`); it must have static obstacles
    :param observation: one observation (``robot`` (9,)) or a batch (``robot`` (B, 9)), with ``obstacles`` and
        ``obstacles_mask``
    :return: (A,) or (B, A) bool; a row whose actions would all hit is all True (never every action masked)
    """
    if not isinstance(world, World):
        raise TypeError(f"world must be a World, got {type(world).__name__}")
    if not world.has_static_world:
        raise ValueError(NO_WALLS.format(what="this world"))
    missing = [key for key in ("robot", *OBSTACLE_KEYS) if key not in observation]
    if missing:
        raise ValueError(f"the observation has no {missing}: wall masks read the warehouse's observed segments")
    robot = np.asarray(observation["robot"])
    single = robot.ndim == 1
    robots = robot.reshape(-1, ROBOT_DIM)
    batch = robots.shape[0]
    static = {key: np.asarray(observation[key]).reshape(batch, -1) for key in OBSTACLE_KEYS}
    allowed = ~wall_hits(world, robots, static)  # (B, A)
    allowed[~allowed.any(axis=1)] = True
    return allowed[0] if single else allowed


def _static_world(env: gym.Env) -> World:
    world = getattr(env.unwrapped, "world", None)
    if not isinstance(world, World) or not world.has_static_world:
        spec = getattr(env, "spec", None)
        raise ValueError(NO_WALLS.format(what=spec.id if spec is not None else type(env.unwrapped).__name__))
    return world


class WallActionMasker(ActionMasker):
    """sb3-contrib's ``ActionMasker`` whose ``action_masks()`` are :func:`wall_action_masks` of the latest observation.

    ``MaskablePPO`` finds the method through the VecEnv (``sb3-crowdnav train --algo maskableppo`` wraps every training
    env; in an rl-zoo3 file, ``env_wrapper: sb3_crowdnav.apg_value.action_masks.WallActionMasker``).

    :param env: a crowd env of a world with racks and walls; another is refused (``ValueError``)
    """

    def __init__(self, env: gym.Env) -> None:
        self._world = _static_world(env)
        self._last_obs: Mapping[str, Any] | None = None
        super().__init__(env, self._masks)

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        self._last_obs = obs
        return obs, info

    def step(self, action: Any):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._last_obs = obs
        return obs, reward, terminated, truncated, info

    def _masks(self, env: gym.Env) -> np.ndarray:
        if self._last_obs is None:
            raise RuntimeError("action_masks() before reset(): there is no observation to mask actions in")
        return wall_action_masks(self._world, self._last_obs)


class WallMaskedPolicy:
    """A ``MaskablePPO`` model that acts with the wall masks of each observation (the evaluation's ``predict``).

    Every other attribute is the model's (``policy``, ``observation_space``, ``set_random_seed``, ...).

    :param model: the ``MaskablePPO`` model
    :param world: the world it acts in (the env's), with racks and walls
    """

    def __init__(self, model: Any, world: World) -> None:
        if not isinstance(world, World) or not world.has_static_world:
            raise ValueError(NO_WALLS.format(what="the world given"))
        self.model = model
        self.world = world

    def predict(self, observation: Mapping[str, Any], state: Any = None, episode_start: Any = None,
                deterministic: bool = True):
        """``model.predict`` with ``action_masks`` = :func:`wall_action_masks` of ``observation``."""
        masks = wall_action_masks(self.world, observation)
        return self.model.predict(observation, state, episode_start, deterministic, action_masks=masks)

    def __getattr__(self, name: str) -> Any:
        if name == "model":  # not set yet (a copy being built): no recursion
            raise AttributeError(name)
        return getattr(self.model, name)


__all__ = ["WallActionMasker", "WallMaskedPolicy", "wall_action_masks"]
