"""DQfD: SB3's DQN that keeps learning from its demonstrations (Hester et al. 2018)."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import torch as th
from stable_baselines3 import DQN
from stable_baselines3.common.policies import BasePolicy

from sb3_crowdnav.imitation.demonstrations import Demonstrations
from sb3_crowdnav.imitation.pretrain import DemoTensors, dqfd_loss
from sb3_crowdnav.nn.buffers import DictNStepMixin
from sb3_crowdnav.nn.policies import ApgDQNPolicy
from sb3_crowdnav.sim.validation import check_int, check_number


class DQfD(DictNStepMixin, DQN):
    """SB3 ``DQN`` that keeps learning from its demonstrations (DQfD, Hester et al. 2018).

    After each of DQN's gradient steps on its replay buffer, one more step on ``demo_batch_size``
    demonstration transitions: their 1-step TD loss plus ``margin_coef`` x the large-margin loss
    ``max_a [Q(s, a) + margin·1(a ≠ a_E)] - Q(s, a_E)``. Plain DQN started from the same
    pre-training drifts into wandering until its episodes time out; the supervised term keeps the greedy policy
    anchored to the demonstrator while Q-learning improves on it.

    Give the demonstrations with :meth:`set_demonstrations` (``sb3-crowdnav train --algo dqfd
    --imitation-episodes N`` does it after :func:`pretrain_dqn`). They are not saved with the model
    (hundreds of MB); the file loads with ``DQN.load`` (and ``DQfD.load``, which continues as plain
    DQN until demonstrations are set again).

    Its ``policy`` may also be ``"ApgPolicy"`` (:class:`~sb3_crowdnav.nn.ApgDQNPolicy`), as in the package's
    hyperparameter files; SB3's own ``DQN`` is left as it is. ``n_steps > 1`` gives the replay buffer n-step targets
    (:class:`~sb3_crowdnav.nn.DictNStepMixin`); the demonstration term stays one-step, as in :func:`pretrain_dqn`.

    :param demo_batch_size: demonstration transitions per extra gradient step
    :param margin: the large margin m
    :param margin_coef: weight of the large-margin loss
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {**DQN.policy_aliases, "ApgPolicy": ApgDQNPolicy}

    def __init__(self, *args, demo_batch_size: int = 64, margin: float = 0.1, margin_coef: float = 1.0, **kwargs) -> None:
        check_int("demo_batch_size", demo_batch_size, 1)
        check_number("margin", margin, allow_zero=True)
        check_number("margin_coef", margin_coef, allow_zero=True)
        self.demo_batch_size = int(demo_batch_size)
        self.margin = float(margin)
        self.margin_coef = float(margin_coef)
        self.demonstrations: Demonstrations | None = None
        super().__init__(*args, **kwargs)

    def set_demonstrations(self, demos: Demonstrations | None) -> None:
        """Transitions to keep learning from (None: continue as plain DQN)."""
        if demos is not None and not isinstance(demos, Demonstrations):
            raise TypeError(f"demos must be a Demonstrations, got {type(demos).__name__}")
        if demos is not None and len(demos) == 0:
            raise ValueError("demos is empty")
        if demos is not None and demos.next_observations is None:
            raise ValueError("DQfD needs next observations: collect with keep_next_observations=True")
        self.demonstrations = demos
        self._demo_tensors = None if demos is None else DemoTensors(demos, self.device)
        self._demo_rng = np.random.default_rng(self.seed)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        super().train(gradient_steps, batch_size)
        demos = self.demonstrations
        if demos is None:
            return
        losses = []
        for _ in range(gradient_steps):
            idx = self._demo_rng.integers(0, len(demos), self.demo_batch_size)
            loss = dqfd_loss(self, demos, self._demo_tensors, idx, self.margin, self.margin_coef)
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
            losses.append(loss.item())
        self.logger.record("train/demo_loss", float(np.mean(losses)))

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "demonstrations", "_demo_tensors", "_demo_rng"]


