"""APGValue's imitation pre-training (paper §3): V regressed on the discounted returns of ORCA-robot episodes.

The demonstrations come from the package's one collector,
:func:`sb3_crowdnav.imitation.collect_demonstrations`; every transition also goes into APGValue's
replay buffer as it is collected (so RL starts replaying them), and the regression itself is
:func:`sb3_crowdnav.imitation.pretrain_value`. Only the algorithm's public attributes and methods are used
(``store_demonstration``, ``imitation_generator``), so this module needs no import of ``APGValue``.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from sb3_crowdnav.imitation import collect_demonstrations, pretrain_value
from sb3_crowdnav.sim.observation import Robot


def last_step_first(episode_end: np.ndarray) -> np.ndarray:
    """Indices that put each episode's steps last-first, episodes in order.

    The regression data is ordered so, and seeded runs depend on that order: their minibatches
    are drawn from it.
    """
    ends = np.flatnonzero(episode_end)
    starts = np.concatenate(([0], ends[:-1] + 1))
    return np.concatenate([np.arange(end, start - 1, -1) for start, end in zip(starts, ends, strict=True)]
                          or [np.zeros(0, dtype=np.int64)])


class Progress:
    """Progress of one imitation phase: a tqdm bar (``progress_bar``) and/or a log line every tenth (``verbose``),
    with the elapsed time and an ETA; the first line comes at once."""

    def __init__(self, total: int, what: str, verbose: int, progress_bar: bool) -> None:
        self.total, self.what, self.verbose, self.done, self.start = total, what, verbose, 0, time.time()
        self.bar = None
        if progress_bar:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, desc=f"imitation: {what}")
        elif verbose >= 1:
            print(f"imitation: {what}, 0/{total}", flush=True)

    def update(self, done: int, note: str = "") -> None:
        step, self.done = done - self.done, done
        if self.bar is not None:
            self.bar.update(step)
            return
        tenth = max(1, self.total // 10)
        if self.verbose >= 1 and (done % tenth == 0 or done == self.total):
            elapsed = time.time() - self.start
            eta = elapsed / done * (self.total - done)
            print(f"imitation: {self.what}, {done}/{self.total} ({elapsed:.0f} s, about {eta:.0f} s left){note}",
                  flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def pretrain_from_orca(model: Any, progress_bar: bool = False) -> list[float]:
    """Collect ``model.imitation_episodes`` ORCA episodes into the replay buffer of ``model`` (an ``APGValue``)
    and regress V on their returns.

    Logs ``imitation/*_rate`` and ``train/imitation_loss`` per epoch; returns the loss of each epoch. Reports its
    progress as it goes: a progress bar with ``progress_bar``, else log lines with ``verbose >= 1``.
    """
    env = model.env
    assert env is not None
    start = time.time()
    collecting = Progress(model.imitation_episodes, "ORCA-robot episodes", model.verbose, progress_bar)

    demos = collect_demonstrations(env, model.imitation_episodes, mapping=model.imitation_mapping,
                                   safety_space=model.imitation_safety_space, on_step=model.store_demonstration,
                                   keep_next_observations=False, on_episode=collecting.update)
    collecting.close()
    for key, count in demos.outcomes.items():
        model.logger.record(f"imitation/{key}_rate", count / max(demos.episodes, 1))
    collect_time = time.time() - start
    # γ is per second at v_pref = 1: a step from state s is discounted by γ^(Δt·v_pref(s))
    exponents = model.policy.world.time_step * demos.observations["robot"][:, Robot.V_PREF].astype(np.float64)
    order = last_step_first(demos.episode_end)
    returns = demos.discounted_returns(model.gamma, exponents)[order]
    observations = {k: v[order] for k, v in demos.observations.items()}

    net = model.policy.value_net
    optimizer = model.imitation_optimizer_class(net.parameters(), lr=model.imitation_learning_rate,
                                                **model.imitation_optimizer_kwargs)
    generator = model.imitation_generator()
    epochs = model.imitation_epochs

    fitting = Progress(epochs, f"fitting V on {len(returns)} states, epochs", model.verbose, progress_bar)

    def log_epoch(epoch: int, loss: float) -> None:
        model.logger.record("train/imitation_loss", loss)
        model.logger.record("train/imitation_epoch", epoch + 1)
        model.logger.dump(step=epoch + 1 - epochs)
        fitting.update(epoch + 1, f", loss {loss:.4f}")

    model.policy.set_training_mode(True)
    losses = pretrain_value(net, observations, returns, optimizer, epochs, model.batch_size, generator,
                            model.max_grad_norm, model.device, on_epoch=log_epoch)
    fitting.close()
    model.policy.set_training_mode(False)
    model.policy.value_net_target.load_state_dict(net.state_dict())
    if model.verbose >= 1:
        print(f"imitation: {len(returns)} states from {model.imitation_episodes} ORCA episodes in {collect_time:.0f} s, "
              f"{epochs} epochs in {time.time() - start - collect_time:.0f} s")
    return losses
