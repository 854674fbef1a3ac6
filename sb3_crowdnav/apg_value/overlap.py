"""``overlap_training``: APGValue's gradient steps on the second core while the envs collect the next steps.

The learner runs the gradient steps of one training call while the acting loop collects the next ``train_freq``
env steps with a copy of V taken when those gradient steps started (V is one training call stale when acting).
Every hand-over (``join``) happens at a fixed point of the schedule — the next training call, a target-network
update, ``save`` and the end of ``learn`` — so a run is deterministic, though not the same run as without overlap.

Two learners with one interface and the same arithmetic (:class:`~.learner.ValueLearner`), hence the same run:

* :class:`ThreadLearner` (``overlap_training="thread"``): a second thread. Torch ops release the GIL, but the
  learner's Python-level work (module calls, autograd bookkeeping) takes it in small slices: decisions run ~25 %
  slower beside it (``benchmarks/contention.py``).
* :class:`ProcessLearner` (``"process"``): a second process (``spawn``) that owns the training copy of V, of
  V_target and of the optimiser. The acting process sends each training call's replay batches (plain arrays
  through a pipe) with the learning rate, and their targets when it computed them (it does when it had to wait
  for the learner at the last hand-over, as the acting thread does: the same numbers); the learner sends back the
  losses after writing V's new weights into shared memory, which the acting process copies into its V at the
  hand-over. V_target is updated in both
  processes at the same point of the schedule; the optimiser's state comes back for ``save`` and at the end
  of ``learn``. Decisions run ~13 % slower beside it (the two cores still share caches and memory bandwidth).
  As with SB3's ``SubprocVecEnv``, a script that trains this way must guard its entry point with
  ``if __name__ == "__main__":`` (the learner process imports the main module).
"""

from __future__ import annotations

import copy
import traceback
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.utils import polyak_update

from sb3_crowdnav.apg_value.learner import Batch, ValueLearner
from sb3_crowdnav.apg_value.policies import bfloat16_extractors

OVERLAP_KINDS = ("thread", "process")


def _acting_copy(value_net: th.nn.Module, bfloat16_acting: bool) -> th.nn.Module:
    """V's copy that acts while V trains; with ``bfloat16_acting`` it runs its APG encoder in bfloat16, V in float32."""
    acting_net = copy.deepcopy(value_net).train(False)
    for acting, training in zip(bfloat16_extractors(acting_net), bfloat16_extractors(value_net), strict=True):
        acting.bfloat16_inference = bfloat16_acting
        training.bfloat16_inference = False
    return acting_net


class ThreadLearner:
    """The acting copy of V and one worker thread for the gradient steps in flight.

    :param value_net: V; its copy acts while V trains
    :param steps: the gradient steps of a list of batches, returning their losses (``APGValue._gradient_steps``)
    :param bfloat16_acting: run the copy's APG encoder in bfloat16 (V itself trains in float32)
    """

    def __init__(self, value_net: th.nn.Module, steps: Callable[[list[Batch]], list[float]],
                 bfloat16_acting: bool) -> None:
        self.acting_net = _acting_copy(value_net, bfloat16_acting)
        self._steps = steps
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="apg-learner")
        self._job: Future | None = None

    @property
    def busy(self) -> bool:
        """Gradient steps are still running (the learner is slower than the acting thread)."""
        return self._job is not None and not self._job.done()

    def submit(self, batches: list[Batch], learning_rates: list[float]) -> None:
        """Start the gradient steps of ``batches`` in the learner thread (after :meth:`join`); the optimiser's
        learning rates are already set in this process."""
        self._job = self._executor.submit(self._steps, batches)

    def join(self) -> list[float] | None:
        """Wait for the gradient steps in flight; their losses (None when none ran); re-raises their exception."""
        job, self._job = self._job, None
        return None if job is None else job.result()

    def sync(self, value_net: th.nn.Module) -> None:
        """Act with V's current weights from now on."""
        self.acting_net.load_state_dict(value_net.state_dict())

    def update_target(self, tau: float) -> None:
        """V_target was updated in this process, which the thread shares: nothing to do."""

    def pull_optimizer(self, optimizer: th.optim.Optimizer) -> None:
        """The thread steps this process's optimiser itself: nothing to do."""

    def shutdown(self) -> None:
        self._executor.shutdown(wait=True)


def _convert(data: Any, leaf: type, convert: Callable[[Any], Any]) -> Any:
    """``data`` (a replay batch: named tuples, tuples and dicts of arrays) with ``convert`` applied to every ``leaf``."""
    if isinstance(data, leaf):
        return convert(data)
    if isinstance(data, dict):
        return {key: _convert(value, leaf, convert) for key, value in data.items()}
    if isinstance(data, tuple):
        values = (_convert(value, leaf, convert) for value in data)
        return type(data)(*values) if hasattr(data, "_fields") else tuple(values)
    return data


def _as_numpy(data: Any) -> Any:
    """A replay batch with plain arrays instead of tensors (sent through the pipe without shared-memory files)."""
    return _convert(data, th.Tensor, th.Tensor.numpy)


def _as_torch(data: Any) -> Any:
    """Inverse of :func:`_as_numpy`."""
    return _convert(data, np.ndarray, th.from_numpy)


