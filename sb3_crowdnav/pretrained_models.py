"""Trained models shipped inside the package: ``sb3_crowdnav.pretrained("apg_rl")``.

Each file in ``sb3_crowdnav/weights/`` is an SB3 ``.zip`` saved without its replay buffer
(policy weights and optimiser state, about 1 MB). They are produced by
``examples/train_paper.py`` (see the README for the command, wall time and results of each).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"

# name -> algorithm of the file weights/<name>.zip
PRETRAINED = {
    "apg_rl": "apg_value",
    "apg_crl": "apg_value",
    "apg_carl": "apg_value",
    "cadrl": "apg_value",
    "sf_rl": "apg_value",
    "lm_rl": "apg_value",
    "ppo_apg": "ppo",
    "dqn_apg": "dqn",
}


def available_pretrained() -> list[str]:
    """Names of the shipped models present in this installation."""
    return [name for name in PRETRAINED if (WEIGHTS_DIR / f"{name}.zip").exists()]


def pretrained_path(name: str) -> Path:
    """Path of a shipped model; ``ValueError`` names the available ones."""
    if name not in PRETRAINED:
        raise ValueError(f"unknown pretrained model {name!r}; known: {sorted(PRETRAINED)}")
    path = WEIGHTS_DIR / f"{name}.zip"
    if not path.exists():
        raise ValueError(f"pretrained model {name!r} is not shipped in this version; available: {available_pretrained()}")
    return path


def pretrained(name: str, env: Any = None, **kwargs: Any):
    """Load a shipped model (``APGValue``, ``PPO`` or ``DQN``) by name, e.g. ``pretrained("apg_rl")``."""
    from sb3_crowdnav.evaluation.models import load_model

    return load_model(pretrained_path(name), env=env, algo=PRETRAINED[name], **kwargs)
