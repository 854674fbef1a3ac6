"""``overlap_training``: APGValue's gradient steps on the second core while the envs collect the next steps.

The learner runs the gradient steps of one training call while the acting loop collects the next ``train_freq``
env steps with a copy of V taken when those gradient steps started (V is one training call stale when acting).
Every hand-over happens at a fixed point of the schedule — the next training call, a target-network update,
``save`` and the end of ``learn`` — so a run is deterministic, though not the same run as without overlap.

Two learners of the :class:`~.learner.Learner` protocol with the same arithmetic
(:class:`~.learner.ValueLearner`), hence the same run:

* :class:`ThreadLearner` (``overlap_training="thread"``): a second thread. Torch ops release the GIL, but the
  learner's Python-level work (module calls, autograd bookkeeping) takes it in small slices, so the acting
  thread's decisions slow down beside it (``benchmarks/contention.py`` measures by how much).
* :class:`ProcessLearner` (``"process"``): a second process (``spawn``) that owns the training copy of V, of
  V_target and of the optimiser. The acting process sends each training call's replay batches (plain arrays
  through a pipe) with the learning rate, and their targets when it computed them; the learner sends back the
  losses after writing V's new weights into shared memory, which the acting process copies into its V at the
  hand-over. V_target is updated in both processes at the same point of the schedule; the optimiser's state
  comes back for ``save`` and at the end of ``learn``. As with SB3's ``SubprocVecEnv``, a script that trains
  this way must guard its entry point with ``if __name__ == "__main__":`` (the learner process imports the
  main module); a learner process that cannot start for want of it says so.

Whichever side waited at the last hand-over computes the next batches' targets: they read V_target only, which
changes at hand-overs only, so the numbers are the same on either side and this timing-based choice does not
change the run.
"""

from __future__ import annotations

import copy
import traceback
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.utils import polyak_update, update_learning_rate

from sb3_crowdnav.apg_value.learner import Batch, Learner, SerialLearner, ValueLearner
from sb3_crowdnav.apg_value.policies import bfloat16_extractors

OVERLAP_KINDS = ("thread", "process")
GUARD_HINT = ("a script that trains with overlap_training='process' must put its training under "
              "if __name__ == \"__main__\": (the learner process imports the main script again), or use "
              "overlap_training='thread'")


def _acting_copy(value_net: th.nn.Module, bfloat16_acting: bool) -> th.nn.Module:
    """V's copy that acts while V trains; with ``bfloat16_acting`` it runs its APG encoder in bfloat16, V in float32."""
    acting_net = copy.deepcopy(value_net).train(False)
    for acting, training in zip(bfloat16_extractors(acting_net), bfloat16_extractors(value_net), strict=True):
        acting.bfloat16_inference = bfloat16_acting
        training.bfloat16_inference = False
    return acting_net


class _OverlapLearner(SerialLearner):
    """What both overlapping learners share: between :meth:`start` and :meth:`stop` a copy of V acts (V trains
    elsewhere), and a training call hands over the previous one before it starts; outside ``learn()`` V acts, as
    with :class:`~.learner.SerialLearner`."""

    def __init__(self, arithmetic: Callable[[], ValueLearner]) -> None:
        super().__init__(arithmetic)
        self.learner: ValueLearner | None = None  # the arithmetic of the running learn() call
        self.acting: th.nn.Module | None = None

    def acting_net(self) -> th.nn.Module:
        return super().acting_net() if self.acting is None else self.acting

    def start(self) -> None:
        self.learner = self.arithmetic()
        policy = self.learner.policy
        policy.set_training_mode(True)  # V only trains from here on; the acting copy only acts
        self.acting = _acting_copy(policy.value_net, policy.lookahead_dtype == "bfloat16")

    @property
    def busy(self) -> bool:
        """Gradient steps are still running (the learner is slower than the acting loop)."""
        raise NotImplementedError

    def submit(self, batches: list[Batch], learning_rate: float) -> list[float] | None:
        learner, acting = self.learner, self.acting
        assert learner is not None and acting is not None, "submit() before start()"
        if self.busy:  # the learner was slower: the acting side computes the targets while it waits
            batches = [Batch(b.data, *learner.batch_target(b.data)) for b in batches]
        losses = self.join()
        acting.load_state_dict(learner.policy.value_net.state_dict())  # act with the completed call's V
        update_learning_rate(learner.policy.optimizer, learning_rate)
        self._begin(batches, learning_rate)
        return losses

    def _begin(self, batches: list[Batch], learning_rate: float) -> None:
        """Start the gradient steps of ``batches`` (the previous call has been joined)."""
        raise NotImplementedError

    def update_target(self, tau: float) -> None:
        policy = self.arithmetic().policy if self.learner is None else self.learner.policy
        polyak_update(policy.value_net.parameters(), policy.value_net_target.parameters(), tau)

    def stop(self) -> None:
        self._shutdown()
        if self.learner is not None:
            policy = self.learner.policy
            policy.set_lookahead_dtype(policy.lookahead_dtype)  # give V back its acting precision
        self.learner = self.acting = None

    def _shutdown(self) -> None:
        raise NotImplementedError


