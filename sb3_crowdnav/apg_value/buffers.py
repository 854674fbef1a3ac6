"""Replay buffer that also remembers how each transition's action was chosen.

``APGValue`` can train V on different targets (its ``value_target`` parameter); two of them
need one number per transition besides SB3's usual fields:

- ``greedy``: the action was the lookahead's argmax (or the demonstrator's), not an ε draw;
- ``lookahead_target``: max over the 80 actions of R(s, a) + γ^(Δt·v_pref)·V(s'_a), computed
  with the online network when the action was chosen (NaN where it was not computed).

The algorithm stages these with :meth:`ValueReplayBuffer.stage` right before SB3's
``_store_transition`` calls :meth:`add`; a transition added without staging counts as greedy
with no lookahead target.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.type_aliases import TensorDict
from stable_baselines3.common.vec_env import VecNormalize


class ValueReplayBufferSamples(NamedTuple):
    observations: TensorDict
    actions: th.Tensor
    next_observations: TensorDict
    dones: th.Tensor
    rewards: th.Tensor
    greedy: th.Tensor  # (batch, 1) float 0/1
    lookahead_targets: th.Tensor  # (batch, 1), NaN where none was stored


class ValueReplayBuffer(DictReplayBuffer):
    """:class:`~stable_baselines3.common.buffers.DictReplayBuffer` plus ``greedy`` and ``lookahead_target``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.greedy = np.ones((self.buffer_size, self.n_envs), dtype=bool)
        self.lookahead_target = np.full((self.buffer_size, self.n_envs), np.nan, dtype=np.float32)
        self._staged: tuple[np.ndarray, np.ndarray] | None = None

    @classmethod
    def from_dict_buffer(cls, buffer: DictReplayBuffer) -> ValueReplayBuffer:
        """Wrap a plain ``DictReplayBuffer`` (e.g. one saved by an older version): every transition greedy, no targets."""
        new = cls.__new__(cls)
        new.__dict__.update(buffer.__dict__)
        new.greedy = np.ones((new.buffer_size, new.n_envs), dtype=bool)
        new.lookahead_target = np.full((new.buffer_size, new.n_envs), np.nan, dtype=np.float32)
        new._staged = None
        return new

    def stage(self, greedy: np.ndarray, lookahead_target: np.ndarray) -> None:
        """Set the extra fields of the next :meth:`add` (one value per env)."""
        greedy = np.asarray(greedy, dtype=bool).reshape(-1)
        target = np.asarray(lookahead_target, dtype=np.float32).reshape(-1)
        if greedy.shape != (self.n_envs,) or target.shape != (self.n_envs,):
            raise ValueError(f"stage() expects one value per env ({self.n_envs}), got {greedy.shape} and {target.shape}")
        self._staged = (greedy, target)

    def add(self, *args: Any, **kwargs: Any) -> None:
        greedy, target = self._staged if self._staged is not None else (True, np.nan)
        self._staged = None
        self.greedy[self.pos] = greedy
        self.lookahead_target[self.pos] = target
        super().add(*args, **kwargs)

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> ValueReplayBufferSamples:  # type: ignore[override]
        if env is not None:
            raise ValueError("ValueReplayBuffer does not support VecNormalize")
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        column = (batch_inds, env_indices)
        dones = self.dones[column] * (1 - self.timeouts[column])
        return ValueReplayBufferSamples(
            observations={key: self.to_torch(obs[column]) for key, obs in self.observations.items()},
            actions=self.to_torch(self.actions[column]),
            next_observations={key: self.to_torch(obs[column]) for key, obs in self.next_observations.items()},
            dones=self.to_torch(dones).reshape(-1, 1),
            rewards=self.to_torch(self.rewards[column]).reshape(-1, 1),
            greedy=self.to_torch(self.greedy[column].astype(np.float32)).reshape(-1, 1),
            lookahead_targets=self.to_torch(self.lookahead_target[column]).reshape(-1, 1),
        )


def follow_timeout_handling(buffer: DictReplayBuffer | None, bootstrap_timeouts: bool) -> None:
    """Make ``buffer`` follow APGValue's ``bootstrap_timeouts`` (it may come from a model saved with the other setting)."""
    if buffer is None or buffer.handle_timeout_termination == bootstrap_timeouts:
        return
    if not bootstrap_timeouts:  # stored dones include truncations: forget which ones were timeouts
        buffer.timeouts[:] = 0
        buffer.handle_timeout_termination = False
    else:
        warnings.warn("the replay buffer did not record timeouts: its old truncations stay terminal")
        buffer.handle_timeout_termination = True


def save_buffer(buffer: DictReplayBuffer, path: str | Path) -> Path:
    """Write ``buffer`` as an ``.npz`` of plain arrays (loading it cannot run code); returns the path written.

    Holds the observations and next observations per key, actions, rewards, dones, timeouts, a
    :class:`ValueReplayBuffer`'s ``greedy`` and ``lookahead_target``, and ``pos``, ``full``, the size and the
    timeout handling.
    """
    arrays = {f"observations.{k}": v for k, v in buffer.observations.items()}
    arrays.update({f"next_observations.{k}": v for k, v in buffer.next_observations.items()})
    arrays.update({name: getattr(buffer, name) for name in (*_FIELDS, *_VALUE_FIELDS) if hasattr(buffer, name)})
    meta = {"pos": buffer.pos, "full": buffer.full, "buffer_size": buffer.buffer_size, "n_envs": buffer.n_envs,
            "handle_timeout_termination": buffer.handle_timeout_termination}
    path = Path(path)
    with open(path, "wb") as f:  # np.savez would append ".npz" to a name without it
        np.savez(f, **arrays, **{f"meta.{k}": np.asarray(v) for k, v in meta.items()})
    return path


def is_npz(path: Any) -> bool:
    """Whether ``path`` holds an ``.npz`` (a zip archive) rather than a pickle, whatever its name."""
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"PK\x03\x04"
    except OSError:
        return False


def load_buffer(buffer: DictReplayBuffer, path: str | Path) -> None:
    """Fill ``buffer`` (made by the algorithm with the same size and spaces) from :func:`save_buffer`'s file."""
    with np.load(path, allow_pickle=False) as saved:
        for key in ("buffer_size", "n_envs"):
            if int(saved[f"meta.{key}"]) != getattr(buffer, key):
                raise ValueError(f"{path}: the replay buffer was saved with {key} = {int(saved[f'meta.{key}'])}, "
                                 f"the model's has {getattr(buffer, key)}")
        targets = {f"observations.{k}": v for k, v in buffer.observations.items()}
        targets.update({f"next_observations.{k}": v for k, v in buffer.next_observations.items()})
        targets.update({name: getattr(buffer, name) for name in (*_FIELDS, *_VALUE_FIELDS) if hasattr(buffer, name)})
        for name, target in targets.items():
            if name in _VALUE_FIELDS and name not in saved:  # a plain DictReplayBuffer's: all greedy, no targets
                target[...] = True if name == "greedy" else np.nan
            elif name not in saved or saved[name].shape != target.shape:
                raise ValueError(f"{path}: array {name!r} is missing or of another shape than the model's buffer")
            else:
                target[...] = saved[name]
        buffer.pos, buffer.full = int(saved["meta.pos"]), bool(saved["meta.full"])
        buffer.handle_timeout_termination = bool(saved["meta.handle_timeout_termination"])


_FIELDS = ("actions", "rewards", "dones", "timeouts")
_VALUE_FIELDS = ("greedy", "lookahead_target")
