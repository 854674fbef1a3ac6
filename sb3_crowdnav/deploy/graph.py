"""The decision of a trained policy as one torch module, from the observation's tensors to the greedy action.

One module per kind of policy, each ``forward(observation) -> (action (B,) int64, action_values (B, A))``:

* :class:`LookaheadDecision`, a :class:`~sb3_crowdnav.apg_value.ValueLookaheadPolicy` (``APGValue`` and its
  baselines, one value network or an ensemble): the propagation and reward of every action
  (:class:`~sb3_crowdnav.deploy.propagation.GraphPropagation`), V of every propagated state in one batch, the
  warehouse's value ceiling, ``R + γ^(Δt·v_pref)·V(s')`` in float64 and its argmax (kind ``"lookahead"``);
* :class:`QDecision`, SB3's DQN policy: the Q network and its argmax (kind ``"q_values"``);
* :class:`ActorDecision`, SB3's actor-critic policy (PPO, A2C) with discrete actions: the actor's logits and their
  argmax, the action SB3's ``predict(deterministic=True)`` takes (kind ``"logits"``).

:func:`decision_module` picks the module for a policy, and refuses, naming it, any policy it does not know.
"""

from __future__ import annotations

from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy, MultiInputActorCriticPolicy
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.dqn.policies import DQNPolicy, MultiInputPolicy
from torch import nn

from sb3_crowdnav.apg_value.policies import ValueLookaheadPolicy
from sb3_crowdnav.deploy.propagation import F64, GraphPropagation, f64
from sb3_crowdnav.nn import ApgActorCriticPolicy, ApgDQNPolicy
from sb3_crowdnav.nn.extractors import CrowdFeaturesExtractor
from sb3_crowdnav.nn.layers import exporting
from sb3_crowdnav.sim.observation import ObservationSchema, Robot

# the SB3 policy classes whose greedy action is exported (subclasses may act otherwise: recurrent, masked, ...)
Q_POLICIES = (DQNPolicy, MultiInputPolicy, ApgDQNPolicy)
ACTOR_POLICIES = (ActorCriticPolicy, MultiInputActorCriticPolicy, ApgActorCriticPolicy)


@th.library.custom_op("sb3_crowdnav::values_per_observation", mutates_args=())
def values_per_observation(observation: list[th.Tensor], n_actions: int) -> th.Tensor:
    """A placeholder in the traced decision for V of B x A propagated states ``observation`` (each (B * A, n), in
    the schema's key order), (B * A,). :func:`~sb3_crowdnav.deploy.export.to_onnx` replaces it by an ONNX ``Scan``
    of the value network over the B observations: on one observation's A states (a few observations' for the small
    encoders) the layers' activations stay in the CPU's caches, which made ``apg_rl``'s value network 1.8x faster in
    ONNX Runtime than in one pass over the 5,120 states of a batch of 64."""
    raise RuntimeError("values_per_observation is a placeholder of an exported graph and is never run")


@values_per_observation.register_fake
def _values_per_observation_shape(observation, n_actions):
    return observation[0].new_empty(observation[0].shape[0])


class LookaheadDecision(nn.Module):
    """A :class:`~sb3_crowdnav.apg_value.ValueLookaheadPolicy`'s greedy decision (see the module docstring)."""

    kind = "lookahead"
    scan = True  # in an exported graph V is the placeholder the export replaces by a Scan (False: the network inline)

    def __init__(self, policy: ValueLookaheadPolicy) -> None:
        super().__init__()
        schema = ObservationSchema.from_space(policy.observation_space)
        self.propagation = GraphPropagation(policy.world, schema, policy.gamma, policy.pedestrian_model)
        self.keys = tuple(schema.shapes)  # the observation's keys in the schema's order, the value network's inputs
        self.value_net = policy.value_net
        world = policy.world
        self.ceiling = world.has_static_world and policy.gamma < 1
        self.ceiling_terms = (world.time_step, world.progress_reward, policy.gamma, world.reward.success_reward)

    def value_ceiling(self, v_pref: th.Tensor) -> th.Tensor:
        """:meth:`ValueLookaheadPolicy.value_ceiling` with float64 constants (the policy's own would enter the graph
        with float32 ones): ``max(S, k·v_pref·Δt / (1 - γ^(Δt·v_pref)))``, (B,)."""
        time_step, progress_reward, gamma, success = (f64(x) for x in self.ceiling_terms)
        step = time_step * v_pref
        return th.maximum(progress_reward * step / (1 - th.pow(gamma, step)), success)

    def values(self, observation: dict[str, th.Tensor], n_actions: int) -> th.Tensor:
        """V of the B x A propagated states (rows b-major), (B * A,). In an exported graph a placeholder
        (:func:`values_per_observation`, the propagated tensors in the schema's key order) that the export replaces
        by the value network run on one observation's A states (or a few observations') at a time."""
        if exporting() and self.scan:
            return values_per_observation([observation[key] for key in self.keys], n_actions)
        return self.value_net(observation)

    def forward(self, observation: dict[str, th.Tensor]) -> tuple[th.Tensor, th.Tensor]:
        prop = self.propagation(observation)
        batch, n_actions = prop.reward.shape
        v = self.values(prop.observation, n_actions).reshape(batch, n_actions).to(F64)
        if self.ceiling:
            v = th.minimum(v, self.value_ceiling(observation["robot"][:, Robot.V_PREF].to(F64))[:, None])
        q = prop.reward + prop.discount[:, None] * th.where(prop.terminal, 0.0, v)
        return q.argmax(dim=1), q