class ThreadLearner(_OverlapLearner):
    """A worker thread runs the gradient steps on this process's V and optimiser while a copy of V acts.

    :param arithmetic: as :class:`~.learner.SerialLearner`'s
    """

    def __init__(self, arithmetic: Callable[[], ValueLearner]) -> None:
        super().__init__(arithmetic)
        self._executor: ThreadPoolExecutor | None = None
        self._job: Future | None = None

    def start(self) -> None:
        super().start()
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="apg-learner")

    @property
    def busy(self) -> bool:
        return self._job is not None and not self._job.done()

    def _begin(self, batches: list[Batch], learning_rate: float) -> None:
        assert self._executor is not None and self.learner is not None
        self._job = self._executor.submit(self.learner.gradient_steps, batches)

    def join(self) -> list[float] | None:
        job, self._job = self._job, None
        return None if job is None else job.result()

    def _shutdown(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=True)
        self._executor, self._job = None, None


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

    conn.send(("ready", None))  # the main module imported: the parent can tell a failed start from a crash
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
                learning_rate, batches = argument
                update_learning_rate(policy.optimizer, learning_rate)
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


class ProcessLearner(_OverlapLearner):
    """A learner process owns V's training (started at the first :meth:`submit`) while a copy of V acts here.

    :param arithmetic: as :class:`~.learner.SerialLearner`'s; its policy's V receives the learner's weights at
        every :meth:`join`
    :param poll_seconds: how often a waiting :meth:`join` checks that the learner process is alive
    """

    def __init__(self, arithmetic: Callable[[], ValueLearner], poll_seconds: float = 1.0) -> None:
        super().__init__(arithmetic)
        self.poll_seconds = poll_seconds
        self._process: Any = None
        self._conn: Any = None
        self._shared: dict[str, th.Tensor] = {}
        self._pending = False
        self._ready = False  # the learner process has imported the main module and serves
        self._failed = False  # the learner raised or died: nothing more is asked of it

    def _start_process(self) -> None:
        assert self.learner is not None
        policy = self.learner.policy
        context = th.multiprocessing.get_context("spawn")
        self._shared = {key: value.detach().clone().share_memory_() for key, value in policy.value_net.state_dict().items()}
        learner_kwargs = dict(gamma=self.learner.gamma, value_target=self.learner.value_target,
                              max_grad_norm=self.learner.max_grad_norm)
        conn, child = context.Pipe()
        # a copy goes: pickling for spawn moves a tensor's storage into shared memory, which would make this
        # process's V_target the learner's own, and each target update would then move it twice
        process = context.Process(target=_serve, name="apg-learner", daemon=True,
                                  args=(child, copy.deepcopy(policy), learner_kwargs, self._shared,
                                        th.get_num_threads()))
        try:
            process.start()
        except RuntimeError:  # spawn refuses to start a process while this one imports the main module
            child.close()
            conn.close()
            raise RuntimeError(f"cannot start a learner process while this process imports the main script: "
                               f"{GUARD_HINT}") from None
        child.close()
        self._process, self._conn, self._ready = process, conn, False

    def _died(self) -> RuntimeError:
        self._pending, self._failed = False, True
        self._process.join(timeout=self.poll_seconds)
        code = self._process.exitcode
        if not self._ready:  # it failed while importing the main module: the script re-ran its training there
            return RuntimeError(f"the learner process failed before it started (exit code {code}; its own error is "
                                f"printed above): {GUARD_HINT}")
        return RuntimeError(f"the learner process (overlap_training='process') died (exit code {code})")

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
        while True:
            while not self._conn.poll(self.poll_seconds):
                if not self._process.is_alive():
                    raise self._died()
            try:
                status, value = self._conn.recv()
            except (EOFError, OSError) as exc:
                raise self._died() from exc
            if status != "ready":
                break
            self._ready = True
        self._pending = False
        if status == "error":
            self._failed = True
            raise value
        return value

    @property
    def busy(self) -> bool:
        return self._pending and not self._conn.poll()

    def _begin(self, batches: list[Batch], learning_rate: float) -> None:
        if self._process is None:  # V, V_target and the optimiser as imitation and the first call left them
            self._start_process()
        self._send("steps", (learning_rate, [_as_numpy((b.data, b.target, b.weights)) for b in batches]))

    def join(self) -> list[float] | None:
        """Wait for the gradient steps in flight and copy V's new weights into this process's V; their losses
        (None when none ran); re-raises the learner's exception."""
        if not self._pending:
            return None
        losses = self._reply()
        assert self.learner is not None
        self.learner.policy.value_net.load_state_dict(self._shared)
        return losses

    def update_target(self, tau: float) -> None:
        super().update_target(tau)
        if self._process is not None and not self._failed:  # the learner's V_target follows this one
            self._request("target", tau)

    def pull_optimizer(self) -> None:
        """Copy the learner's optimiser state into this process's optimiser (after :meth:`join`); after a failure
        of the learner, the optimiser keeps the state of the last ``save`` or ``learn()``."""
        if self._process is not None and not self._failed and self.learner is not None:
            self.learner.policy.optimizer.load_state_dict(_as_torch(self._request("optimizer")))

    def _shutdown(self) -> None:
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
        self._pending = self._failed = False


LEARNERS: dict[str | None, type[SerialLearner]] = {None: SerialLearner, "thread": ThreadLearner,
                                                   "process": ProcessLearner}


def make_learner(kind: str | None, arithmetic: Callable[[], ValueLearner]) -> Learner:
    """The learner of ``overlap_training``'s kind (None: :class:`~.learner.SerialLearner`)."""
    return LEARNERS[kind](arithmetic)
