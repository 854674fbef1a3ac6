"""Torch crowd encoders (SB3 features extractors) and policies using them (paper §2.1, Table 2).

``EXTRACTORS`` maps a short name to each extractor class: ``"apg"`` (the paper's APG +
temporal attention + LSTM), and the baselines ``"cadrl"``, ``"sf"``, ``"lm"``, ``"lstm_rl"``
and ``"sarl"``. Use one with SB3's stock algorithms::

    DQN("MultiInputPolicy", env, policy_kwargs=dict(features_extractor_class=EXTRACTORS["sarl"]))
    DQN(ApgDQNPolicy, env)  # APG by default

:class:`NStepDictReplayBuffer` gives DQN and QR-DQN n-step returns on these Dict observations (SB3 2.9 builds its
n-step buffer for Box observations only).
"""

from __future__ import annotations

from sb3_crowdnav.nn.buffers import DictNStepMixin, NStepDictReplayBuffer, dict_n_step_kwargs
from sb3_crowdnav.nn.extractors import (
    EXTRACTORS,
    ApgExtractor,
    CadrlExtractor,
    CrowdFeaturesExtractor,
    LmExtractor,
    LstmRlExtractor,
    SarlExtractor,
    SfExtractor,
)
from sb3_crowdnav.nn.interactions import angular_pedestrian_grid, local_occupancy_map, sector_of, social_forces
from sb3_crowdnav.nn.layers import MLP, set_onednn_inference, set_onednn_training
from sb3_crowdnav.nn.perf import configure_cpu, tune_malloc
from sb3_crowdnav.nn.policies import (
    APG_POLICIES,
    ApgActorCriticPolicy,
    ApgDQNPolicy,
    ApgMaskablePolicy,
    ApgQRDQNPolicy,
    ApgRecurrentPolicy,
)
from sb3_crowdnav.nn.transforms import (
    HUMAN_FEATURES,
    ROBOT_FEATURES,
    HumanFeat,
    RobotFeat,
    goal_frame_grid,
    parse_observation_space,
    robot_centric,
    split_observation,
)

__all__ = [
    "APG_POLICIES",
    "EXTRACTORS",
    "HUMAN_FEATURES",
    "MLP",
    "ROBOT_FEATURES",
    "ApgActorCriticPolicy",
    "ApgDQNPolicy",
    "ApgExtractor",
    "ApgMaskablePolicy",
    "ApgQRDQNPolicy",
    "ApgRecurrentPolicy",
    "CadrlExtractor",
    "CrowdFeaturesExtractor",
    "DictNStepMixin",
    "HumanFeat",
    "LmExtractor",
    "LstmRlExtractor",
    "NStepDictReplayBuffer",
    "RobotFeat",
    "SarlExtractor",
    "SfExtractor",
    "angular_pedestrian_grid",
    "configure_cpu",
    "dict_n_step_kwargs",
    "goal_frame_grid",
    "local_occupancy_map",
    "parse_observation_space",
    "robot_centric",
    "sector_of",
    "set_onednn_inference",
    "set_onednn_training",
    "social_forces",
    "split_observation",
    "tune_malloc",
]