class QDecision(nn.Module):
    """SB3 DQN: ``argmax Q(s, ·)``."""

    kind = "q_values"

    def __init__(self, policy: DQNPolicy) -> None:
        super().__init__()
        self.q_net = policy.q_net

    def forward(self, observation: dict[str, th.Tensor]) -> tuple[th.Tensor, th.Tensor]:
        q = self.q_net(observation)
        return q.argmax(dim=1), q


class ActorDecision(nn.Module):
    """SB3 actor-critic (PPO, A2C) with discrete actions: the mode of the actor's distribution, argmax of its logits."""

    kind = "logits"

    def __init__(self, policy: ActorCriticPolicy) -> None:
        super().__init__()
        self.observation_space = policy.observation_space
        self.normalize_images = policy.normalize_images
        self.features_extractor = policy.pi_features_extractor
        self.mlp_extractor = policy.mlp_extractor
        self.action_net = policy.action_net

    def forward(self, observation: dict[str, th.Tensor]) -> tuple[th.Tensor, th.Tensor]:
        features = self.features_extractor(preprocess_obs(observation, self.observation_space, self.normalize_images))
        logits = self.action_net(self.mlp_extractor.forward_actor(features))
        return logits.argmax(dim=1), logits


def policy_of(model: Any) -> Any:
    """The policy of an SB3 model (``model.policy``), or ``model`` itself when it is a policy."""
    policy = getattr(model, "policy", model)
    return policy if isinstance(policy, nn.Module) else model


def decision_module(model: Any) -> LookaheadDecision | QDecision | ActorDecision:
    """The decision module of a model or policy (see the module docstring); ``ValueError`` naming what is not
    supported: another algorithm or policy class, another extractor, bfloat16 acting, a non-discrete action space."""
    policy = policy_of(model)
    name = type(policy).__name__ if policy is model else f"{type(model).__name__} ({type(policy).__name__})"
    if isinstance(policy, ValueLookaheadPolicy):
        if policy.lookahead_dtype != "float32":
            raise ValueError(f"{name} acts with lookahead_dtype={policy.lookahead_dtype!r}; the exported graph is "
                             "float32: call model.policy.set_lookahead_dtype('float32') before exporting")
        return LookaheadDecision(policy)
    supported = type(policy) in (*Q_POLICIES, *ACTOR_POLICIES)
    if not supported:
        raise ValueError(f"{name} cannot be exported: supported are APGValue (ValueLookaheadPolicy and its aliases), "
                         f"DQN ({', '.join(c.__name__ for c in Q_POLICIES)}) and PPO/A2C "
                         f"({', '.join(c.__name__ for c in ACTOR_POLICIES)})")
    if not isinstance(policy.action_space, spaces.Discrete):
        raise ValueError(f"{name} has a {type(policy.action_space).__name__} action space; the exporter takes "
                         "Discrete actions (the crowd envs' action table)")
    extractor = policy.features_extractor_class
    if not (isinstance(extractor, type) and issubclass(extractor, CrowdFeaturesExtractor)):
        raise ValueError(f"{name} encodes the observation with {getattr(extractor, '__name__', extractor)}; the "
                         "exporter takes this package's crowd encoders (sb3_crowdnav.nn.EXTRACTORS)")
    ObservationSchema.from_space(policy.observation_space)  # a crowd observation, or a message saying how to fix it
    return QDecision(policy) if type(policy) in Q_POLICIES else ActorDecision(policy)


__all__ = ["ACTOR_POLICIES", "Q_POLICIES", "ActorDecision", "LookaheadDecision", "QDecision",
           "decision_module", "policy_of"]
