"""APGValue's imitation pre-training (paper §3): V regressed on the discounted returns of ORCA-robot episodes.

The demonstrations come from the package's one collector,
:func:`sb3_crowdnav.imitation.collect_demonstrations`; every transition also goes into APGValue's
replay buffer as it is collected (so RL starts replaying them), and the regression itself is
:func:`sb3_crowdnav.imitation.pretrain_value`.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np
import torch as th

from sb3_crowdnav.imitation import collect_demonstrations, pretrain_value
from sb3_crowdnav.sim.observation import Robot

if TYPE_CHECKING:
    from sb3_crowdnav.apg_value.apg_value import APGValue


def last_step_first(episode_end: np.ndarray) -> np.ndarray:
    """Indices that put each episode's steps last-first, episodes in order.

    The regression data keeps the order of the first collector, which walked each episode
    backwards to sum its return: the minibatches, and so a seeded run, stay bit for bit the same.
    """
    ends = np.flatnonzero(episode_end)
    starts = np.concatenate(([0], ends[:-1] + 1))
    return np.concatenate([np.arange(end, start - 1, -1) for start, end in zip(starts, ends, strict=True)]
                          or [np.zeros(0, dtype=np.int64)])


def pretrain_from_orca(model: APGValue) -> list[float]:
    """Collect ``model.imitation_episodes`` ORCA episodes into the replay buffer and regress V on their returns.

    Logs ``imitation/*_rate`` and ``train/imitation_loss`` per epoch; returns the loss of each epoch.
    """
    env = model.env
    assert env is not None
    start = time.time()

    def store(obs, actions, new_obs, rewards, dones, infos) -> None:
        model._last_obs = obs
        model._store_transition(model.replay_buffer, actions.reshape(env.num_envs, -1), new_obs, rewards, dones, infos)

    demos = collect_demonstrations(env, model.imitation_episodes, mapping=model.imitation_mapping,
                                   safety_space=model.imitation_safety_space, on_step=store,
                                   keep_next_observations=False)
    for key, count in demos.outcomes.items():
        model.logger.record(f"imitation/{key}_rate", count / max(demos.episodes, 1))
    collect_time = time.time() - start
    # γ is per second at v_pref = 1: a step from state s is discounted by γ^(Δt·v_pref(s))
    exponents = model.policy.time_step * demos.observations["robot"][:, Robot.V_PREF].astype(np.float64)
    order = last_step_first(demos.episode_end)
    returns = demos.discounted_returns(model.gamma, exponents)[order]
    observations = {k: v[order] for k, v in demos.observations.items()}

    net = model.policy.value_net
    optimizer = model.imitation_optimizer_class(net.parameters(), lr=model.imitation_learning_rate,
                                                **model.imitation_optimizer_kwargs)
    generator = th.Generator().manual_seed(int(model._explore_rng.integers(2**31)))
    epochs = model.imitation_epochs

    def log_epoch(epoch: int, loss: float) -> None:
        model.logger.record("train/imitation_loss", loss)
        model.logger.record("train/imitation_epoch", epoch + 1)
        model.logger.dump(step=epoch + 1 - epochs)

    model.policy.set_training_mode(True)
    losses = pretrain_value(net, observations, returns, optimizer, epochs, model.batch_size, generator,
                            model.max_grad_norm, model.device, on_epoch=log_epoch)
    model.policy.set_training_mode(False)
    model.policy.value_net_target.load_state_dict(net.state_dict())
    if model.verbose >= 1:
        print(f"imitation: {len(returns)} states from {model.imitation_episodes} ORCA episodes in {collect_time:.0f} s, "
              f"{epochs} epochs in {time.time() - start - collect_time:.0f} s")
    return losses
