"""The settings of each crowd model (the env's ``crowd_kwargs``), frozen and validated; numpy-free, so that the scene's
config can check them without importing the models (which import the config)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from sb3_crowdnav.sim.validation import check_at_most, check_choice, check_instance, check_int, check_number

MAX_SAFETY_SPACE = 2.0  # [m]
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
CROWD_SETTINGS: dict[str, type] = {"orca": OrcaCrowdSettings, "linear": LinearCrowdSettings,
                                   "social_force": SocialForceCrowdSettings}


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


__all__ = ["CROWD_SETTINGS", "LinearCrowdSettings", "OrcaCrowdSettings", "SocialForceCrowdSettings", "crowd_settings"]
