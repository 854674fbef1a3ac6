"""What APGValue accepts: its constructor arguments, replay buffers and env wrappers, checked before any work."""

from __future__ import annotations

from typing import Any

import torch as th
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecNormalize, unwrap_vec_wrapper
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

from sb3_crowdnav.apg_value.buffers import ValueReplayBuffer
from sb3_crowdnav.apg_value.overlap import OVERLAP_KINDS
from sb3_crowdnav.serialization import world_of
from sb3_crowdnav.sim.validation import check_bool, check_choice, check_int, check_number, check_positive, check_range
from sb3_crowdnav.sim.world import World, compare_worlds, upgrade_policy_kwargs

VALUE_TARGETS = ("td", "greedy_td", "lookahead")


def check_env_compatible(env: VecEnv | None) -> None:
    """Refuse wrappers that corrupt the physical states the lookahead propagates."""
    if env is None:
        return
    for wrapper in (VecNormalize, VecFrameStack):
        if unwrap_vec_wrapper(env, wrapper) is not None:
            raise ValueError(
                f"APGValue cannot use {wrapper.__name__}: the lookahead propagates the raw physical observation "
                "(positions, velocities) one step ahead; remove the wrapper"
            )


def with_env_world(policy_kwargs: dict[str, Any], env: VecEnv | None) -> dict[str, Any]:
    """``policy_kwargs`` with ``"world"``: the plain form of the env's :class:`~sb3_crowdnav.sim.world.World`.

    A world already in ``policy_kwargs`` (a loaded model's; older files' separate entries are upgraded by
    :func:`~sb3_crowdnav.sim.world.upgrade_policy_kwargs`) must be the env's in every field: the lookahead would
    otherwise propagate, and learn the rewards of, another world than the one it acts in. Without an env the given
    world is kept (checked, in its plain form).
    """
    kwargs = upgrade_policy_kwargs(policy_kwargs)
    given = World.coerce(kwargs["world"]) if "world" in kwargs else None
    world = world_of(env) if env is not None else None
    if world is not None and given is not None and (mismatch := compare_worlds(given, world)):
        raise ValueError(f"policy_kwargs['world'] does not match the env's world: {mismatch}")
    world = world if world is not None else given
    if world is not None:
        kwargs["world"] = world.to_dict()
    return kwargs


def check_policy_name(policy: Any, aliases: dict[str, Any]) -> None:
    """``ValueError`` listing APGValue's policy aliases when given another name (SB3's ``MlpPolicy``, ...)."""
    if isinstance(policy, str) and policy not in aliases:
        raise ValueError(f"policy {policy!r} is not an APGValue policy; use one of {sorted(aliases)} (SB3's "
                         "MlpPolicy and MultiInputPolicy are for DQN and PPO; with them, use ApgDQNPolicy or "
                         "ApgActorCriticPolicy for the APG extractor)")


def check_args(*, exploration_initial_eps: float, exploration_final_eps: float, gamma: float, tau: float,
               exploration_episodes: int, imitation_episodes: int, imitation_epochs: int, target_update_interval: int,
               batch_size: int, bootstrap_timeouts: bool, overlap_training: bool | str, value_target: str) -> None:
    """``TypeError`` naming the first of APGValue's scalar arguments of a wrong type, ``ValueError`` out of its range."""
    check_range("exploration_initial_eps", exploration_initial_eps, 0, 1)
    check_range("exploration_final_eps", exploration_final_eps, 0, 1)
    check_range("gamma", gamma, 0, 1, low_open=True)
    check_range("tau", tau, 0, 1, low_open=True)
    for name, value, minimum in (
        ("exploration_episodes", exploration_episodes, 1),
        ("imitation_episodes", imitation_episodes, 0),
        ("imitation_epochs", imitation_epochs, 0),
        ("target_update_interval", target_update_interval, 1),
        ("batch_size", batch_size, 1),
    ):
        check_int(name, value, minimum)
    check_bool("bootstrap_timeouts", bootstrap_timeouts)
    if not (isinstance(overlap_training, bool) or overlap_training in OVERLAP_KINDS):
        raise ValueError(f"overlap_training must be a bool or one of {OVERLAP_KINDS}, got {overlap_training!r}")
    check_choice("value_target", value_target, VALUE_TARGETS)


def check_replay_buffer_class(replay_buffer_class: type[DictReplayBuffer] | None,
                              value_target: str) -> type[DictReplayBuffer]:
    """The replay buffer class to use (:class:`ValueReplayBuffer` by default); refuses HER and, for the targets that
    need it, a buffer that does not record how each action was chosen."""
    if replay_buffer_class is None:
        return ValueReplayBuffer
    if issubclass(replay_buffer_class, HerReplayBuffer):
        raise ValueError("APGValue does not support HerReplayBuffer: CrowdNav has no goal relabelling")
    if value_target != "td" and not issubclass(replay_buffer_class, ValueReplayBuffer):
        raise ValueError(
            f"value_target={value_target!r} needs a ValueReplayBuffer (it stores how each action was chosen); "
            f"got replay_buffer_class={replay_buffer_class.__name__}"
        )
    return replay_buffer_class


def check_imitation_args(learning_rate: float, optimizer_class: Any, optimizer_kwargs: dict[str, Any] | None,
                         safety_space: float, mapping: str, mappings: tuple[str, ...]) -> dict[str, Any]:
    """Validate APGValue's imitation arguments; return the optimiser's keyword arguments (SGD: momentum 0.9)."""
    if not (isinstance(optimizer_class, type) and issubclass(optimizer_class, th.optim.Optimizer)):
        raise TypeError(f"imitation_optimizer_class must be a torch.optim.Optimizer subclass, got {optimizer_class!r}")
    check_positive("imitation_learning_rate", learning_rate)
    check_number("imitation_safety_space", safety_space, allow_zero=True)
    check_choice("imitation_mapping", mapping, mappings)
    if optimizer_kwargs is None:
        return {"momentum": 0.9} if issubclass(optimizer_class, th.optim.SGD) else {}
    return dict(optimizer_kwargs)
