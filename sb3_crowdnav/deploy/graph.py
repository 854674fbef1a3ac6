"""The decision of a trained policy as one torch module, from the observation's tensors to the greedy action.

One module per kind of policy, each ``forward(observation) -> (action (B,) int64, action_values (B, A))``:

* :class:`LookaheadDecision`, a :class:`~sb3_crowdnav.apg_value.ValueLookaheadPolicy` (``APGValue`` and its
  baselines, one value network or an ensemble): the propagation and reward of every action
  (:class:`~sb3_crowdnav.deploy.propagation.GraphPropagation`), V of every propagated state in one batch, the
  value ceiling (the warehouse, shaped worlds), the stopping-distance check when the policy acts with it,
  ``R + γ^(Δt·v_pref)·V(s')`` in float64 and its argmax (kind ``"lookahead"``);
* :class:`QDecision`, SB3's DQN policy: the Q network and its argmax (kind ``"q_values"``);
* :class:`ActorDecision`, SB3's actor-critic policy (PPO, A2C) with discrete actions: the actor's logits and their
  argmax, the action SB3's ``predict(deterministic=True)`` takes (kind ``"logits"``);
* :class:`QuantileDecision`, sb3-contrib's QR-DQN policy: the mean over the quantiles (its Q) and the argmax, the
  action ``QRDQN.predict`` takes (kind ``"q_values"``);
* :class:`MaskedActorDecision`, sb3-contrib's MaskablePPO policy: the actor's logits with an action mask applied as
  sb3-contrib applies it (-1e8 where masked) and their argmax; the mask is a second input, ``action_masks`` (B, A)
  bool (kind ``"masked_logits"``; the wall masks are computed outside the graph; all True allows every action).

:func:`decision_module` picks the module for a policy, and refuses, naming it, any policy it does not know; a
recurrent policy (RecurrentPPO) with a message saying why: its action depends on an LSTM state the graph does not
carry.
"""

from __future__ import annotations

from typing import Any

import torch as th
from gymnasium import spaces
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy, MaskableMultiInputActorCriticPolicy
from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
from sb3_contrib.qrdqn.policies import MultiInputPolicy as QRDQNMultiInputPolicy
from sb3_contrib.qrdqn.policies import QRDQNPolicy
from stable_baselines3.common.policies import ActorCriticPolicy, MultiInputActorCriticPolicy
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.dqn.policies import DQNPolicy, MultiInputPolicy
from torch import nn

from sb3_crowdnav.apg_value.policies import ValueLookaheadPolicy
from sb3_crowdnav.deploy.metadata import MASK_INPUT
from sb3_crowdnav.deploy.propagation import F64, GraphPropagation, braking_steps, f64
from sb3_crowdnav.nn import ApgActorCriticPolicy, ApgDQNPolicy, ApgMaskablePolicy, ApgQRDQNPolicy
from sb3_crowdnav.nn.extractors import CrowdFeaturesExtractor
from sb3_crowdnav.nn.layers import exporting
from sb3_crowdnav.sim.config import SceneConfig
from sb3_crowdnav.sim.observation import ObservationSchema, Robot

