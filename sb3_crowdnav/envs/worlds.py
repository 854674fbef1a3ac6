"""``CrowdNavWorlds-v0``: episodes drawn from several crowds around one robot (training for people never met).

Each episode is one of a list of *worlds*: the same env (``CrowdNav-v0`` or ``CrowdNavWarehouse-v0``) with different
people, drawn per episode with given weights. Everything else (the robot, its actions and limits, the sensing, the
reward, the observation) is one for all worlds, so a model sees one env and one world contract::

    env = gym.make("CrowdNavWorlds-v0", worlds="robust")  # the apg_robust recipe's crowds
    env = gym.make("CrowdNavWorlds-v0", worlds=[{"crowd": "orca"}, {"crowd": "social_force"}], weights=[0.7, 0.3],
                   num_humans=(0, 10))  # keyword arguments beside worlds/weights/base_env: every world's

A world is a dict of the base env's keyword arguments that set the people (:data:`PEOPLE_KEYS`); the other keyword
arguments are given once and go to every world. ``info["world"]`` is the index of the episode's world.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_crowdnav.envs.crowd_nav import ORCA_KEYS, REPLAY_DECIDES
from sb3_crowdnav.sim.population import MEASURED_POPULATION
from sb3_crowdnav.sim.validation import check_choice, check_instance, check_number

# the keyword arguments that set who the people are and how they move: what may differ between worlds
PEOPLE_KEYS = ("crowd", "crowd_kwargs", "human_policy", "num_humans", "human_speed", "human_v_pref",
               "stop_probability", "stop_duration", "robot_visible")
BASE_ENVS = ("CrowdNav-v0", "CrowdNavWarehouse-v0")
# what a recorded world's recording decides, so that it does not take these from the keyword arguments of every world
RECORDING_DECIDES = (*REPLAY_DECIDES, *ORCA_KEYS)

# the apg_robust recipe's crowds, 0 to 10 people each (num_humans given once; see docs/decisions.md, "Robust
# training"): the paper's ORCA walkers at 1 m/s who never see the robot; the measured-speed population (ORCA, people
# who stop, half of them see the robot); social force at measured speeds, blind to the robot like recorded people
ROBUST_WORLDS = (
    MappingProxyType({"crowd": "orca"}),
    MappingProxyType({"crowd": "orca", **MEASURED_POPULATION}),
    MappingProxyType({"crowd": "social_force", "human_speed": "measured", "stop_probability": 0.2}),
)
# the apg_warehouse recipe's pickers: the warehouse's own (ORCA, 4 in 5 see the robot), and social force (everyone
# sees the robot: JuPedSim takes no share), both at measured walking speeds
WAREHOUSE_WORLDS = (
    MappingProxyType({"crowd": "orca", "human_speed": "measured"}),
    MappingProxyType({"crowd": "social_force", "human_speed": "measured", "robot_visible": True}),
)
PRESETS = {"robust": (ROBUST_WORLDS, "CrowdNav-v0"), "warehouse": (WAREHOUSE_WORLDS, "CrowdNavWarehouse-v0")}


def _recorded(world: Mapping[str, Any]) -> bool:
    return world.get("crowd") == "replay"


def _shared(kwargs: Mapping[str, Any], world: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword arguments given for every world that this world takes: all of them, except that a recorded world
    (``crowd="replay"``) leaves to its recording what the recording decides (:data:`RECORDING_DECIDES`), so that one
    ``num_humans`` can serve the simulated worlds beside it."""
    if not _recorded(world):
        return dict(kwargs)
    return {key: value for key, value in kwargs.items() if key not in RECORDING_DECIDES}


def _people_free(env: gym.Env) -> tuple[Any, ...]:
    """What must be the same in every world: the scene without its people, the reward, the world contract, the
    spaces and (warehouse) the layout settings."""
    scene = {f.name: getattr(env.scene, f.name) for f in dataclasses.fields(env.scene) if f.name not in PEOPLE_KEYS}
    return scene, env.reward_config, env.world, env.action_space, getattr(env, "config", None)


def _layout(space: spaces.Dict) -> dict[str, tuple]:
    """Each key's shape and dtype (what a model's network takes; the bounds aside)."""
    return {key: (box.shape, box.dtype) for key, box in space.spaces.items()}


def widest(observation_spaces: Sequence[spaces.Dict]) -> spaces.Dict:
    """The Dict space whose boxes hold every one of ``observation_spaces``' (same keys, shapes and dtypes; the
    bounds differ with the people's fastest speed)."""
    first = observation_spaces[0]
    return spaces.Dict({key: spaces.Box(np.min([s[key].low for s in observation_spaces], axis=0),
                                        np.max([s[key].high for s in observation_spaces], axis=0), dtype=box.dtype)
                        for key, box in first.spaces.items()})


