"""The settings of each crowd model (the env's ``crowd_kwargs``), frozen and validated; free of the models (and of
the config), so that the scene's config can check them without importing the models (which import the config). The
replay's settings read their recording with :mod:`sb3_crowdnav.sim.recording` (numpy only)."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from sb3_crowdnav.sim.recording import MAX_COORDINATE, Recording, read_recording
from sb3_crowdnav.sim.validation import (
    check_at_most,
    check_choice,
    check_instance,
    check_int,
    check_number,
    check_positive,
)

MAX_SAFETY_SPACE = 2.0  # [m]
TRACKED = ("all", "nearest")  # crowd='replay''s choices of who is observed
APPEAR = ("as_recorded", "clear")  # crowd='replay''s choices of when a person appears
# upper bounds of the social force settings (name, limit, unit): beyond them a setting is a slip, not a crowd
SOCIAL_FORCE_LIMITS = (
    ("person_strength", 1e5, " N"), ("wall_strength", 1e5, " N"), ("force_range", 5.0, " m"),
    ("relaxation_time", 10.0, " s"), ("sub_steps", 100, ""),
)


@dataclass(frozen=True)
class OrcaCrowdSettings:
    """``crowd_kwargs`` of ``crowd="orca"`` (ORCA's shared parameters stay the scene's ``orca_*`` fields, which the
    ORCA robot reads too).

    :param safety_space: [m] extra radius each person's ORCA keeps from the others and from a robot it sees (the
        observed radius stays ``human_radius``); 0 is the paper's crowd
    """

    safety_space: float = 0.0

    def __post_init__(self) -> None:
        check_number("crowd_kwargs['safety_space']", self.safety_space, allow_zero=True)
        check_at_most("crowd_kwargs['safety_space']", self.safety_space, MAX_SAFETY_SPACE, " m")
        if not isinstance(self.safety_space, float):
            object.__setattr__(self, "safety_space", float(self.safety_space))


@dataclass(frozen=True)
class LinearCrowdSettings:
    """``crowd_kwargs`` of ``crowd="linear"``: none (each person walks straight to its goal at its preferred speed)."""


MAX_CROSSING = 100.0  # [m]
MAX_LEAD_IN = 10.0  # [s] replay's lead_in: longer extrapolates a straight walk too far


def _point(name: str, value: Any) -> tuple[float, float] | None:
    """``value`` as an (x, y) pair of floats [m], or None."""
    if value is None:
        return None
    check_instance(name, value, (tuple, list), "an (x, y) pair [m] or None")
    if len(value) != 2:
        raise ValueError(f"{name} must be an (x, y) pair [m], got {value!r}")
    for v in value:
        check_number(name, v, positive=False)
        check_at_most(f"|{name}|", abs(v), MAX_COORDINATE, " m")
    return float(value[0]), float(value[1])


@dataclass(frozen=True)
class ReplayCrowdSettings:
    """``crowd_kwargs`` of ``crowd="replay"``: people who walk as recorded (:mod:`sb3_crowdnav.sim.replay`).

    The file is read and checked once, here (:func:`~sb3_crowdnav.sim.recording.read_recording`; a bad recording is a
    ``ValueError`` naming ``file:line``); the result is :attr:`recording`.

    :param path: the recording, a ``t,id,x,y`` CSV (t [s], x, y [m]) or an ETH/UCY text file (``frame ped_id x y``)
    :param frame_rate: [frames/s] of the original video: required for the ETH/UCY text format (ETH 15, HOTEL and UCY
        25), refused for a CSV
    :param robot_start: (x, y) [m] the robot's start in the recording's frame; with ``robot_goal``, or neither (then
        both are placed per episode across the busy part of the window, see :class:`~sb3_crowdnav.sim.replay.ReplayCrowdModel`)
    :param robot_goal: (x, y) [m] the robot's goal
    :param start_time: [s] recording time at which every episode starts; None: drawn per episode, uniformly over the
        times that leave a whole episode (``time_limit``) in the recording (or in ``time_window``)
    :param time_window: (start, end) [s]: the part of the recording the episodes are taken from; None: all of it
    :param crossing_length: [m] the distance from the placed start to the placed goal (refused with a given start and
        goal)
    :param tracked: who is observed when more people are present than ``max_humans``: ``"all"`` (the default) refuses
        such a recording at construction; ``"nearest"`` observes the ``max_humans`` present people nearest to the
        robot at the start of each step, as a tracker that reports its N nearest tracks (a person who enters that set
        starts a new track, its history its state repeated). Real scenes (ETH, UCY) have up to 18-62 people at once.
    :param lead_in: [s] each person is present this long before their first sample, walking back along their first
        segment (0: from the first sample, as recorded). Annotators start a track when a person is first marked, which
        in the ETH/UCY scenes is often well inside the view (people step out of a door, or are marked late): with 0
        such a person appears from nowhere, possibly in contact with the robot, which no sensor would allow
    :param appear: when a person appears: ``"as_recorded"`` (the default) at their first sample (less ``lead_in``),
        wherever the robot is; ``"clear"``: the same, except that a person whose disc would touch the robot's during
        the step they appear in (the robot's move through the step against the person where they appear: the
        collision test of the reward) is held back, absent and unobserved, until a step in which it would not, and
        appears there, where the recording has them then. A person who steps out of a door or is marked late is
        then never counted as a collision the robot could not have seen coming; nobody's path is changed
    """

    path: str | None = None
    frame_rate: float | None = None
    robot_start: tuple[float, float] | None = None
    robot_goal: tuple[float, float] | None = None
    start_time: float | None = None
    time_window: tuple[float, float] | None = None
    crossing_length: float = 8.0
    tracked: str = "all"
    lead_in: float = 0.0
    appear: str = "as_recorded"

    def __post_init__(self) -> None:
        if self.path is None:
            raise ValueError("crowd_kwargs['path'] is required with crowd='replay': the recording to replay (a "
                             "t,id,x,y CSV or an ETH/UCY text file)")
        check_instance("crowd_kwargs['path']", self.path, (str, os.PathLike), "a str or a path")
        object.__setattr__(self, "path", os.fspath(self.path))
        if not os.path.isfile(self.path):
            raise ValueError(f"crowd_kwargs['path']: no file at {self.path!r}")
        if self.frame_rate is not None:
            check_positive("crowd_kwargs['frame_rate']", self.frame_rate, " [frames/s]")
            object.__setattr__(self, "frame_rate", float(self.frame_rate))
        start, goal = _point("crowd_kwargs['robot_start']", self.robot_start), \
            _point("crowd_kwargs['robot_goal']", self.robot_goal)
        if (start is None) != (goal is None):
            raise ValueError("crowd_kwargs: give robot_start and robot_goal together, or neither (then they are "
                             f"placed per episode); got robot_start={start!r}, robot_goal={goal!r}")
        if start is not None and math.dist(start, goal) == 0:
            raise ValueError(f"crowd_kwargs: robot_start and robot_goal must differ, both are {start!r}")
        object.__setattr__(self, "robot_start", start)
        object.__setattr__(self, "robot_goal", goal)
        check_number("crowd_kwargs['crossing_length']", self.crossing_length)
        check_at_most("crowd_kwargs['crossing_length']", self.crossing_length, MAX_CROSSING, " m")
        object.__setattr__(self, "crossing_length", float(self.crossing_length))
        check_choice("crowd_kwargs['tracked']", self.tracked, TRACKED)
        check_number("crowd_kwargs['lead_in']", self.lead_in, allow_zero=True)
        check_at_most("crowd_kwargs['lead_in']", self.lead_in, MAX_LEAD_IN, " s")
        object.__setattr__(self, "lead_in", float(self.lead_in))
        check_choice("crowd_kwargs['appear']", self.appear, APPEAR)
        if start is not None and self.crossing_length != 8.0:
            raise ValueError("crowd_kwargs['crossing_length'] sets the placed crossing; with robot_start and "
                             "robot_goal given it has no effect")
        try:
            recording = read_recording(self.path, self.frame_rate)
        except ValueError as error:
            raise ValueError(f"crowd_kwargs: {error}") from None
        object.__setattr__(self, "_recording", recording)
        self._check_times(*recording.span)

    def _check_times(self, first: float, last: float) -> None:
        if self.time_window is not None:
            name = "crowd_kwargs['time_window']"
            check_instance(name, self.time_window, (tuple, list), "a (start, end) pair [s] or None")
            if len(self.time_window) != 2:
                raise ValueError(f"{name} must be a (start, end) pair [s], got {self.time_window!r}")
            for v in self.time_window:
                check_number(name, v, positive=False)
            lo, hi = (float(v) for v in self.time_window)
            if not (lo < hi and lo <= last and hi >= first):
                raise ValueError(f"{name} must satisfy start < end and overlap the recording's times [{first!r}, "
                                 f"{last!r}] s, got {self.time_window!r}")
            object.__setattr__(self, "time_window", (lo, hi))
        if self.start_time is not None:
            check_number("crowd_kwargs['start_time']", self.start_time, positive=False)
            object.__setattr__(self, "start_time", float(self.start_time))
            lo, hi = self.window
            if not lo <= self.start_time <= hi:
                raise ValueError(f"crowd_kwargs['start_time'] must lie within the recording's times (and time_window) "
                                 f"[{lo!r}, {hi!r}] s, got {self.start_time!r}")

    @property
    def recording(self) -> Recording:
        """The recording, read and checked at construction."""
        return self._recording  # type: ignore[attr-defined]

    @property
    def window(self) -> tuple[float, float]:
        """The part of the recording the episodes are taken from [s]: ``time_window`` within the recording's span."""
        first, last = self.recording.span
        if self.time_window is None:
            return first, last
        return max(first, self.time_window[0]), min(last, self.time_window[1])

    @property
    def max_speed(self) -> float:
        """[m/s] the fastest replayed speed (the observation's bound on the people's velocities)."""
        return self.recording.max_speed

    @property
    def extent(self) -> float:
        """[m] the largest absolute coordinate an episode can place a person or the robot's start or goal at."""
        people = self.recording.extent + self.lead_in * self.recording.max_speed  # (walked back along a segment)
        if self.robot_start is None:  # the placed crossing's centre lies among the samples
            return people + self.crossing_length / 2
        return max(people, *map(abs, (*self.robot_start, *self.robot_goal)))




