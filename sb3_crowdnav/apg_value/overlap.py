"""``overlap_training``: APGValue's gradient steps in a second thread while the envs collect the next steps.

The learner thread runs the gradient steps of one training call while the acting thread collects the
next ``train_freq`` env steps with a copy of V taken when those gradient steps started (V is one
training call stale when acting). Torch ops release the GIL, so the two threads use two cores.
Every hand-over (:meth:`OverlappingLearner.join`) happens at a fixed point of the schedule — the
next training call, a target-network update, ``save`` and the end of ``learn`` — so a run is
deterministic, though not the same run as without overlap.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import torch as th


@dataclasses.dataclass
class Batch:
    """A replay batch of one gradient step; ``target`` None until computed (by the acting or the learner thread)."""

    data: Any
    target: th.Tensor | None = None
    weights: th.Tensor | None = None


class OverlappingLearner:
    """The acting copy of V and one worker thread for the gradient steps in flight.

    :param value_net: V; its copy acts while V trains
    :param bfloat16_acting: run the copy's APG encoder in bfloat16 (V itself trains in float32)
    """

    def __init__(self, value_net: th.nn.Module, bfloat16_acting: bool) -> None:
        self.acting_net = copy.deepcopy(value_net).train(False)
        if hasattr(self.acting_net.features_extractor, "bfloat16_inference"):  # bf16 acting on the copy only
            self.acting_net.features_extractor.bfloat16_inference = bfloat16_acting
            value_net.features_extractor.bfloat16_inference = False
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="apg-learner")
        self._job: Future | None = None

    @property
    def busy(self) -> bool:
        """Gradient steps are still running (the learner is slower than the acting thread)."""
        return self._job is not None and not self._job.done()

    def submit(self, steps: Callable[[list[Batch]], list[float]], batches: list[Batch]) -> None:
        """Start ``steps(batches)`` in the learner thread (after :meth:`join`)."""
        self._job = self._executor.submit(steps, batches)

    def join(self) -> list[float] | None:
        """Wait for the gradient steps in flight; their losses (None when none ran); re-raises their exception."""
        job, self._job = self._job, None
        return None if job is None else job.result()

    def sync(self, value_net: th.nn.Module) -> None:
        """Act with V's current weights from now on."""
        self.acting_net.load_state_dict(value_net.state_dict())

    def shutdown(self) -> None:
        self._executor.shutdown(wait=True)
