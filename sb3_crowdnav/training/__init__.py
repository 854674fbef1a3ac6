"""The training floor: the paper's schedule for every variant, and training from rl-zoo3 hyperparameter files.

- :func:`train_schedule` / :class:`ScheduleConfig` / :data:`VARIANTS`: the paper's schedule (ORCA imitation, then
  RL by episodes) with checkpoints, resume, signals, validation and best-model selection
  (``sb3-crowdnav train --variant NAME``);
- :func:`train_from_hyperparams` and the rl-zoo3 YAML reading (``sb3-crowdnav train --hyperparams FILE``);
- :func:`average_checkpoints`: one model with the mean weights of a run's checkpoints (weight averaging);
- :func:`ensemble_models`: one model whose V is the mean value of several runs' networks (a value ensemble);
- :mod:`sb3_crowdnav.training.zoo`: ``apg_value`` added to rl-zoo3 itself (``sb3-crowdnav-zoo``).
"""

from sb3_crowdnav.training.averaging import average_checkpoints, ensemble_models
from sb3_crowdnav.training.callbacks import VALIDATION_SEED_OFFSET, EpisodeCheckpoint
from sb3_crowdnav.training.hyperparams import load_hyperparams, prepare, safe_eval, train_from_hyperparams
from sb3_crowdnav.training.schedule import VARIANTS, ScheduleConfig, ScheduleResult, Variant, train_schedule

__all__ = [
    "VALIDATION_SEED_OFFSET",
    "VARIANTS",
    "EpisodeCheckpoint",
    "ScheduleConfig",
    "ScheduleResult",
    "Variant",
    "average_checkpoints",
    "ensemble_models",
    "load_hyperparams",
    "prepare",
    "safe_eval",
    "train_from_hyperparams",
    "train_schedule",
]