@dataclass(frozen=True)
class SocialForceCrowdSettings:
    """``crowd_kwargs`` of ``crowd="social_force"``: Helbing's social force model (JuPedSim's ``SocialForceModel``).

    Each person is driven towards its preferred velocity with the relaxation time and pushed away from every other
    person (and from a robot it sees) by ``person_strength * exp((r_i + r_j - d) / force_range)`` and from every wall
    by ``wall_strength * exp((r_i - d) / force_range)``, d the distance between centres (to the wall's nearest
    point); mass 80 kg (only the forces over the mass act, so the strengths set it). The defaults are softer and
    longer-ranged than Helbing, Farkas & Vicsek (2000)'s evacuation values (2000 N, 0.08 m, 0.5 s): people walking,
    not pushing (``docs/decisions.md``). JuPedSim's contact forces
    (body force 120000 kg/s², friction 240000 kg/(m s)) act only when bodies overlap and stay its defaults.

    :param person_strength: [N] the repulsion between two people at contact (A of the paper); 0: they ignore each other
    :param wall_strength: [N] the repulsion of a wall or rack at contact; 0: people walk through walls
    :param force_range: [m] the decay length of both repulsions (B of the paper)
    :param relaxation_time: [s] how fast a person takes up its preferred velocity (τ of the paper)
    :param sub_steps: integration steps per env step (the model is integrated at ``time_step / sub_steps``); None
        (default): the fewest that integrate the strengths, the range and the contact force stably (7 at 0.25 s);
        fewer are refused (the explicit integration would blow people apart)
    """

    person_strength: float = 500.0
    wall_strength: float = 500.0
    force_range: float = 0.3
    relaxation_time: float = 0.5
    sub_steps: int | None = None

    def __post_init__(self) -> None:
        for name in ("person_strength", "wall_strength"):
            check_number(f"crowd_kwargs['{name}']", getattr(self, name), allow_zero=True)
        for name in ("force_range", "relaxation_time"):
            check_number(f"crowd_kwargs['{name}']", getattr(self, name))
        if self.sub_steps is not None:
            check_int("crowd_kwargs['sub_steps']", self.sub_steps, 1)
            object.__setattr__(self, "sub_steps", int(self.sub_steps))
        for name, limit, unit in SOCIAL_FORCE_LIMITS:
            if getattr(self, name) is not None:
                check_at_most(f"crowd_kwargs['{name}']", getattr(self, name), limit, unit)
        for name in ("person_strength", "wall_strength", "force_range", "relaxation_time"):
            object.__setattr__(self, name, float(getattr(self, name)))


