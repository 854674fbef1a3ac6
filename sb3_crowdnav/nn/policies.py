"""SB3 policy classes whose **default** features extractor is :class:`ApgExtractor`.

rl-zoo3 (and any caller) may replace ``policy_kwargs`` wholesale; with these classes the APG
encoder stays the default even then. The default head mirrors ψ_M's hidden layers (Table 2:
[150, 100, 100]) instead of SB3's [64, 64]; ``net_arch`` still overrides it.

SB3's own classes are left as they are: pass the class (``PPO(ApgActorCriticPolicy, env)``,
``DQN(ApgDQNPolicy, env)``); the same for sb3-contrib's ``QRDQN`` (:class:`ApgQRDQNPolicy`), ``RecurrentPPO``
(:class:`ApgRecurrentPolicy`) and ``MaskablePPO`` (:class:`ApgMaskablePolicy`). The name ``"ApgPolicy"`` in a
hyperparameter file is resolved by the package's own readers of those files through :data:`APG_POLICIES`
(``sb3-crowdnav train --hyperparams`` and ``sb3-crowdnav-zoo``).
"""

from __future__ import annotations

from typing import Any

from gymnasium import spaces
from sb3_contrib.common.maskable.policies import MaskableMultiInputActorCriticPolicy
from sb3_contrib.common.recurrent.policies import RecurrentMultiInputActorCriticPolicy
from sb3_contrib.qrdqn.policies import MultiInputPolicy as QRDQNMultiInputPolicy
from stable_baselines3.common.policies import MultiInputActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.dqn.policies import MultiInputPolicy as DQNMultiInputPolicy
from torch import nn

from sb3_crowdnav.nn.extractors import ApgExtractor

VALUE_HEAD_ARCH = [150, 100, 100]  # ψ_M of Table 2 without its scalar output


def _q_head(net_arch: list[int] | None, activation_fn: type[nn.Module],
            features_extractor_class: type[BaseFeaturesExtractor],
            features_extractor_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """The keywords of a Q-network policy (DQN's, QR-DQN's): a [150, 100, 100] head unless ``net_arch`` is given."""
    return {"net_arch": list(VALUE_HEAD_ARCH) if net_arch is None else net_arch, "activation_fn": activation_fn,
            "features_extractor_class": features_extractor_class, "features_extractor_kwargs": features_extractor_kwargs}


class ApgDQNPolicy(DQNMultiInputPolicy):
    """DQN ``MultiInputPolicy`` with the APG extractor and a [150, 100, 100] Q-head by default.

    Same arguments as :class:`stable_baselines3.dqn.policies.MultiInputPolicy`.
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        features_extractor_class: type[BaseFeaturesExtractor] = ApgExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(observation_space, action_space, lr_schedule,
                         **_q_head(net_arch, activation_fn, features_extractor_class, features_extractor_kwargs), **kwargs)


def _actor_critic_arch(net_arch: list[int] | dict[str, list[int]] | None) -> list[int] | dict[str, list[int]]:
    """Separate [150, 100, 100] policy and value heads unless ``net_arch`` is given."""
    return {"pi": list(VALUE_HEAD_ARCH), "vf": list(VALUE_HEAD_ARCH)} if net_arch is None else net_arch


class _ApgActorCriticDefaults:
    """The APG defaults of an actor-critic policy class, put before SB3's or sb3-contrib's class in the bases: the
    APG extractor, ReLU activations (the paper's) and separate [150, 100, 100] policy and value heads."""

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        *args: Any,
        features_extractor_class: type[BaseFeaturesExtractor] = ApgExtractor,
        **kwargs: Any,
    ) -> None:
        super().__init__(observation_space, action_space, lr_schedule, _actor_critic_arch(net_arch),
                         activation_fn, *args, features_extractor_class=features_extractor_class, **kwargs)


class ApgActorCriticPolicy(_ApgActorCriticDefaults, MultiInputActorCriticPolicy):
    """``MultiInputActorCriticPolicy`` (PPO, A2C) with the APG extractor by default.

    Defaults differing from SB3: ReLU activations (the paper's) and separate [150, 100, 100]
    policy and value heads. Same arguments as
    :class:`stable_baselines3.common.policies.MultiInputActorCriticPolicy`.
    """


class ApgQRDQNPolicy(QRDQNMultiInputPolicy):
    """sb3-contrib QR-DQN ``MultiInputPolicy`` with the APG extractor and a [150, 100, 100] quantile head by default.

    Same arguments as :class:`sb3_contrib.qrdqn.policies.MultiInputPolicy` (``n_quantiles``: 200 by default).
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        n_quantiles: int = 200,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        features_extractor_class: type[BaseFeaturesExtractor] = ApgExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(observation_space, action_space, lr_schedule, n_quantiles=n_quantiles,
                         **_q_head(net_arch, activation_fn, features_extractor_class, features_extractor_kwargs), **kwargs)


class ApgRecurrentPolicy(_ApgActorCriticDefaults, RecurrentMultiInputActorCriticPolicy):
    """sb3-contrib ``MultiInputLstmPolicy`` (RecurrentPPO) with the APG extractor by default.

    The APG features of each step go through sb3-contrib's LSTM (``lstm_hidden_size``, 256 by default), which carries
    memory across the episode (a picker hidden behind a rack); ReLU activations and [150, 100, 100] heads as
    :class:`ApgActorCriticPolicy`. Same arguments as
    :class:`sb3_contrib.common.recurrent.policies.RecurrentMultiInputActorCriticPolicy`.
    """


class ApgMaskablePolicy(_ApgActorCriticDefaults, MaskableMultiInputActorCriticPolicy):
    """sb3-contrib ``MultiInputPolicy`` of MaskablePPO with the APG extractor by default (ReLU, [150, 100, 100] heads
    as :class:`ApgActorCriticPolicy`). Same arguments as
    :class:`sb3_contrib.common.maskable.policies.MaskableMultiInputActorCriticPolicy`.
    """


# what "ApgPolicy" names under each algorithm (this package's algorithm names)
APG_POLICIES: dict[str, type] = {"ppo": ApgActorCriticPolicy, "a2c": ApgActorCriticPolicy, "dqn": ApgDQNPolicy,
                                 "dqfd": ApgDQNPolicy, "qrdqn": ApgQRDQNPolicy, "recurrentppo": ApgRecurrentPolicy,
                                 "maskableppo": ApgMaskablePolicy}
