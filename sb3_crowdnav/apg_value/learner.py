"""Where APGValue's gradient steps run: the :class:`Learner` protocol, its serial form, and their arithmetic.

:class:`ValueLearner` holds the arithmetic (regression targets and one step per replay batch), so that the same
code runs wherever the steps run. A :class:`Learner` decides where and when: :class:`SerialLearner` runs each
training call at once in the calling thread; the learners of ``overlap_training`` (:mod:`.overlap`) run it
beside the acting loop. ``APGValue`` holds one learner and calls it the same way whichever it is, as SB3's
algorithms call any ``VecEnv``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import torch as th
from stable_baselines3.common.utils import polyak_update, update_learning_rate

from sb3_crowdnav.apg_value.policies import ValueLookaheadPolicy
from sb3_crowdnav.sim.observation import Robot


@dataclasses.dataclass
class Batch:
    """A replay batch of one gradient step; ``target`` None until computed (by the acting or the learner thread)."""

    data: Any
    target: th.Tensor | None = None
    weights: th.Tensor | None = None


@dataclasses.dataclass
class ValueLearner:
    """Targets and gradient steps of V (``policy.value_net``) against ``policy.value_net_target``.

    :param policy: the value policy whose V trains (its ``optimizer`` steps)
    :param gamma: discount per second at v_pref = 1
    :param value_target: ``"td"``, ``"greedy_td"`` or ``"lookahead"`` (see :class:`~.APGValue`)
    :param max_grad_norm: gradient clipping
    """

    policy: ValueLookaheadPolicy
    gamma: float
    value_target: str
    max_grad_norm: float

    def td_target(self, rewards: th.Tensor, next_obs: dict[str, th.Tensor], obs: dict[str, th.Tensor],
                  dones: th.Tensor) -> th.Tensor:
        """``r + γ^(Δt·v_pref) · min(V_target(s'), ceiling) · (1 - done)`` (the ceiling: warehouse and shaped worlds)."""
        with th.no_grad():
            v_next = self.policy.values(next_obs, target=True)
            ceiling = self.policy.value_ceiling(obs["robot"][:, Robot.V_PREF])
            if ceiling is not None:  # no return exceeds it (ValueLookaheadPolicy.value_ceiling)
                v_next = th.minimum(v_next, ceiling)
            discount = self.gamma ** (self.policy.world.time_step * obs["robot"][:, Robot.V_PREF])
            return rewards + discount * (1.0 - dones) * v_next

    def batch_target(self, data: Any) -> tuple[th.Tensor, th.Tensor | None]:
        """Regression target of a sampled batch (see ``value_target``) and per-sample weights (None: all count).

        Targets only read V_target, which changes between training calls only (APGValue waits for the learner
        before updating it), so the numbers do not depend on which thread or process computes them, or when.
        """
        if self.value_target == "lookahead":
            target = data.lookahead_targets.flatten()
            known = th.isfinite(target)
            if not known.all():
                td = self.td_target(data.rewards.flatten(), data.next_observations, data.observations,
                                    data.dones.flatten())
                target = th.where(known, target, td)
            return target, None
        target = self.td_target(data.rewards.flatten(), data.next_observations, data.observations, data.dones.flatten())
        return target, (data.greedy.flatten() if self.value_target == "greedy_td" else None)

    def gradient_steps(self, batches: list[Batch]) -> list[float]:
        """One gradient step on V per batch (its target computed here unless it carries one); the losses."""
        policy, losses = self.policy, []
        for batch in batches:
            data, target, weights = batch.data, batch.target, batch.weights
            if target is None:
                target, weights = self.batch_target(data)
            error = policy.values(data.observations) - target
            if weights is None:
                loss = error.square().mean()
            else:  # ε-drawn transitions do not train V
                loss = (weights * error.square()).sum() / weights.sum().clamp_min(1.0)
            policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(policy.value_net.parameters(), self.max_grad_norm)
            policy.optimizer.step()
            losses.append(loss.item())
        return losses


@runtime_checkable
class Learner(Protocol):
    """What ``APGValue`` asks of the place its gradient steps run (serial, thread or process).

    A ``learn()`` call brackets its use with :meth:`start` and :meth:`stop`; :meth:`submit` is one training
    call. Every hand-over (:meth:`submit`, :meth:`join`) happens at a fixed point of the schedule, so a run
    does not depend on how long the steps take.
    """

    def acting_net(self) -> th.nn.Module:
        """The network to act with now: V itself, or a copy of V one training call stale while V trains."""

    def start(self) -> None:
        """``learn()`` begins acting and training (after the imitation pre-training)."""

    def submit(self, batches: list[Batch], learning_rate: float) -> list[float] | None:
        """Run a training call on ``batches`` at ``learning_rate``, once the call before it has finished; the
        losses of the calls finished by now (this call's, or the previous one's; None when none had run)."""

    def join(self) -> list[float] | None:
        """Wait for the training call in flight; its losses (None when none was in flight); re-raises its
        exception."""

    def update_target(self, tau: float) -> None:
        """Move V_target towards V (after :meth:`join`), wherever a copy of V_target is kept."""

    def pull_optimizer(self) -> None:
        """Bring the optimiser's state into the policy's ``optimizer`` (after :meth:`join`), for ``save``."""

    def stop(self) -> None:
        """``learn()`` ends (also on an exception): release threads and processes; V acts again."""


class SerialLearner:
    """The gradient steps of a training call run at once, in the calling thread; V itself acts.

    :param arithmetic: builds the :class:`ValueLearner` of the algorithm's current policy and settings (called
        at each use: a policy replaced after construction, as ensemble averaging does, is followed)
    """

    def __init__(self, arithmetic: Callable[[], ValueLearner]) -> None:
        self.arithmetic = arithmetic

    def acting_net(self) -> th.nn.Module:
        policy = self.arithmetic().policy
        policy.set_training_mode(False)
        return policy.value_net

    def start(self) -> None:
        """Nothing to set up: the steps run in :meth:`submit`."""

    def submit(self, batches: list[Batch], learning_rate: float) -> list[float] | None:
        learner = self.arithmetic()
        learner.policy.set_training_mode(True)
        update_learning_rate(learner.policy.optimizer, learning_rate)
        return learner.gradient_steps(batches)

    def join(self) -> list[float] | None:
        return None  # submit() finished its call

    def update_target(self, tau: float) -> None:
        policy = self.arithmetic().policy
        polyak_update(policy.value_net.parameters(), policy.value_net_target.parameters(), tau)

    def pull_optimizer(self) -> None:
        """The steps ran on the policy's own optimiser: nothing to bring."""

    def stop(self) -> None:
        """Nothing to release."""