# the SB3 policy classes whose greedy action is exported (subclasses may act otherwise: recurrent, masked, ...)
Q_POLICIES = (DQNPolicy, MultiInputPolicy, ApgDQNPolicy)
ACTOR_POLICIES = (ActorCriticPolicy, MultiInputActorCriticPolicy, ApgActorCriticPolicy)
QUANTILE_POLICIES = (QRDQNPolicy, QRDQNMultiInputPolicy, ApgQRDQNPolicy)  # sb3-contrib's QR-DQN
MASKABLE_POLICIES = (MaskableActorCriticPolicy, MaskableMultiInputActorCriticPolicy, ApgMaskablePolicy)
MASKED_LOGIT = -1e8  # what sb3-contrib's MaskableCategorical puts in place of a masked action's logit


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

    def __init__(self, policy: ValueLookaheadPolicy, v_pref: float = SceneConfig.robot_v_pref) -> None:
        super().__init__()
        schema = ObservationSchema.from_space(policy.observation_space)
        braking = braking_steps(policy.world, v_pref) if policy.stopping_check else None
        self.propagation = GraphPropagation(policy.world, schema, policy.gamma, policy.pedestrian_model, braking)
        self.keys = tuple(schema.shapes)  # the observation's keys in the schema's order, the value network's inputs
        self.value_net = policy.value_net
        world = policy.world
        self.ceiling = policy.caps_values and policy.gamma < 1
        self.ceiling_terms = (world.time_step, world.progress_reward, policy.gamma, world.reward.success_reward)
        self.depth, self.width = policy.planning_depth, policy.planning_width

    def brake_for(self, v_pref: float) -> None:
        """With the stopping-distance check, brake for a robot of preferred speed ``v_pref`` [m/s] (the number of
        braking sub-steps the graph runs, :func:`~sb3_crowdnav.deploy.propagation.braking_steps`)."""
        if self.propagation.braking_steps is not None:
            self.propagation.braking_steps = braking_steps(self.propagation.world, v_pref)

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
        q = self.search(observation, self.depth)
        return q.argmax(dim=1), q

    def search(self, observation: dict[str, th.Tensor], depth: int) -> th.Tensor:
        """Q of every action, (B, A): V after one step, or with ``depth`` d > 1 the best Q of the (d - 1)-step search
        from each of the B x A propagated states (every one, where the policy evaluates each distinct state once:
        the same values; V runs once, on the B x A^d states of the last step), or from the best ``width`` of them
        by their one-step Q (``TopK``: ties to the lower action index, as
        :func:`~sb3_crowdnav.apg_value.search.best_actions`), the others keeping their one-step Q."""
        prop = self.propagation(observation)
        batch, n_actions = prop.reward.shape
        if depth > 1 and (self.width is None or self.width >= n_actions):
            v = self.search(prop.observation, depth - 1).amax(dim=1).reshape(batch, n_actions)
            return prop.reward + prop.discount[:, None] * th.where(prop.terminal, 0.0, v)
        v = self.values(prop.observation, n_actions).reshape(batch, n_actions).to(F64)
        if self.ceiling:
            v = th.minimum(v, self.value_ceiling(observation["robot"][:, Robot.V_PREF].to(F64))[:, None])
        q = prop.reward + prop.discount[:, None] * th.where(prop.terminal, 0.0, v)
        if depth == 1:
            return q
        top = th.sort(q, dim=1, descending=True, stable=True).indices[:, : self.width]  # (B, k); ONNX: TopK
        rows = (th.arange(batch)[:, None] * n_actions + top).reshape(-1)
        deeper = self.search({key: value.index_select(0, rows) for key, value in prop.observation.items()}, depth - 1)
        deeper = deeper.amax(dim=1).reshape(batch, self.width)
        expanded = prop.reward.gather(1, top) + prop.discount[:, None] * th.where(prop.terminal.gather(1, top), 0.0,
                                                                                   deeper)
        return q.scatter(1, top, expanded)


class QDecision(nn.Module):
    """SB3 DQN: ``argmax Q(s, ·)``; a subclass names its policy's network (``network``) and how it gives Q
    (:meth:`q_values`)."""

    kind = "q_values"
    network = "q_net"  # the policy's attribute that holds the network

    def __init__(self, policy: DQNPolicy | QRDQNPolicy) -> None:
        super().__init__()
        self.net = getattr(policy, self.network)

    def q_values(self, observation: dict[str, th.Tensor]) -> th.Tensor:
        """Q of every action, (B, A)."""
        return self.net(observation)

    def forward(self, observation: dict[str, th.Tensor]) -> tuple[th.Tensor, th.Tensor]:
        q = self.q_values(observation)
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


class QuantileDecision(QDecision):
    """sb3-contrib QR-DQN: ``argmax`` of the mean over the quantiles (``QuantileNetwork._predict``)."""

    network = "quantile_net"

    def q_values(self, observation: dict[str, th.Tensor]) -> th.Tensor:
        return self.net(observation).mean(dim=1)  # (B, n_quantiles, A) -> (B, A)