class CrowdNavWorldsEnv(gym.Env):
    """Episodes drawn from several worlds of one base env that differ only in their people (see the module).

    :param worlds: a preset name (``"robust"``: :data:`ROBUST_WORLDS` on ``CrowdNav-v0``; ``"warehouse"``:
        :data:`WAREHOUSE_WORLDS` on ``CrowdNavWarehouse-v0``) or a sequence of dicts of :data:`PEOPLE_KEYS`
    :param weights: the probability of each world per episode (normalised; None: equal)
    :param base_env: ``"CrowdNav-v0"`` or ``"CrowdNavWarehouse-v0"``; None: the preset's, else ``"CrowdNav-v0"``
    :param render_mode: passed to every world
    :param kwargs: the base env's keyword arguments for every world (a world's own people keys override them; a
        recorded world, ``crowd="replay"``, takes none of :data:`RECORDING_DECIDES`: its recording decides how many
        people walk, how fast, who stops and who sees the robot)
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 4}

    def __init__(self, worlds: str | Sequence[Mapping[str, Any]] = "robust", weights: Sequence[float] | None = None,
                 base_env: str | None = None, render_mode: str | None = None, **kwargs: Any) -> None:
        super().__init__()
        if isinstance(worlds, str):
            check_choice("worlds", worlds, tuple(PRESETS))
            worlds, preset_base = PRESETS[worlds]
        else:
            preset_base = "CrowdNav-v0"
        base_env = preset_base if base_env is None else base_env
        check_choice("base_env", base_env, BASE_ENVS)
        check_instance("worlds", worlds, (list, tuple), "a preset name or a list of dicts")
        if not worlds:
            raise ValueError("worlds must hold at least one world, got an empty list")
        for i, world in enumerate(worlds):
            check_instance(f"worlds[{i}]", world, Mapping, "a dict of people keyword arguments")
            other = sorted(set(world) - set(PEOPLE_KEYS))
            if other:
                raise ValueError(f"worlds[{i}] sets {other}: a world may set only the people {PEOPLE_KEYS}; give the "
                                 f"other keyword arguments once, for every world")
        self.weights = self._weights(weights, len(worlds))
        self.worlds = tuple(dict(w) for w in worlds)
        for key in sorted(set(kwargs) & {*PEOPLE_KEYS, *RECORDING_DECIDES}):
            if all(key in world or (_recorded(world) and key in RECORDING_DECIDES) for world in self.worlds):
                raise ValueError(f"{key}={kwargs[key]!r} has no effect: every world sets its own {key} or replays a "
                                 "recording that decides it")
        self.base_env = base_env
        self.envs = [gym.make(base_env, render_mode=render_mode, **{**_shared(kwargs, world), **world}).unwrapped
                     for world in self.worlds]
        first = _people_free(self.envs[0])
        for i, env in enumerate(self.envs[1:], start=1):
            if _people_free(env) != first or _layout(env.observation_space) != _layout(self.envs[0].observation_space):
                raise ValueError(f"worlds[{i}] changes more than the people (its robot, reward, observation or layout "
                                 f"settings differ from worlds[0]'s): {self.worlds[i]}")
        # the observations' layout is every world's; their bounds the widest (a faster crowd's)
        self.observation_space = widest([env.observation_space for env in self.envs])
        self.action_space = self.envs[0].action_space
        self.render_mode = render_mode
        self.current = 0
        self.episode_seed: int | None = None  # the current world's env was reset with this seed

    @staticmethod
    def _weights(weights: Sequence[float] | None, n: int) -> np.ndarray:
        if weights is None:
            return np.full(n, 1.0 / n)
        check_instance("weights", weights, (list, tuple, np.ndarray), "a list of numbers, one per world")
        if len(weights) != n:
            raise ValueError(f"weights must have one number per world ({n}), got {len(weights)}")
        for i, w in enumerate(weights):
            check_number(f"weights[{i}]", w, allow_zero=True)
        total = float(sum(weights))
        if total <= 0:
            raise ValueError(f"weights must not all be 0, got {list(weights)}")
        return np.asarray(weights, dtype=np.float64) / total

    # ------------------------------------------------------------------ the current world's env
    @property
    def env(self) -> gym.Env:
        """The base env of the current episode's world."""
        return self.envs[self.current]

    @property
    def scene(self):
        """The current world's :class:`~sb3_crowdnav.sim.config.SceneConfig` (the robot's part is every world's)."""
        return self.env.scene

    @property
    def world(self):
        """The world contract, one for every world."""
        return self.envs[0].world

    def __getattr__(self, name: str) -> Any:  # the rest (sim, trajectory, max_steps, a warehouse's layout...): the current's
        if name.startswith("_") or name in ("envs", "current", "episode_seed"):
            raise AttributeError(name)
        return getattr(self.envs[self.current], name)

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Draw the episode's world (by ``weights``) and its base env's seed from this env's generator, then reset
        that env: the same seed gives the same world and episode."""
        super().reset(seed=seed)
        self.current = int(self.np_random.choice(len(self.envs), p=self.weights))
        self.episode_seed = int(self.np_random.integers(2**63 - 1))
        obs, info = self.env.reset(seed=self.episode_seed, options=options)
        return obs, {**info, "world": self.current}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["world"] = self.current
        return obs, reward, terminated, truncated, info

    def render(self):
        return self.env.render()

    def close(self) -> None:
        for env in self.envs:
            env.close()


__all__ = ["BASE_ENVS", "PEOPLE_KEYS", "RECORDING_DECIDES", "ROBUST_WORLDS", "WAREHOUSE_WORLDS", "CrowdNavWorldsEnv"]
