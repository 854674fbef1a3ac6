"""n-step returns on Dict observations for SB3's DQN family: :class:`NStepDictReplayBuffer`.

SB3 2.9's off-policy algorithms build their ``NStepReplayBuffer`` for ``Box`` observations only and refuse
``n_steps > 1`` on a ``Dict`` space ("N-step returns are not supported for Dict observation spaces yet"); every
observation of this package is a ``Dict``. :class:`NStepDictReplayBuffer` is SB3's ``DictReplayBuffer`` whose samples
are SB3's own n-step arithmetic: its ``_get_samples`` *is* ``NStepReplayBuffer._get_samples``, run on a view of this
buffer in which the dict of observation arrays is indexed as one array. The discounting, the stop at a termination
or a timeout (``handle_timeout_termination``), the wrap-around at the buffer's end and the per-sample
``discounts`` (``gamma ** steps``, which DQN and QR-DQN bootstrap with) are therefore SB3's, not a copy of them.

Give it to an algorithm by hand, with the algorithm's own ``gamma``::

    DQN(ApgDQNPolicy, env, gamma=0.98, replay_buffer_class=NStepDictReplayBuffer,
        replay_buffer_kwargs={"n_steps": 3, "gamma": 0.98})

or write ``n_steps: 3`` in a hyperparameter file: ``sb3-crowdnav train --hyperparams`` and ``sb3-crowdnav-zoo`` turn
it into exactly these keywords (:func:`dict_n_step_kwargs`), as do the algorithms with :class:`DictNStepMixin`
(``DQfD`` and the rl-zoo3 classes) when given ``n_steps``. The model's own ``n_steps`` then stays 1 (SB3's switch
for its ``Box`` buffer, which would warn that a custom buffer ignores it); ``replay_buffer_kwargs`` records the
setting in the saved file.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer, NStepReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.type_aliases import DictReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_crowdnav.sim.validation import check_int, check_range


class _DictRows:
    """A dict of ``(buffer_size, n_envs, *shape)`` arrays indexed as one array: ``rows[i, e]`` is ``{key: a[i, e]}``."""

    def __init__(self, arrays: Mapping[str, np.ndarray]) -> None:
        self.arrays = arrays

    def __getitem__(self, index: Any) -> dict[str, np.ndarray]:
        return {key: array[index] for key, array in self.arrays.items()}


class _NStepView:
    """The buffer as ``NStepReplayBuffer._get_samples`` reads it: every attribute is the buffer's own (the arrays it
    marks and restores are the buffer's), except that the observations are :class:`_DictRows` and ``to_torch``
    converts a dict key by key."""

    def __init__(self, buffer: NStepDictReplayBuffer) -> None:
        self.buffer = buffer
        self.observations = _DictRows(buffer.observations)
        self.next_observations = _DictRows(buffer.next_observations)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.buffer, name)

    def to_torch(self, array: np.ndarray | dict[str, np.ndarray], copy: bool = True) -> Any:
        if isinstance(array, dict):
            return {key: self.buffer.to_torch(value, copy) for key, value in array.items()}
        return self.buffer.to_torch(array, copy)


class NStepDictReplayBuffer(DictReplayBuffer):
    """SB3's ``DictReplayBuffer`` sampling n-step returns, with SB3's ``NStepReplayBuffer`` arithmetic.

    A sample's ``rewards`` are ``sum_k gamma**k r_{t+k}`` over the next ``n_steps`` transitions of its env, stopped at
    the first termination or timeout (that one included); ``next_observations`` and ``dones`` are those of the last
    transition summed, and ``discounts`` is ``gamma ** (transitions summed)``, the factor of the bootstrapped value.

    :param buffer_size: max number of transitions (over all envs)
    :param observation_space: the ``Dict`` observation space
    :param action_space: action space
    :param device: PyTorch device
    :param n_envs: number of parallel envs
    :param optimize_memory_usage: not supported (SB3's ``DictReplayBuffer`` refuses it)
    :param handle_timeout_termination: bootstrap from the last state of a timed-out episode (SB3's meaning)
    :param n_steps: transitions summed per sample (>= 1; 1 is the one-step target)
    :param gamma: discount factor per transition, in (0, 1]; give the algorithm's own ``gamma``
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Dict,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        *,
        n_steps: int,
        gamma: float,
    ) -> None:
        check_int("n_steps", n_steps, 1)
        check_range("gamma", gamma, 0, 1, low_open=True)
        super().__init__(buffer_size, observation_space, action_space, device=device, n_envs=n_envs,
                         optimize_memory_usage=optimize_memory_usage,
                         handle_timeout_termination=handle_timeout_termination)
        self.n_steps = int(n_steps)
        self.gamma = float(gamma)

    def _get_samples(  # type: ignore[override]
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> DictReplayBufferSamples:
        samples = NStepReplayBuffer._get_samples(_NStepView(self), batch_inds, env)  # type: ignore[arg-type]
        return DictReplayBufferSamples(**samples._asdict())


def _default(algorithm_class: type, name: str) -> Any:
    """The default of the constructor argument ``name`` of ``algorithm_class`` (the first ``__init__`` naming it)."""
    for klass in algorithm_class.__mro__:
        if "__init__" in vars(klass):
            parameter = inspect.signature(klass.__init__).parameters.get(name)
            if parameter is not None and parameter.default is not inspect.Parameter.empty:
                return parameter.default
    raise ValueError(f"{algorithm_class.__name__} has no default {name}")


def dict_n_step_kwargs(algorithm_class: type, observation_space: spaces.Space | None,
                       kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """The constructor keywords ``kwargs`` of an off-policy ``algorithm_class`` with ``n_steps > 1`` on a ``Dict``
    ``observation_space`` given as ``replay_buffer_class=NStepDictReplayBuffer`` and ``replay_buffer_kwargs``
    ``{"n_steps": n, "gamma": gamma}`` (the algorithm's ``gamma``); anything else is returned as it is.

    With ``replay_buffer_class=NStepDictReplayBuffer`` already given, its ``gamma`` defaults to the algorithm's. A
    ``ValueError`` when ``n_steps > 1`` comes with another buffer class (SB3 would ignore ``n_steps``), or when
    ``replay_buffer_kwargs`` contradicts ``n_steps`` or ``gamma``.
    """
    kwargs = dict(kwargs)
    if not (isinstance(algorithm_class, type) and issubclass(algorithm_class, OffPolicyAlgorithm)
            and isinstance(observation_space, spaces.Dict)):
        return kwargs
    n_steps = kwargs.get("n_steps", 1)
    check_int("n_steps", n_steps, 1)
    buffer_class = kwargs.get("replay_buffer_class")
    if n_steps == 1 and buffer_class is not NStepDictReplayBuffer:
        return kwargs
    if buffer_class not in (None, NStepDictReplayBuffer):
        raise ValueError(f"n_steps={n_steps} on Dict observations needs replay_buffer_class NStepDictReplayBuffer "
                         f"(or none), got {getattr(buffer_class, '__name__', buffer_class)}")
    gamma = kwargs.get("gamma", _default(algorithm_class, "gamma"))
    buffer_kwargs = dict(kwargs.get("replay_buffer_kwargs") or {})
    wanted = {"gamma": gamma} if n_steps == 1 else {"n_steps": n_steps, "gamma": gamma}
    for key, value in wanted.items():
        if buffer_kwargs.setdefault(key, value) != value:
            raise ValueError(f"replay_buffer_kwargs[{key!r}] = {buffer_kwargs[key]!r} contradicts {key} = {value!r}")
    kwargs.pop("n_steps", None)
    kwargs.update(replay_buffer_class=NStepDictReplayBuffer, replay_buffer_kwargs=buffer_kwargs)
    return kwargs


class DictNStepMixin:
    """An SB3 off-policy algorithm that takes ``n_steps > 1`` on a ``Dict`` observation space: before SB3 sets up the
    replay buffer, ``n_steps``, ``gamma`` and the buffer settings go through :func:`dict_n_step_kwargs`.

    Put it first among the bases: ``class ZooDQN(DictNStepMixin, DQN)``.
    """

    n_steps: int
    gamma: float
    observation_space: spaces.Space
    replay_buffer_class: Any
    replay_buffer_kwargs: dict[str, Any]

    def _setup_model(self) -> None:
        settings = {"n_steps": self.n_steps, "gamma": self.gamma, "replay_buffer_class": self.replay_buffer_class,
                    "replay_buffer_kwargs": self.replay_buffer_kwargs}
        settings = dict_n_step_kwargs(type(self), self.observation_space, settings)
        self.n_steps = settings.get("n_steps", 1)
        self.replay_buffer_class = settings["replay_buffer_class"]
        self.replay_buffer_kwargs = settings["replay_buffer_kwargs"]
        super()._setup_model()  # type: ignore[misc]


__all__ = ["DictNStepMixin", "NStepDictReplayBuffer", "dict_n_step_kwargs"]
