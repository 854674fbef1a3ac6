"""The settings of each crowd model (the env's ``crowd_kwargs``), frozen and validated; numpy-free, so that the scene's
config can check them without importing the models (which import the config)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from sb3_crowdnav.sim.validation import check_at_most, check_choice, check_instance, check_number

MAX_SAFETY_SPACE = 2.0  # [m]


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


# the settings of every registered crowd model, by name (sim/crowd.py's CROWD_MODELS has the same names)
CROWD_SETTINGS: dict[str, type] = {"orca": OrcaCrowdSettings, "linear": LinearCrowdSettings}


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


__all__ = ["CROWD_SETTINGS", "LinearCrowdSettings", "OrcaCrowdSettings", "crowd_settings"]