def _serve(conn: Any, policy: Any, learner_kwargs: dict[str, Any], shared: dict[str, th.Tensor],
           num_threads: int) -> None:
    """The learner process: answer ``(command, argument)`` messages until ``"stop"`` or the pipe closes."""
    from sb3_crowdnav.nn import configure_cpu

    configure_cpu(num_threads=num_threads)
    for extractor in bfloat16_extractors(policy.value_net):  # V trains in float32
        extractor.bfloat16_inference = False
    policy.set_training_mode(True)
    learner = ValueLearner(policy, **learner_kwargs)
    while True:
        try:
            command, argument = conn.recv()
        except EOFError:  # the acting process is gone
            return
        if command == "stop":
            return
        try:
            if command == "steps":
                learning_rates, batches = argument
                for group, lr in zip(policy.optimizer.param_groups, learning_rates, strict=True):
                    group["lr"] = lr
                reply: Any = learner.gradient_steps([Batch(*_as_torch(batch)) for batch in batches])
                with th.no_grad():
                    for key, value in policy.value_net.state_dict().items():
                        shared[key].copy_(value)
            elif command == "target":
                polyak_update(policy.value_net.parameters(), policy.value_net_target.parameters(), argument)
                reply = None
            elif command == "optimizer":
                reply = _as_numpy(policy.optimizer.state_dict())
            else:
                raise ValueError(f"unknown learner command {command!r}")
            conn.send(("ok", reply))
        except Exception as exc:  # handed to the acting process, which re-raises it
            try:
                conn.send(("error", exc))
            except Exception:  # the exception does not pickle: send its text
                conn.send(("error", RuntimeError(traceback.format_exc())))


class ProcessLearner:
    """The acting copy of V and a learner process that owns V's training (started at the first :meth:`submit`).

    :param policy: the acting process's value policy; its V receives the learner's weights at every :meth:`join`
    :param learner_kwargs: ``gamma``, ``value_target`` and ``max_grad_norm`` of :class:`~.learner.ValueLearner`
    :param bfloat16_acting: run the acting copy's APG encoder in bfloat16 (V trains in float32)
    :param num_threads: torch threads of the learner process
    :param poll_seconds: how often a waiting :meth:`join` checks that the learner process is alive
    """

    def __init__(self, policy: Any, learner_kwargs: dict[str, Any], bfloat16_acting: bool, num_threads: int = 1,
                 poll_seconds: float = 1.0) -> None:
        self.policy = policy
        self.acting_net = _acting_copy(policy.value_net, bfloat16_acting)
        self._learner_kwargs = dict(learner_kwargs)
        self._num_threads, self._poll_seconds = num_threads, poll_seconds
        self._process: Any = None
        self._conn: Any = None
        self._shared: dict[str, th.Tensor] = {}
        self._pending = False
        self._failed = False  # the learner raised or died: nothing more is asked of it

    def _start(self) -> None:
        context = th.multiprocessing.get_context("spawn")
        self._shared = {key: value.detach().clone().share_memory_()
                        for key, value in self.policy.value_net.state_dict().items()}
        self._conn, child = context.Pipe()
        self._process = context.Process(target=_serve, name="apg-learner", daemon=True,
                                        args=(child, self.policy, self._learner_kwargs, self._shared,
                                              self._num_threads))
        self._process.start()
        child.close()

    def _died(self) -> RuntimeError:
        self._pending, self._failed = False, True
        self._process.join(timeout=self._poll_seconds)
        return RuntimeError(f"the learner process (overlap_training='process') died (exit code "
                            f"{self._process.exitcode})")

    def _send(self, command: str, argument: Any) -> None:
        try:
            self._conn.send((command, argument))
        except OSError as exc:
            raise self._died() from exc
        self._pending = True

    def _request(self, command: str, argument: Any = None) -> Any:
        self._send(command, argument)
        return self._reply()

    def _reply(self) -> Any:
        while not self._conn.poll(self._poll_seconds):
            if not self._process.is_alive():
                raise self._died()
        try:
            status, value = self._conn.recv()
        except (EOFError, OSError) as exc:
            raise self._died() from exc
        self._pending = False
        if status == "error":
            self._failed = True
            raise value
        return value

    @property
    def busy(self) -> bool:
        """Gradient steps are still running (the learner is slower than the acting process)."""
        return self._pending and not self._conn.poll()

    def submit(self, batches: list[Batch], learning_rates: list[float]) -> None:
        """Send ``batches`` to the learner process (after :meth:`join`); the targets of those without one are
        computed there."""
        if self._process is None:
            self._start()
        self._send("steps", (list(learning_rates), [_as_numpy((b.data, b.target, b.weights)) for b in batches]))

    def join(self) -> list[float] | None:
        """Wait for the gradient steps in flight and copy V's new weights into this process's V; their losses
        (None when none ran); re-raises the learner's exception."""
        if not self._pending:
            return None
        losses = self._reply()
        self.policy.value_net.load_state_dict(self._shared)
        return losses

    def sync(self, value_net: th.nn.Module) -> None:
        """Act with V's current weights from now on."""
        self.acting_net.load_state_dict(value_net.state_dict())

    def update_target(self, tau: float) -> None:
        """Update the learner's V_target as this process just updated its own (after :meth:`join`)."""
        if self._process is not None and not self._failed:
            self._request("target", tau)

    def pull_optimizer(self, optimizer: th.optim.Optimizer) -> None:
        """Copy the learner's optimiser state into this process's ``optimizer`` (after :meth:`join`); after a
        failure of the learner, ``optimizer`` keeps the state of the last ``save`` or ``learn()``."""
        if self._process is not None and not self._failed:
            optimizer.load_state_dict(_as_torch(self._request("optimizer")))

    def shutdown(self) -> None:
        if self._process is None:
            return
        try:
            self._conn.send(("stop", None))
        except (BrokenPipeError, OSError):
            pass
        self._process.join(timeout=30)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()
        self._conn.close()
        self._process = None
