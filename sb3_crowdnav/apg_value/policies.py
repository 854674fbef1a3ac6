"""``ValueLookaheadPolicy``: a state-value network that acts by one-step lookahead over the world's actions."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, create_mlp
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_crowdnav.apg_value.propagation import Propagated, PropagationModel, check_stopping_check
from sb3_crowdnav.apg_value.search import STATIC_KEYS, check_cap_values, check_planning, search
from sb3_crowdnav.nn import ApgExtractor, CadrlExtractor, LmExtractor, LstmRlExtractor, SarlExtractor, SfExtractor
from sb3_crowdnav.nn.layers import bfloat16_supported
from sb3_crowdnav.sim.observation import OBS_KEYS, ObservationSchema
from sb3_crowdnav.sim.validation import check_choice, check_int, check_range
from sb3_crowdnav.sim.world import World

# how a trained model acts, each with its default: switched on a loaded model by ValueLookaheadPolicy's setters, and
# written into the model file (APGValue.save) once it differs from the default
LOOKAHEAD_SETTINGS = {"lookahead_dtype": "float32", "pedestrian_model": "constant_velocity", "stopping_check": False,
                      "planning_depth": 1, "planning_width": None, "cap_values": None}


class ValueNetwork(nn.Module):
    """V(s) = ψ_M([features]) with ψ_M = MLP ``net_arch`` then a linear output (paper Table 2: [150, 100, 100, 1])."""

    def __init__(self, features_extractor: BaseFeaturesExtractor, net_arch: list[int], activation_fn: type[nn.Module]):
        super().__init__()
        self.features_extractor = features_extractor
        self.head = nn.Sequential(*create_mlp(features_extractor.features_dim, 1, net_arch, activation_fn))

    def forward(self, obs: dict[str, th.Tensor]) -> th.Tensor:
        """:return: values (batch,)"""
        return self.head(self.features_extractor(obs)).squeeze(-1)


class ValueEnsemble(nn.Module):
    """V(s) as the mean of several :class:`ValueNetwork` members (``members``), one forward pass each.

    Independently trained value networks err in different places; the lookahead on their mean picks fewer actions
    that one member overrates. Built from trained models by :func:`sb3_crowdnav.training.ensemble_models`; a policy
    with ``ensemble_size > 1`` that is trained further fits the mean (one loss, gradients to every member).
    """

    def __init__(self, members: list[ValueNetwork]):
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"members: a ValueEnsemble needs at least two networks, got {len(members)}")
        self.members = nn.ModuleList(members)

    def forward(self, obs: dict[str, th.Tensor]) -> th.Tensor:
        """:return: the members' mean value (batch,)"""
        return th.stack([member(obs) for member in self.members]).mean(dim=0)


def bfloat16_extractors(net: nn.Module) -> list[nn.Module]:
    """The feature extractors of ``net`` (a :class:`ValueNetwork` or :class:`ValueEnsemble`) that can act in bfloat16."""
    return [module for module in net.modules() if hasattr(module, "bfloat16_inference")]


