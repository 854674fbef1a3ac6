"""The world contract: everything a model and the env it acts in must agree on, as one frozen value.

An env publishes its :class:`World` (``env.unwrapped.world``); the lookahead (its policy and propagation model) is
built from one; a saved model stores it as plain JSON (:meth:`World.to_dict`), and :func:`compare_worlds` is the one
comparison of a model's world with an env's, used by every loader, the evaluation runner and the CLI.

Which fields must agree depends on what the model does with them (the field sets below): any policy must share the
meaning of an action and the step (:data:`MOTION_FIELDS`); a lookahead also predicts the route's waypoints
(:data:`PREDICTION_FIELDS`); learning in the env also needs the same rewards (every field).

Model files written before this contract stored the same facts as separate entries; :func:`upgrade_policy_kwargs`
and :meth:`World.from_legacy` are the one place that reads those forms.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sb3_crowdnav.sim.actions import ACTION_SETS, N_DIRECTIONS, N_SPEEDS, action_table
from sb3_crowdnav.sim.config import KINEMATICS, RewardConfig, check_robot_limits
from sb3_crowdnav.sim.validation import check_choice, check_int, check_number

# the meaning of an action and of one step: what every policy acting in the env must share
MOTION_FIELDS = ("time_step", "kinematics", "rotation_range", "actions", "max_acceleration", "max_turn_rate",
                 "n_speeds", "n_directions")
# a lookahead also moves the observed route's waypoints itself, by the env's rule
PREDICTION_FIELDS = (*MOTION_FIELDS, "waypoint_radius")
MAX_TIME_STEP = 2.0  # [s] SceneConfig's bound
# the policy-kwargs entries in which files saved before this contract stored the world (read by from_legacy only)
LEGACY_KEYS = ("time_step", "kinematics", "rotation_range", "reward", "obstacles")
# the fields an env takes as keyword arguments of the same name (what a user passes to run a model in its world)
ENV_KEYWORD_FIELDS = ("time_step", "kinematics", "rotation_range", "actions", "max_acceleration", "max_turn_rate",
                      "obstacle_collision_penalty", "waypoint_radius", "progress_reward")
# fields added to the plain form after models were shipped, with the value every file written before them meant
ADDED_FIELDS = {"actions": "paper"}


@dataclass(frozen=True)
class World:
    """What the lookahead and a saved model must agree on with the env they act in.

    :param time_step: Δt of one env step [s]
    :param kinematics: ``"unicycle"`` (actions rotate the heading) or ``"holonomic"`` (directions are relative to the
        goal direction)
    :param rotation_range: width of the direction fan of the action table [rad], in (0, 2π]
    :param actions: the action set, ``"paper"`` (80 actions) or ``"with_stop"`` (81: those and a stop, the last)
    :param max_acceleration: the robot's a_max [m/s²]: the speed (unicycle) or the velocity (holonomic) changes by at
        most a_max·Δt per step (:mod:`sb3_crowdnav.sim.actions`); None: unlimited, the paper's
    :param max_turn_rate: the robot's ω_max [rad/s]: the heading turns by at most ω_max·Δt per step; None:
        unlimited, the paper's (and the only value with ``"holonomic"``)
    :param n_speeds: speeds of the action table, ``v_pref · (1..n_speeds) / n_speeds`` [m/s]
    :param n_directions: directions of the action table across ``rotation_range``
    :param reward: the reward's terms and weights (paper Eq. 9-14)
    :param obstacle_collision_penalty: reward of hitting a static obstacle (a rack or a wall; ends the episode);
        None on the open floor, which has none
    :param waypoint_radius: a route waypoint counts as passed within this distance of the robot's centre [m];
        None on the open floor, which has no route
    :param progress_reward: progress shaping: reward per metre gained during the step on the current waypoint (a
        world with a route, the warehouse) or on the goal (the open floor) [1/m]; 0 without shaping, the paper's reward
    """

    time_step: float = 0.25  # [s]
    kinematics: str = "unicycle"
    rotation_range: float = 2 * math.pi  # [rad]
    actions: str = "paper"
    max_acceleration: float | None = None  # [m/s²]
    max_turn_rate: float | None = None  # [rad/s]
    n_speeds: int = N_SPEEDS
    n_directions: int = N_DIRECTIONS
    reward: RewardConfig = field(default_factory=RewardConfig)
    obstacle_collision_penalty: float | None = None  # [reward]
    waypoint_radius: float | None = None  # [m]
    progress_reward: float = 0.0  # [1/m]

    def __post_init__(self) -> None:
        check_number("time_step", self.time_step)
        if self.time_step > MAX_TIME_STEP:
            raise ValueError(f"time_step must be <= {MAX_TIME_STEP} s, got {self.time_step!r}")
        check_choice("kinematics", self.kinematics, KINEMATICS)
        check_number("rotation_range", self.rotation_range)
        if self.rotation_range > 2 * math.pi + 1e-9:
            raise ValueError(f"rotation_range must be in (0, 2π] rad, got {self.rotation_range!r}")
        check_robot_limits(self.actions, self.max_acceleration, self.max_turn_rate, self.kinematics)
        for name, table in (("n_speeds", N_SPEEDS), ("n_directions", N_DIRECTIONS)):
            check_int(name, getattr(self, name), 1)
            if getattr(self, name) != table:  # the action space is Discrete(N_SPEEDS · N_DIRECTIONS)
                raise ValueError(f"{name} must be {table} (the {N_SPEEDS} x {N_DIRECTIONS} action table is the only "
                                 f"one implemented), got {getattr(self, name)!r}")
        if not isinstance(self.reward, RewardConfig):
            raise TypeError(f"reward must be a RewardConfig, got {type(self.reward).__name__}")
        self._check_static_rules()
        for f in dataclasses.fields(self):  # numpy scalars and ints of float fields become plain floats (JSON)
            value = getattr(self, f.name)
            if f.name not in ("kinematics", "actions", "reward", "n_speeds", "n_directions") and value is not None:
                object.__setattr__(self, f.name, float(value))
            elif isinstance(value, np.integer):
                object.__setattr__(self, f.name, int(value))

    def _check_static_rules(self) -> None:
        if (self.obstacle_collision_penalty is None) != (self.waypoint_radius is None):
            raise ValueError("obstacle_collision_penalty and waypoint_radius must both be set (a world of static "
                             "obstacles and a route) or both be None (the open floor), got "
                             f"{self.obstacle_collision_penalty!r} and {self.waypoint_radius!r}")
        if self.obstacle_collision_penalty is not None:
            check_number("obstacle_collision_penalty", self.obstacle_collision_penalty, positive=False)
            if self.obstacle_collision_penalty > 0:
                raise ValueError(f"obstacle_collision_penalty must be <= 0, got {self.obstacle_collision_penalty!r}")
        if self.waypoint_radius is not None:
            check_number("waypoint_radius", self.waypoint_radius)
        check_number("progress_reward", self.progress_reward, allow_zero=True)

    @property
    def n_actions(self) -> int:
        """The number of actions of the action set (the env's ``Discrete(n_actions)``)."""
        return ACTION_SETS[self.actions]

    @property
    def has_static_world(self) -> bool:
        """True in a world of static obstacles and a route (the warehouse), False on the open floor."""
        return self.waypoint_radius is not None

    @property
    def has_limits(self) -> bool:
        """Whether the robot's acceleration or turn rate is limited (commands beyond reach are clipped)."""
        return self.max_acceleration is not None or self.max_turn_rate is not None

    @property
    def has_value_ceiling(self) -> bool:
        """Whether the lookahead caps V at the largest return a state can have
        (:meth:`~sb3_crowdnav.apg_value.ValueLookaheadPolicy.value_ceiling`): in a world of static obstacles, and
        wherever progress is shaped; not on the paper's open floor, where the shipped models act as trained."""
        return self.has_static_world or self.progress_reward > 0

    def action_table(self, v_pref: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """``(speeds [m/s], directions [rad])`` of the actions at preferred speed ``v_pref``, each (n_actions,)."""
        return action_table(v_pref, self.rotation_range, self.actions)

    # ------------------------------------------------------------------ plain form
    def to_dict(self) -> dict[str, Any]:
        """Every field as plain JSON values (``reward`` as a dict of :class:`RewardConfig`'s fields)."""
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        data["reward"] = dataclasses.asdict(self.reward)
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> World:
        """The :class:`World` of :meth:`to_dict`'s form; every field must be given, and no other key (but a field of
        :data:`ADDED_FIELDS`, which files written before it lack: it takes the value they meant)."""
        if not isinstance(data, Mapping):
            raise TypeError(f"a world must be a mapping of its fields, got {type(data).__name__}")
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(data) - set(names))
        data = {**ADDED_FIELDS, **data}
        missing = [name for name in names if name not in data]
        if unknown or missing:
            raise ValueError(f"a world has exactly the keys {names}; unknown {unknown}, missing {missing}")
        reward = data["reward"]
        if not isinstance(reward, Mapping):
            raise TypeError(f"a world's reward must be a mapping of RewardConfig's fields, got {type(reward).__name__}")
        return cls(**{**data, "reward": _reward_config(reward)})

    @classmethod
    def coerce(cls, world: World | Mapping[str, Any]) -> World:
        """``world`` itself, or the :class:`World` of its plain form (as policy kwargs and model files carry it)."""
        return world if isinstance(world, World) else cls.from_dict(world)

    @classmethod
    def from_legacy(cls, settings: Mapping[str, Any]) -> World:
        """The world of a model file saved before this contract (its settings as separate entries).

        Such files hold some of :data:`LEGACY_KEYS`: ``time_step``, ``kinematics``, ``rotation_range`` (every file;
        SB3 algorithms' files in the member ``sb3_crowdnav.json``, nothing else), ``reward`` (a dict of
        :class:`RewardConfig` fields) and, saved in the warehouse, ``obstacles = {"penalty": ..., "waypoint_radius":
        ..., "progress_reward": ...}``. What a file lacks takes the value its version used: the policy's defaults
        of the time (0.25 s, ``"unicycle"``, 2π, the ``"crowdnav"`` reward), and ``progress_reward`` 0 for warehouse
        files saved before route shaping existed. Any other key is a ``ValueError``.
        """
        if not isinstance(settings, Mapping):
            raise TypeError(f"legacy settings must be a mapping, got {type(settings).__name__}")
        unknown = sorted(set(settings) - set(LEGACY_KEYS))
        if unknown:
            raise ValueError(f"legacy world settings have the keys {LEGACY_KEYS}; unknown {unknown}")
        reward = settings.get("reward") or {"name": "crowdnav"}
        if not isinstance(reward, Mapping):
            raise TypeError(f"legacy reward must be a mapping of RewardConfig's fields, got {type(reward).__name__}")
        static: dict[str, Any] = {}
        obstacles = settings.get("obstacles")
        if obstacles:
            if not isinstance(obstacles, Mapping) or not {"penalty", "waypoint_radius"} <= set(obstacles) \
                    or set(obstacles) - {"penalty", "waypoint_radius", "progress_reward"}:
                raise ValueError("legacy obstacles must be {'penalty': ..., 'waypoint_radius': ...[, "
                                 f"'progress_reward': ...]}}, got {obstacles!r}")
            static = {"obstacle_collision_penalty": obstacles["penalty"],
                      "waypoint_radius": obstacles["waypoint_radius"],
                      "progress_reward": obstacles.get("progress_reward", 0.0)}
        return cls(time_step=settings.get("time_step", 0.25), kinematics=settings.get("kinematics", "unicycle"),
                   rotation_range=settings.get("rotation_range", 2 * math.pi), reward=_reward_config(reward), **static)


def _reward_config(reward: Mapping[str, Any]) -> RewardConfig:
    names = {f.name for f in dataclasses.fields(RewardConfig)}
    unknown = sorted(set(reward) - names)
    if unknown:
        raise ValueError(f"a world's reward has the keys of RewardConfig {sorted(names)}; unknown {unknown}")
    return RewardConfig(**reward)


def upgrade_policy_kwargs(policy_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """A lookahead policy's keyword arguments with the world as one entry ``"world"`` (its plain form).

    The one converter of the form files saved before the world contract (and callers) used: the entries of
    :data:`LEGACY_KEYS` become ``World.from_legacy(...)``. Keyword arguments with a ``"world"`` already come back as
    they are; both forms at once are a ``ValueError``, since it is not clear which one holds.
    """
    kwargs = dict(policy_kwargs)
    legacy = {key: kwargs.pop(key) for key in LEGACY_KEYS if key in kwargs}
    if "world" in kwargs:
        if legacy:
            raise ValueError(f"policy_kwargs has a 'world' and also {sorted(legacy)}: give the world only")
        return kwargs
    if legacy:
        kwargs["world"] = World.from_legacy(legacy).to_dict()
    return kwargs


def compare_worlds(trained: World, actual: World, fields: Iterable[str] | None = None,
                   against: str = "the env") -> str | None:
    """How the world a model was trained in differs from the env's, or None when it does not.

    The message lists each differing field (the reward's by term): ``"the model was trained with time_step=0.5 (the
    env has 0.25), reward.name='comfort' (the env has 'crowdnav')"``. Floats equal to 1e-9 (relative) agree: a value
    read back from text may differ from the env's in the last bits without changing the world.

    :param fields: the fields to compare (:data:`MOTION_FIELDS`, :data:`PREDICTION_FIELDS`; default every field)
    :param against: what ``actual`` belongs to, in the message (another model's file, when models are combined)
    """
    names = [f.name for f in dataclasses.fields(World)]
    fields = names if fields is None else list(fields)
    unknown = sorted(set(fields) - set(names))
    if unknown:
        raise ValueError(f"fields must be fields of World {names}, got unknown {unknown}")
    diffs = []
    for name in fields:
        ours, theirs = getattr(trained, name), getattr(actual, name)
        if name == "reward":
            diffs += [f"reward.{f.name}={getattr(ours, f.name)!r} ({against} has {getattr(theirs, f.name)!r})"
                      for f in dataclasses.fields(RewardConfig) if not _same(getattr(ours, f.name), getattr(theirs, f.name))]
        elif not _same(ours, theirs):
            diffs.append(f"{name}={ours!r} ({against} has {theirs!r})")
    return f"the model was trained with {', '.join(diffs)}" if diffs else None


def env_keywords(trained: World, actual: World, fields: Iterable[str]) -> dict[str, Any]:
    """The env keyword arguments (of :data:`ENV_KEYWORD_FIELDS` among ``fields``) that give ``actual``'s env the
    ``trained`` world's values where they differ: what to pass to run a model in the world it was trained in."""
    return {name: getattr(trained, name) for name in fields
            if name in ENV_KEYWORD_FIELDS and not _same(getattr(trained, name), getattr(actual, name))}


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return abs(a - b) <= 1e-9 * max(1.0, abs(b))
    return a == b


__all__ = ["ADDED_FIELDS", "LEGACY_KEYS", "MOTION_FIELDS", "PREDICTION_FIELDS", "World", "compare_worlds",
           "env_keywords", "upgrade_policy_kwargs"]
