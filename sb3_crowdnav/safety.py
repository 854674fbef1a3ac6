"""An optional protective field around any policy: the robot slows down while a person is inside it.

Warehouse robots that drive among people carry safety-rated scanners whose *protective fields* make the vehicle slow
down or stop when a person enters them, whatever its navigation software decided (ISO 3691-4, driverless industrial
trucks: personnel detection and speed reduction). :class:`ProtectiveField` is such a field's settings and
:class:`ProtectedPolicy` wraps any policy with SB3's ``predict`` so that, at every step:

* the field is the region within ``distance`` [m] of the robot's disc (surface to surface), within ``half_angle``
  [rad] of its heading on either side (π: all around, the default, as two corner scanners cover an AMR);
* a person is inside when their observed disc (the observation's newest row, ``humans_mask`` 1) reaches into it: the
  field sees what the robot's sensors see, racks hide people from it too;
* while someone is inside, an action faster than ``speed_cap`` [m/s] is replaced by the action of the **same
  direction** at the fastest speed of the action table at or below the cap, or by the stop (``actions="with_stop"``)
  when none is; the robot's acceleration limit then brakes it as the env's kinematics allow. Actions at or below the
  cap pass unchanged.

A field whose cap no action can follow (below the slowest speed without a stop) is refused at construction, as is a
field for an env that is not a crowd env. The wrapper counts the steps it capped (:attr:`ProtectedPolicy.capped`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from sb3_crowdnav.sim.actions import N_DIRECTIONS, STOP_ACTION
from sb3_crowdnav.sim.observation import Human, ObservationSchema, Robot
from sb3_crowdnav.sim.validation import check_at_most, check_number


@dataclass(frozen=True)
class ProtectiveField:
    """A protective field's settings (see the module's rules).

    :param distance: [m] the field's reach beyond the robot's disc, > 0
    :param speed_cap: [m/s] the fastest command while someone is inside, >= 0 (0: stop)
    :param half_angle: [rad] the field covers bearings within this of the heading on either side, in (0, π]; π: all
        around
    """

    distance: float = 0.5
    speed_cap: float = 0.3
    half_angle: float = math.pi

    def __post_init__(self) -> None:
        check_number("distance", self.distance)
        check_at_most("distance", self.distance, 20.0, " m")
        check_number("speed_cap", self.speed_cap, allow_zero=True)
        check_at_most("speed_cap", self.speed_cap, 10.0, " m/s")
        check_number("half_angle", self.half_angle)
        check_at_most("half_angle", self.half_angle, math.pi + 1e-9, " rad")
        for name in ("distance", "speed_cap", "half_angle"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @classmethod
    def parse(cls, text: str, name: str = "--protective-field") -> ProtectiveField:
        """``DISTANCE,SPEED_CAP[,HALF_ANGLE_DEG]`` (metres, m/s, degrees), e.g. ``0.5,0.3`` or ``1.0,0,90``;
        ``ValueError`` naming ``name`` otherwise."""
        parts = [p.strip() for p in str(text).split(",")]
        try:
            if len(parts) not in (2, 3):
                raise ValueError("expected 2 or 3 numbers")
            values = [float(p) for p in parts]
            return cls(values[0], values[1], math.radians(values[2]) if len(values) == 3 else math.pi)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be DISTANCE,SPEED_CAP[,HALF_ANGLE_DEG] (m, m/s, degrees; e.g. 0.5,0.3), "
                             f"got {text!r}: {exc}") from None

    def __str__(self) -> str:
        angle = "" if self.half_angle >= math.pi else f", within {math.degrees(self.half_angle):g}° of the heading"
        return f"protective field {self.distance:g} m, cap {self.speed_cap:g} m/s{angle}"


class ProtectedPolicy:
    """``policy`` behind a :class:`ProtectiveField` in ``env``'s world: SB3's ``predict`` signature.

    :param policy: any object with ``predict(observation, state, episode_start, deterministic)``
    :param field: the field
    :param env: the crowd env the policy acts in (its action table and observation schema)
    """

    def __init__(self, policy: Any, field: ProtectiveField, env: Any) -> None:
        if not hasattr(policy, "predict"):
            raise TypeError(f"policy must have predict(observation, ...), got {type(policy).__name__}")
        if not isinstance(field, ProtectiveField):
            raise TypeError(f"field must be a ProtectiveField, got {type(field).__name__}")
        base = getattr(env, "unwrapped", env)
        world, scene = getattr(base, "world", None), getattr(base, "scene", None)
        if world is None or scene is None:
            raise TypeError(f"env must be a sb3_crowdnav crowd env (with a world and a scene), got {type(base).__name__}")
        self.policy, self.field = policy, field
        self.schema = ObservationSchema.from_space(base.observation_space)
        speeds, _ = world.action_table(scene.robot_v_pref)
        self.n_actions = len(speeds)
        self.capped_action = np.arange(self.n_actions)  # the action each one becomes while someone is inside
        for a in np.flatnonzero(speeds > field.speed_cap + 1e-9):
            same = [b for b in range(min(self.n_actions, STOP_ACTION)) if b % N_DIRECTIONS == a % N_DIRECTIONS
                    and speeds[b] <= field.speed_cap + 1e-9]
            if same:
                self.capped_action[a] = max(same, key=lambda b: speeds[b])
            elif self.n_actions > STOP_ACTION:
                self.capped_action[a] = STOP_ACTION
            else:
                raise ValueError(f"speed_cap: {field.speed_cap} m/s is below the slowest action's {speeds.min():g} m/s "
                                 f"and actions={world.actions!r} has no stop; raise it or use actions='with_stop'")
        self.capped = 0  # steps on which the field changed the action
        self.steps = 0

    def inside(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """(B,) bool: whether someone observed is inside the field, for a batch of observations (leading dim B)."""
        robot = np.asarray(observation["robot"], dtype=np.float64).reshape(-1, self.schema.shapes["robot"][0])
        humans = self.schema.humans_view(np.asarray(observation["humans"], dtype=np.float64).reshape(len(robot), -1))
        newest, mask = humans[:, -1], np.asarray(observation["humans_mask"]).reshape(len(robot), -1) > 0.5
        rel = newest[..., Human.POS] - robot[:, None, Robot.POS]
        dist = np.hypot(rel[..., 0], rel[..., 1])
        reach = dist - newest[..., Human.RADIUS] - robot[:, None, Robot.RADIUS] <= self.field.distance
        if self.field.half_angle < math.pi:
            bearing = np.arctan2(rel[..., 1], rel[..., 0]) - robot[:, None, Robot.HEADING]
            bearing = np.abs((bearing + math.pi) % (2 * math.pi) - math.pi)
            # a disc counts when any of it is within the sector: its angular half-width widens the bearing allowed
            half_width = np.arcsin(np.clip(newest[..., Human.RADIUS] / np.maximum(dist, 1e-9), 0.0, 1.0))
            reach &= bearing <= self.field.half_angle + half_width
        return (reach & mask).any(axis=1)

    def predict(self, observation: dict[str, np.ndarray], state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """The wrapped policy's action, capped while someone is inside the field."""
        action, state = self.policy.predict(observation, state=state, episode_start=episode_start,
                                            deterministic=deterministic)
        action = np.asarray(action)
        inside = self.inside(observation).reshape(action.shape) if action.ndim else self.inside(observation)[0]
        capped = np.where(inside, self.capped_action[action.astype(np.int64)], action)
        self.steps += int(np.size(action))
        self.capped += int(np.sum(capped != action))
        return capped.astype(action.dtype), state

    def __getattr__(self, name: str) -> Any:  # the wrapped policy's other attributes (observation_space, world, ...)
        if name == "policy":
            raise AttributeError(name)
        return getattr(self.policy, name)


__all__ = ["ProtectedPolicy", "ProtectiveField"]
