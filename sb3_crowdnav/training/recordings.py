"""Recorded scenes in a variant's training worlds (``ScheduleConfig.recordings``, ``sb3-crowdnav train --recording``).

Each recording becomes one more world of ``CrowdNavWorlds-v0`` beside the variant's simulated crowds: ``crowd="replay"``
with the recording's settings (the grammar of ``--crowd replay:PATH[,...]``), the 10 nearest people tracked and
everyone present 1 s before their first annotation unless the settings say otherwise (``tracked="nearest"``,
``lead_in=1``: the observation holds the nearest, and nobody appears on the robot).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sb3_crowdnav.envs.worlds import PRESETS
from sb3_crowdnav.evaluation.crowd_spec import CrowdSpec
from sb3_crowdnav.sim.validation import check_instance

TRAINING_DEFAULTS = {"tracked": "nearest", "lead_in": 1}  # a training scene's replay settings unless given


def check_recordings(variant: str, env_id: str, env_kwargs: Mapping[str, Any], recordings: Sequence[str]) -> tuple[str, ...]:
    """``recordings`` as a tuple, each ``PATH[,key=value...]``; ``ValueError`` naming the parameter for a variant that
    does not train among several crowds on the open floor (``env_id`` and the variant's and run's ``env_kwargs``) or a
    setting outside the grammar (the env checks the file itself when it is built)."""
    check_instance("recordings", recordings, (tuple, list), "a sequence of replay settings 'PATH[,...]'")
    if not recordings:
        return ()
    base, worlds = env_kwargs.get("base_env"), env_kwargs.get("worlds")
    if env_id != "CrowdNavWorlds-v0" or base not in (None, "CrowdNav-v0") or worlds == "warehouse":
        raise ValueError(f"recordings: variant {variant!r} does not train among several crowds on the open floor; "
                         "recorded scenes join a variant that trains in CrowdNavWorlds-v0 on CrowdNav-v0 (apg_robust)")
    for i, text in enumerate(recordings):
        check_instance(f"recordings[{i}]", text, str, "replay settings 'PATH[,frame_rate=F][,key=value...]'")
        CrowdSpec.parse(f"replay:{text}", name=f"recordings[{i}]")
    return tuple(recordings)


def recorded_worlds(recordings: Sequence[str]) -> list[dict[str, Any]]:
    """The worlds of ``recordings``: ``crowd="replay"`` with their settings over :data:`TRAINING_DEFAULTS`."""
    return [{"crowd": "replay", "crowd_kwargs": {**TRAINING_DEFAULTS, **CrowdSpec.parse(f"replay:{text}").crowd_kwargs}}
            for text in recordings]


def with_recordings(env_kwargs: dict[str, Any], recordings: Sequence[str]) -> dict[str, Any]:
    """``env_kwargs`` of ``CrowdNavWorlds-v0`` with the worlds of ``recordings`` after its own (a preset's resolved);
    unchanged without recordings."""
    if not recordings:
        return env_kwargs
    worlds = env_kwargs.get("worlds", "robust")
    simulated = PRESETS[worlds][0] if isinstance(worlds, str) else worlds
    return {**env_kwargs, "worlds": [dict(world) for world in simulated] + recorded_worlds(recordings)}


__all__ = ["TRAINING_DEFAULTS", "check_recordings", "recorded_worlds", "with_recordings"]
