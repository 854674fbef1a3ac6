"""The observation schema: the one module that names the observation's keys, shapes and layouts.

Every floor reads the observation through this module: the env builds it
(:meth:`ObservationSchema.observation`, :meth:`ObservationSchema.bounds`), the extractors and the
lookahead validate its space (:meth:`ObservationSchema.from_space`) and view the flat pedestrian
history as (T, max_humans, 5) (:meth:`ObservationSchema.humans_view`), the ORCA robot and the
demonstration collector iterate over :data:`OBS_KEYS`. Adding a key is a change here plus what its
users need of it.

The observation of ``CrowdNav-v0`` is a ``Dict`` in world coordinates:

===============  =====================  =====================================================================
key              shape                  content
===============  =====================  =====================================================================
``robot``        (9,)                   :data:`ROBOT_FIELDS`, columns named by :class:`Robot`
``humans``       (T * max_humans * 5,)  :data:`HUMAN_FIELDS` of every slot for the last T steps, oldest first
``humans_mask``  (max_humans,)          1 for a present pedestrian, 0 for a padded slot
===============  =====================  =====================================================================

``humans`` is stored flat because SB3's ``check_env`` warns on Box shapes that are neither 1-D nor
image-like. Never use bare column numbers elsewhere: name them through :class:`Robot` / :class:`Human`.

The warehouse (``CrowdNavWarehouse-v0``) adds, in world coordinates too:

==================  ====================  =================================================================================
key                 shape                 content
==================  ====================  =================================================================================
``obstacles``       (max_obstacles * 4,)  the nearest rack and wall segments [x0, y0, x1, y1], nearest first, zero padded
``obstacles_mask``  (max_obstacles,)      1 for an observed segment, 0 for padding
``waypoints``       (num_waypoints * 2,)  the robot's current route waypoint and the next ones; the goal repeats at the end
==================  ====================  =================================================================================

This module is on the ground floor (numpy only): it describes spaces without importing Gymnasium;
:meth:`ObservationSchema.from_space` reads any ``Dict``-like space with ``.spaces`` and ``.shape``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

ROBOT_FIELDS = ("px", "py", "vx", "vy", "radius", "gx", "gy", "v_pref", "heading")
HUMAN_FIELDS = ("px", "py", "vx", "vy", "radius")
ROBOT_DIM = len(ROBOT_FIELDS)
HUMAN_DIM = len(HUMAN_FIELDS)
OBS_KEYS = ("robot", "humans", "humans_mask")
OBSTACLE_KEYS = ("obstacles", "obstacles_mask")  # the warehouse's static world, when max_obstacles > 0
WAYPOINT_KEY = "waypoints"  # the warehouse robot's route, when num_waypoints > 0
SEGMENT_DIM = 4  # one obstacle segment: x0, y0, x1, y1


class Robot:
    """Columns of ``observation["robot"]`` (9,)."""

    POS = slice(0, 2)
    VEL = slice(2, 4)
    RADIUS = 4
    GOAL = slice(5, 7)
    V_PREF = 7
    HEADING = 8


class Human:
    """Columns of one pedestrian state (5,) in ``observation["humans"]`` viewed as (T, max_humans, 5)."""

    POS = slice(0, 2)
    VEL = slice(2, 4)
    RADIUS = 4


HOW_TO_FIX = (
    "Use the observation space of a sb3_crowdnav env (e.g. gym.make('CrowdNav-v0')) without observation "
    "wrappers that flatten, stack or normalise it (FlattenObservation, VecFrameStack, VecNormalize)."
)


class ObservationSpaceError(ValueError, TypeError):
    """An observation space that is not a crowd observation; a ``ValueError`` and, for the wrong kind of space,
    a ``TypeError`` too, so that a caller may catch either kind of mistake."""


@dataclass(frozen=True)
class ObservationSchema:
    """Shapes of the crowd observation for a history length T and a pedestrian capacity ``max_humans``."""

    history_length: int
    max_humans: int
    max_obstacles: int = 0  # 0: no obstacle keys (CrowdNav-v0)
    num_waypoints: int = 0  # 0: no waypoint key

    @property
    def humans_shape(self) -> tuple[int, int, int]:
        """The logical shape of ``humans``: (T, max_humans, 5)."""
        return (self.history_length, self.max_humans, HUMAN_DIM)

    @property
    def shapes(self) -> dict[str, tuple[int, ...]]:
        """Stored shape of every key (one observation, no batch dimension)."""
        shapes = {"robot": (ROBOT_DIM,), "humans": (int(np.prod(self.humans_shape)),), "humans_mask": (self.max_humans,)}
        if self.max_obstacles:
            shapes.update(obstacles=(self.max_obstacles * SEGMENT_DIM,), obstacles_mask=(self.max_obstacles,))
        if self.num_waypoints:
            shapes[WAYPOINT_KEY] = (self.num_waypoints * 2,)
        return shapes

    def humans_view(self, humans: Any) -> Any:
        """View flat ``humans`` (..., T*M*5) as (..., T, M, 5); numpy arrays and torch tensors alike."""
        return humans.reshape(*humans.shape[:-1], *self.humans_shape)

    @staticmethod
    def flatten_humans(history: Any) -> Any:
        """The inverse of :meth:`humans_view`: (..., T, M, 5) to (..., T*M*5)."""
        return history.reshape(*history.shape[:-3], -1)

    def observation(self, robot: np.ndarray, history: np.ndarray, mask: np.ndarray, obstacles: np.ndarray | None = None,
                    obstacles_mask: np.ndarray | None = None,
                    waypoints: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """One observation (float32) from the robot state (9,), the history (T, M, 5) and the presence mask (M,);
        in the warehouse also the segments (max_obstacles, 4) with their mask and the waypoints (K, 2)."""
        obs = {"robot": robot.astype(np.float32), "humans": history.astype(np.float32).ravel(),
               "humans_mask": mask.astype(np.float32)}
        if self.max_obstacles:
            obs.update(obstacles=obstacles.astype(np.float32).ravel(), obstacles_mask=obstacles_mask.astype(np.float32))
        if self.num_waypoints:
            obs[WAYPOINT_KEY] = waypoints.astype(np.float32).ravel()
        return obs

    def bounds(self, pos_bound: float, vel_bound: float, radius_bound: float,
               v_pref_bound: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """(low, high) float32 arrays of every key: positions within ±``pos_bound``, velocities within
        ±``vel_bound``, radii in [0, ``radius_bound``], v_pref in [0, ``v_pref_bound``], heading in [-π, π]."""
        robot_hi = np.array([pos_bound, pos_bound, vel_bound, vel_bound, radius_bound, pos_bound, pos_bound,
                             v_pref_bound, np.pi + 0.01], dtype=np.float32)
        robot_lo = -robot_hi
        robot_lo[Robot.RADIUS] = 0.0
        robot_lo[Robot.V_PREF] = 0.0
        human_hi = np.array([pos_bound, pos_bound, vel_bound, vel_bound, radius_bound], dtype=np.float32)
        human_lo = -human_hi
        human_lo[Human.RADIUS] = 0.0
        return {
            "robot": (robot_lo, robot_hi),
            "humans": (np.broadcast_to(human_lo, self.humans_shape).ravel(),
                       np.broadcast_to(human_hi, self.humans_shape).ravel()),
            "humans_mask": (np.zeros(self.max_humans, dtype=np.float32), np.ones(self.max_humans, dtype=np.float32)),
            **self._static_bounds(pos_bound),
        }

    def _static_bounds(self, pos_bound: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for key, shape in self.shapes.items():
            if key in (*OBSTACLE_KEYS, WAYPOINT_KEY):
                high = np.full(shape, 1.0 if key == "obstacles_mask" else pos_bound, dtype=np.float32)
                out[key] = (np.zeros(shape, dtype=np.float32) if key == "obstacles_mask" else -high, high)
        return out

    @classmethod
    def from_space(cls, observation_space: Any) -> ObservationSchema:
        """Validate a crowd observation space (a Gymnasium ``Dict`` of 1-D ``Box``) and read its schema.

        :class:`ObservationSpaceError` (a ``ValueError`` and a ``TypeError``) when it is not a ``Dict``,
        ``ValueError`` naming the key and the expected shape otherwise.
        """
        subspaces = getattr(observation_space, "spaces", None)
        if not isinstance(subspaces, dict):
            raise ObservationSpaceError(f"expected a gymnasium.spaces.Dict observation space with keys {OBS_KEYS}, got "
                            f"{type(observation_space).__name__}. {HOW_TO_FIX}")
        missing = [k for k in OBS_KEYS if k not in subspaces]
        if missing:
            raise ValueError(f"observation space lacks key(s) {missing}; it has {sorted(subspaces)}. {HOW_TO_FIX}")
        for key in OBS_KEYS:
            shape = getattr(subspaces[key], "shape", None)
            if type(subspaces[key]).__name__ != "Box" or shape is None or len(shape) != 1:
                raise ValueError(f"observation_space[{key!r}] must be a 1-D Box, got {subspaces[key]}. {HOW_TO_FIX}")
        if subspaces["robot"].shape != (ROBOT_DIM,):
            raise ValueError(f"observation_space['robot'] must have shape ({ROBOT_DIM},), got "
                             f"{subspaces['robot'].shape}. {HOW_TO_FIX}")
        max_humans = subspaces["humans_mask"].shape[0]
        size = subspaces["humans"].shape[0]
        if max_humans < 1 or size == 0 or size % (max_humans * HUMAN_DIM) != 0:
            raise ValueError(f"observation_space['humans'] must hold T * max_humans * {HUMAN_DIM} values with "
                             f"max_humans = humans_mask size = {max_humans}; got {size} values. {HOW_TO_FIX}")
        max_obstacles = subspaces["obstacles_mask"].shape[0] if "obstacles_mask" in subspaces else 0
        num_waypoints = subspaces[WAYPOINT_KEY].shape[0] // 2 if WAYPOINT_KEY in subspaces else 0
        schema = cls(size // (max_humans * HUMAN_DIM), max_humans, max_obstacles, num_waypoints)
        for key, shape in schema.shapes.items():
            if key in subspaces and subspaces[key].shape != shape:
                raise ValueError(f"observation_space[{key!r}] must have shape {shape}, got {subspaces[key].shape}. "
                                 f"{HOW_TO_FIX}")
        return schema