# the settings of every registered crowd model, by name (sim/crowd.py's CROWD_MODELS has the same names)
CROWD_SETTINGS: dict[str, type] = {
    "orca": OrcaCrowdSettings,
    "linear": LinearCrowdSettings,
    "social_force": SocialForceCrowdSettings,
    "replay": ReplayCrowdSettings,
}


def crowd_settings(crowd: str, value: Any) -> Any:
    """The frozen settings of model ``crowd`` from ``crowd_kwargs`` (a mapping, None, or the settings object).

    ``ValueError`` for an unknown model or an unknown key (naming the keys allowed), ``TypeError`` for a value that is
    not a mapping; each setting is checked by the settings class.
    """
    check_choice("crowd", crowd, tuple(CROWD_SETTINGS))
    cls = CROWD_SETTINGS[crowd]
    if isinstance(value, cls):
        return value
    if value is None:
        return cls()
    check_instance("crowd_kwargs", value, Mapping, f"a dict of crowd {crowd!r}'s settings or None")
    allowed = sorted(f.name for f in fields(cls))
    unknown = sorted(str(k) for k in value if k not in allowed)
    if unknown:
        raise ValueError(f"crowd_kwargs: unknown setting(s) {unknown} for crowd={crowd!r}; allowed: {allowed}")
    return cls(**value)


__all__ = ["CROWD_SETTINGS", "LinearCrowdSettings", "OrcaCrowdSettings", "ReplayCrowdSettings",
           "SocialForceCrowdSettings", "crowd_settings"]