class MaskedActorDecision(ActorDecision):
    """sb3-contrib MaskablePPO: the actor's logits, :data:`MASKED_LOGIT` where ``action_masks`` is False (as
    ``MaskableCategorical.apply_masking``), and their argmax (the mode ``predict(deterministic=True)`` takes)."""

    kind = "masked_logits"

    def __init__(self, policy: MaskableActorCriticPolicy) -> None:
        super().__init__(policy)
        self.n_actions = int(policy.action_space.n)

    def example_inputs(self, batch: int) -> dict[str, th.Tensor]:
        """The inputs beside the observation to trace with: every action allowed, (batch, A) bool."""
        return {MASK_INPUT: th.ones(batch, self.n_actions, dtype=th.bool)}

    def forward(self, observation: dict[str, th.Tensor], action_masks: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        logits = super().forward(observation)[1]
        masked = th.where(action_masks, logits, th.tensor(MASKED_LOGIT, dtype=logits.dtype))
        return masked.argmax(dim=1), masked


Decision = LookaheadDecision | QDecision | ActorDecision | QuantileDecision | MaskedActorDecision


def policy_of(model: Any) -> Any:
    """The policy of an SB3 model (``model.policy``), or ``model`` itself when it is a policy."""
    policy = getattr(model, "policy", model)
    return policy if isinstance(policy, nn.Module) else model


def decision_module(model: Any) -> Decision:
    """The decision module of a model or policy (see the module docstring); ``ValueError`` naming what is not
    supported: another algorithm or policy class, a recurrent policy, another extractor, bfloat16 acting, a
    non-discrete action space."""
    policy = policy_of(model)
    name = type(policy).__name__ if policy is model else f"{type(model).__name__} ({type(policy).__name__})"
    if isinstance(policy, ValueLookaheadPolicy):
        if policy.lookahead_dtype != "float32":
            raise ValueError(f"{name} acts with lookahead_dtype={policy.lookahead_dtype!r}; the exported graph is "
                             "float32: call model.policy.set_lookahead_dtype('float32') before exporting")
        return LookaheadDecision(policy)
    if isinstance(policy, RecurrentActorCriticPolicy):
        raise ValueError(f"{name} cannot be exported: a recurrent policy's action depends on the LSTM state it carries "
                         "from step to step (and resets at an episode's start), and an exported graph is one stateless "
                         "decision per observation; export a feed-forward model (PPO, MaskablePPO, DQN, QRDQN, "
                         "APGValue), whose APG encoder already reads the history of the last steps")
    kinds = {**dict.fromkeys(Q_POLICIES, QDecision), **dict.fromkeys(ACTOR_POLICIES, ActorDecision),
             **dict.fromkeys(QUANTILE_POLICIES, QuantileDecision), **dict.fromkeys(MASKABLE_POLICIES, MaskedActorDecision)}
    if type(policy) not in kinds:
        raise ValueError(f"{name} cannot be exported: supported are APGValue (ValueLookaheadPolicy and its aliases), "
                         f"DQN ({', '.join(c.__name__ for c in Q_POLICIES)}), PPO/A2C "
                         f"({', '.join(c.__name__ for c in ACTOR_POLICIES)}), QRDQN "
                         f"({', '.join(c.__name__ for c in QUANTILE_POLICIES)}) and MaskablePPO "
                         f"({', '.join(c.__name__ for c in MASKABLE_POLICIES)})")
    if not isinstance(policy.action_space, spaces.Discrete):
        raise ValueError(f"{name} has a {type(policy.action_space).__name__} action space; the exporter takes "
                         "Discrete actions (the crowd envs' action table)")
    extractor = policy.features_extractor_class
    if not (isinstance(extractor, type) and issubclass(extractor, CrowdFeaturesExtractor)):
        raise ValueError(f"{name} encodes the observation with {getattr(extractor, '__name__', extractor)}; the "
                         "exporter takes this package's crowd encoders (sb3_crowdnav.nn.EXTRACTORS)")
    ObservationSchema.from_space(policy.observation_space)  # a crowd observation, or a message saying how to fix it
    return kinds[type(policy)](policy)


__all__ = ["ACTOR_POLICIES", "MASKABLE_POLICIES", "QUANTILE_POLICIES", "Q_POLICIES", "ActorDecision", "Decision",
           "LookaheadDecision", "MaskedActorDecision", "QDecision", "QuantileDecision", "decision_module", "policy_of"]
