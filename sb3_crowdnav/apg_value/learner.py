"""The arithmetic of APGValue's gradient steps on V: regression targets and one step per replay batch.

One object, :class:`ValueLearner`, holds it so that the same code runs wherever the steps run: in ``learn()``
itself, in the learner thread, or in the learner process of ``overlap_training`` (:mod:`.overlap`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch as th

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
        """``r + γ^(Δt·v_pref) · min(V_target(s'), ceiling) · (1 - done)`` (the ceiling: warehouse only)."""
        with th.no_grad():
            v_next = self.policy.values(next_obs, target=True)
            ceiling = self.policy.value_ceiling(obs["robot"][:, Robot.V_PREF])
            if ceiling is not None:  # the warehouse: no return exceeds it (ValueLookaheadPolicy.value_ceiling)
                v_next = th.minimum(v_next, ceiling)
            discount = self.gamma ** (self.policy.time_step * obs["robot"][:, Robot.V_PREF])
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