class ValueLookaheadPolicy(BasePolicy):
    """State-value policy acting by one-step lookahead (paper Eq. 1).

    For every observation in the batch and every one of the world's actions (80, or 81 with a stop) the
    :class:`PropagationModel` gives the next observation and R(s, a); V is evaluated on the
    B x n_actions propagated states in **one** forward pass (each distinct state once under the robot's limits:
    :meth:`lookahead_inputs`; a batch of more than :attr:`ACTION_VALUE_CHUNK` observations in chunks of that many),
    and the action maximising
    ``R + γ^(Δt·v_pref) · V(s')`` (zero future value for terminal successors) is taken.

    :param observation_space: the env's Dict observation space
    :param action_space: ``Discrete(world.n_actions)``
    :param lr_schedule: learning-rate schedule (RL phase)
    :param world: the env's :class:`~sb3_crowdnav.sim.world.World`, or its plain form (:meth:`World.to_dict`, as
        ``policy_kwargs`` and the model file carry it; ``APGValue`` sets it from the env): the time step, kinematics
        action table and limits the lookahead moves the robot by, the reward R(s, a) it charges and, in a world of static
        obstacles, their collision penalty, the waypoint rule and the route shaping. Default: ``CrowdNav-v0``'s
    :param gamma: discount per second at v_pref = 1
    :param net_arch: hidden sizes of the value head ψ_M
    :param activation_fn: activation of the value head
    :param features_extractor_class: encoder of the joint state (default: the class's ``default_extractor_class``,
        APG + temporal attention + LSTM here, the baseline's encoder in the aliases ``CadrlPolicy``, ...)
    :param features_extractor_kwargs: its keyword arguments
    :param optimizer_class: RL optimiser (here SGD with momentum 0.9, as the field's reference code; ``APGValue``
        passes Adam unless ``policy_kwargs`` name one)
    :param optimizer_kwargs: its keyword arguments
    :param lookahead_dtype: precision of the acting lookahead. ``"float32"`` (default) everywhere;
        ``"bfloat16"`` runs the APG encoder's per-(step, pedestrian) layers in bfloat16 when acting
        (needs a CPU with native bfloat16 matrix kernels; the softmax, LSTM and value head stay in
        float32; TD targets and gradient steps are always float32). It trades a small share of identical
        decisions for speed (``benchmarks/lookahead_speed.py --dtype bfloat16`` measures both).
    :param pedestrian_model: how the lookahead's reward predicts the pedestrians over the step (see
        :class:`PropagationModel`): ``"constant_velocity"`` (the paper, default) or ``"cautious"`` (also charges
        a collision with a pedestrian who stands still instead; :meth:`set_pedestrian_model` switches a loaded
        model)
    :param stopping_check: also charge an action a collision when the robot, braking from its new velocity at the
        world's ``max_acceleration`` until it stands, would hit an observed rack, wall or person (see
        :class:`PropagationModel`; default False, the paper's lookahead). Refused for a world without
        ``max_acceleration``; :meth:`set_stopping_check` switches a loaded model
    :param planning_depth: how many steps the lookahead searches before it takes V (default 1: the paper's
        one-step lookahead). With d > 1 every distinct state the actions reach is propagated again, d steps in all
        (the same propagation each step: the people at constant velocity, the reward, the terminal flags and the
        checks), V is evaluated at the last step only and each step backs up ``R + γ^(Δt·v_pref)·max_a Q``. The cost
        grows about as the number of distinct successors to the power d: about 11 a step under the warehouse robot's
        limits, 80 on the open floor. Whatever acts through the lookahead uses it, training included;
        :meth:`set_planning_depth` switches a loaded model
    :param planning_width: with ``planning_depth`` > 1, search only the best ``planning_width`` actions of each step
        deeper, ranked by their one-step Q (a beam; :mod:`~sb3_crowdnav.apg_value.search`); None (default): every
        successor. Refused at depth 1, where nothing is searched deeper; :meth:`set_planning_width` switches a
        loaded model
    :param cap_values: whether the lookahead (and the TD targets) take ``min(V(s'), ceiling)``, the largest return a
        state can have (:meth:`value_ceiling`): None (default) the world's rule (``World.has_value_ceiling``: on
        with racks or progress shaping, off on the paper's open floor, where the shipped models act as trained);
        True also on the paper's open floor (where the ceiling is the success reward); False never.
        :meth:`set_cap_values` switches a loaded model
    :param ensemble_size: number of value networks whose mean is V (:class:`ValueEnsemble`; 1, the paper: one
        :class:`ValueNetwork`). Each decision costs one forward pass per member. Ensembles are made of trained models
        with :func:`sb3_crowdnav.training.ensemble_models`
    """

    LOOKAHEAD_DTYPES = ("float32", "bfloat16")
    # observations whose actions are searched at once by action_values (and so predict): a larger batch goes in
    # chunks of this many, which bounds the memory of the search (a two-step search over 81 actions expands about 730
    # states per observation; 300 at once peaked at 14.7 GB, 16 take about 1 GB)
    ACTION_VALUE_CHUNK = 16
    default_extractor_class: type[BaseFeaturesExtractor] = ApgExtractor  # the policy aliases set their encoder here

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        world: World | Mapping[str, Any] | None = None,
        gamma: float = 0.9,
        net_arch: list[int] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        features_extractor_class: type[BaseFeaturesExtractor] | None = None,
        features_extractor_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = False,
        optimizer_class: type[th.optim.Optimizer] = th.optim.SGD,
        optimizer_kwargs: dict[str, Any] | None = None,
        lookahead_dtype: str = "float32",
        pedestrian_model: str = "constant_velocity",
        ensemble_size: int = 1,
        stopping_check: bool = False,
        planning_depth: int = 1,
        planning_width: int | None = None,
        cap_values: bool | None = None,
    ) -> None:
        schema = ObservationSchema.from_space(observation_space)
        self.history_length, self.max_humans = schema.history_length, schema.max_humans
        check_choice("lookahead_dtype", lookahead_dtype, self.LOOKAHEAD_DTYPES)
        check_choice("pedestrian_model", pedestrian_model, PropagationModel.PEDESTRIAN_MODELS)
        check_int("ensemble_size", ensemble_size, 1)
        self.ensemble_size = int(ensemble_size)
        self.planning_depth, self.planning_width = check_planning(planning_depth, planning_width)
        self.cap_values = check_cap_values(cap_values)
        world = World() if world is None else World.coerce(world)
        check_stopping_check(stopping_check, world)  # before any work
        if not isinstance(action_space, spaces.Discrete) or action_space.n != world.n_actions:
            raise ValueError(f"ValueLookaheadPolicy needs Discrete({world.n_actions}) actions (the world's "
                             f"actions={world.actions!r}), got {action_space}")
        check_range("gamma", gamma, 0, 1, low_open=True)
        if optimizer_kwargs is None:
            optimizer_kwargs = {"momentum": 0.9} if optimizer_class is th.optim.SGD else {}
        super().__init__(
            observation_space,
            action_space,
            features_extractor_class or self.default_extractor_class,
            features_extractor_kwargs or {},
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            normalize_images=normalize_images,
        )
        self.world = world
        self.gamma = float(gamma)
        self.net_arch = list(net_arch) if net_arch is not None else [150, 100, 100]
        self.activation_fn = activation_fn
        self.propagation = PropagationModel(world, self.history_length, self.gamma, pedestrian_model, stopping_check)
        self._build(lr_schedule)
        self.lookahead_dtype = "float32"
        self.set_lookahead_dtype(lookahead_dtype)

    def set_lookahead_dtype(self, dtype: str) -> None:
        """Switch the acting lookahead between ``"float32"`` and ``"bfloat16"`` (see the class docstring)."""
        if dtype not in self.LOOKAHEAD_DTYPES:
            raise ValueError(f"lookahead_dtype must be one of {self.LOOKAHEAD_DTYPES}, got {dtype!r}")
        extractors = bfloat16_extractors(self.value_net)
        if dtype == "bfloat16":
            if not extractors:
                raise ValueError(f"lookahead_dtype='bfloat16' is implemented for the APG encoder only, not "
                                 f"{self.features_extractor_class.__name__}")
            if not bfloat16_supported():
                raise ValueError("lookahead_dtype='bfloat16' needs a CPU with native bfloat16 matrix kernels "
                                 "(AVX-512 BF16 or AMX) and torch's oneDNN; use 'float32'")
        for extractor in extractors:
            extractor.bfloat16_inference = dtype == "bfloat16"
        self.lookahead_dtype = dtype

    @property
    def pedestrian_model(self) -> str:
        """``"constant_velocity"`` or ``"cautious"`` (see the class docstring)."""
        return self.propagation.pedestrian_model

    @property
    def stopping_check(self) -> bool:
        """Whether the lookahead charges actions the robot cannot brake from (see the class docstring)."""
        return self.propagation.stopping_check

    def set_pedestrian_model(self, pedestrian_model: str) -> None:
        """Switch the lookahead's pedestrian model (see the class docstring); V is unchanged."""
        self.propagation = PropagationModel(self.world, self.history_length, self.gamma, pedestrian_model,
                                            self.stopping_check)

    def set_stopping_check(self, stopping_check: bool) -> None:
        """Switch the lookahead's stopping-distance check on or off (see the class docstring); V is unchanged."""
        self.propagation = PropagationModel(self.world, self.history_length, self.gamma, self.pedestrian_model,
                                            stopping_check)

    def set_planning(self, planning_depth: int, planning_width: int | None = None) -> None:
        """Switch the lookahead's search, its depth and width (see the class docstring); V is unchanged."""
        self.planning_depth, self.planning_width = check_planning(planning_depth, planning_width)

    def set_planning_depth(self, planning_depth: int) -> None:
        """Switch the search's depth, keeping its width (refused at 1 with a width: :meth:`set_planning`)."""
        self.set_planning(planning_depth, self.planning_width)

    def set_planning_width(self, planning_width: int | None) -> None:
        """Switch how many actions of each step a deeper search expands, keeping its depth."""
        self.set_planning(self.planning_depth, planning_width)

    def set_cap_values(self, cap_values: bool | None) -> None:
        """Switch whether V is capped at :meth:`value_ceiling` (see the class docstring); V is unchanged."""
        self.cap_values = check_cap_values(cap_values)

    @property
    def caps_values(self) -> bool:
        """Whether V is capped: :attr:`cap_values`, or the world's rule when it is None."""
        return self.world.has_value_ceiling if self.cap_values is None else self.cap_values

    def make_value_net(self) -> ValueNetwork | ValueEnsemble:
        """A new V: one :class:`ValueNetwork`, or a :class:`ValueEnsemble` of ``ensemble_size`` of them."""
        members = [ValueNetwork(self.make_features_extractor(), self.net_arch, self.activation_fn)
                   for _ in range(self.ensemble_size)]
        return members[0] if self.ensemble_size == 1 else ValueEnsemble(members)

    def _build(self, lr_schedule: Schedule) -> None:
        self.value_net = self.make_value_net()
        self.value_net_target = self.make_value_net()
        self.value_net_target.load_state_dict(self.value_net.state_dict())
        self.value_net_target.train(False)
        self.optimizer = self.optimizer_class(self.value_net.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            world=self.world.to_dict(),
            gamma=self.gamma,
            net_arch=self.net_arch,
            activation_fn=self.activation_fn,
            features_extractor_class=self.features_extractor_class,
            features_extractor_kwargs=self.features_extractor_kwargs,
            lookahead_dtype=self.lookahead_dtype,
        )
        if self.pedestrian_model != "constant_velocity":  # only when not the paper's, which needs no entry
            data["pedestrian_model"] = self.pedestrian_model
        if self.ensemble_size != 1:
            data["ensemble_size"] = self.ensemble_size
        if self.stopping_check:  # only when on: the files of models without it stay as they were
            data["stopping_check"] = True
        if self.planning_depth != 1:  # likewise: a one-step model's file has no entry
            data["planning_depth"] = self.planning_depth
        if self.planning_width is not None:
            data["planning_width"] = self.planning_width
        if self.cap_values is not None:  # likewise: the world's rule needs no entry
            data["cap_values"] = self.cap_values
        return data

    # ------------------------------------------------------------------ values
    def values(self, observation: dict[str, th.Tensor], target: bool = False) -> th.Tensor:
        """V(s) of a batch of observations (tensors) with the online or the target network; (batch,)."""
        net = self.value_net_target if target else self.value_net
        return net(observation)

    def value_ceiling(self, v_pref: Any) -> Any:
        """The largest return any state can have, per state (numpy or torch like ``v_pref``), where V is capped
        (:attr:`caps_values`: by default in the warehouse and wherever progress is shaped, ``world.has_value_ceiling``);
        None where it is not (by default the paper's open floor, where the shipped models act as trained).

        Every reward term is <= 0 but the success reward S and the progress shaping, and one step gains at
        most its length ``v_pref·Δt`` on any waypoint or goal: a return is at most ``max(S, k·v_pref·Δt / (1 - γ'))``
        with ``γ' = γ^(Δt·v_pref)`` (S = 1 for k = 0.1, v_pref = 1). The lookahead and the TD targets take
        ``min(V(s'), ceiling)``: V's overestimates beyond it (which, next to the goal, outbid the success action
        and kept the robot circling there) are cut, and no true value is.
        """
        if not self.caps_values or self.gamma >= 1:
            return None
        step = self.world.time_step * v_pref
        shaping = self.world.progress_reward * step / (1 - self.gamma**step)
        success = self.world.reward.success_reward
        return shaping.clamp(min=success) if isinstance(shaping, th.Tensor) else np.maximum(shaping, success)

    def lookahead(self, observation: dict[str, np.ndarray], net: nn.Module | None = None) -> tuple[np.ndarray, Propagated]:
        """R + γ^(Δt·v_pref)·V(s') for every action of a batch of numpy observations: (B, n_actions), and the first
        step's propagation. With ``planning_depth`` d > 1, V(s') is the best of the (d - 1)-step search from s'.

        ``net`` replaces V (``self.value_net``) by another network of the same architecture (APGValue's acting copy).
        """
        return search(self, observation, self.value_net if net is None else net, self.planning_depth)

    def successors(self, prop: Propagated,
                   distinct: bool | None = None) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
        """The propagated states of a lookahead as float32 numpy observations (V's inputs, and where a deeper search
        propagates from, as the exported graph does), and where each (observation, action) pair's state is among
        them.

        :param prop: the propagation of B observations under the world's n_actions actions
        :param distinct: keep every distinct state once. Under the robot's limits, commands beyond reach are clipped
            to the same reachable motion (the warehouse robot's 81 actions reach about 11 distinct states a step), and
            their rows are equal to the bit. Default: on in a world with ``max_acceleration`` or ``max_turn_rate``, off
            otherwise (every action reaches its own state)
        :return: the states (rows in order of the observations) and the row of each of the B x n_actions pairs,
            flattened (None when the rows are the B x n_actions states in order)
        """
        if distinct is not None and not isinstance(distinct, bool):
            raise TypeError(f"distinct must be a bool or None, got {distinct!r}")
        b, n_actions = prop.reward.shape
        distinct = self.world.has_limits if distinct is None else distinct
        robot = prop.robot.reshape(b * n_actions, -1).astype(np.float32)
        # the warehouse: segments the same under every action (B, S*4), waypoints not (B, A, K*2)
        per_action = {k: v.reshape(b * n_actions, -1).astype(np.float32) for k, v in prop.static.items() if v.ndim == 3}
        rows, inverse = np.arange(b * n_actions), None
        if distinct:  # equal float32 rows are equal inputs to V; the observation's index keeps observations apart
            key = np.concatenate([(rows // n_actions)[:, None].astype(np.float32), robot, *per_action.values()], axis=1)
            _, rows, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
            inverse = inverse.reshape(-1)
        owner = rows // n_actions  # humans, their mask and the segments are the same under every action
        states = dict(zip(OBS_KEYS, (robot[rows], prop.humans.astype(np.float32)[owner], prop.humans_mask[owner]),
                          strict=True))
        for key, value in prop.static.items():
            states[key] = per_action[key][rows] if key in per_action else np.asarray(value, dtype=np.float32)[owner]
        return states, inverse

    def lookahead_inputs(self, prop: Propagated,
                         distinct: bool | None = None) -> tuple[dict[str, th.Tensor], np.ndarray | None]:
        """The propagated states of a one-step lookahead that V is evaluated on, as float32 tensors, and where each
        (observation, action) pair's state is among them (:meth:`successors`, ``distinct`` likewise)."""
        states, inverse = self.successors(prop, distinct)
        return {k: th.as_tensor(v, dtype=th.float32, device=self.device) for k, v in states.items()}, inverse

    def action_values(self, observation: dict[str, np.ndarray], net: nn.Module | None = None) -> np.ndarray:
        """Lookahead value of each action, (B, n_actions) (Fig. 11's action-value map); ``net`` as in lookahead.
        A batch of more than :attr:`ACTION_VALUE_CHUNK` observations is searched that many at a time."""
        obs = {k: np.asarray(observation[k]) for k in (*OBS_KEYS, *STATIC_KEYS) if k in observation}
        if obs["robot"].ndim == 1:
            obs = {k: v[None] for k, v in obs.items()}
        b, chunk = obs["robot"].shape[0], self.ACTION_VALUE_CHUNK
        if b <= chunk:
            return self.lookahead(obs, net)[0]
        return np.concatenate([self.lookahead({k: v[i: i + chunk] for k, v in obs.items()}, net)[0]
                               for i in range(0, b, chunk)])

    # ------------------------------------------------------------------ acting
    def forward(self, obs: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        return self._predict(obs, deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        assert isinstance(observation, dict)
        q = self.action_values({k: value.cpu().numpy() for k, value in observation.items()})
        return th.as_tensor(q.argmax(axis=1), device=self.device)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = False):
        """Greedy lookahead action(s); same contract as SB3's ``BasePolicy.predict`` (numpy in, numpy out)."""
        self.set_training_mode(False)
        if isinstance(observation, tuple) and len(observation) == 2 and isinstance(observation[1], dict):
            raise ValueError("predict() got a (obs, info) tuple: pass the observation only (Gym API vs VecEnv API)")
        if not isinstance(observation, dict) or set(OBS_KEYS) - set(observation):
            raise ValueError(f"observation must be a dict with keys {OBS_KEYS}")
        vectorized = np.asarray(observation["robot"]).ndim == 2
        actions = self.action_values(observation).argmax(axis=1)
        return (actions if vectorized else actions[0]), state

    def set_training_mode(self, mode: bool) -> None:
        if self.training != mode or self.value_net.training != mode:  # train() walks every submodule: skip it when set
            self.value_net.train(mode)
        self.training = mode


class CadrlPolicy(ValueLookaheadPolicy):
    """:class:`ValueLookaheadPolicy` with the CADRL encoder."""

    default_extractor_class = CadrlExtractor


class SfPolicy(ValueLookaheadPolicy):
    """:class:`ValueLookaheadPolicy` with the social-force (SF_RL) encoder."""

    default_extractor_class = SfExtractor


class LmPolicy(ValueLookaheadPolicy):
    """:class:`ValueLookaheadPolicy` with the local-map (LM_RL) encoder."""

    default_extractor_class = LmExtractor


class LstmRlPolicy(ValueLookaheadPolicy):
    """:class:`ValueLookaheadPolicy` with the LSTM-RL encoder."""

    default_extractor_class = LstmRlExtractor


class SarlPolicy(ValueLookaheadPolicy):
    """:class:`ValueLookaheadPolicy` with the SARL encoder."""

    default_extractor_class = SarlExtractor


ApgPolicy = ValueLookaheadPolicy
POLICY_ALIASES: dict[str, type[ValueLookaheadPolicy]] = {
    "ApgPolicy": ValueLookaheadPolicy,
    "ValueLookaheadPolicy": ValueLookaheadPolicy,
    "CadrlPolicy": CadrlPolicy,
    "SfPolicy": SfPolicy,
    "LmPolicy": LmPolicy,
    "LstmRlPolicy": LstmRlPolicy,
    "SarlPolicy": SarlPolicy,
}
