"""Pre-training on ORCA demonstrations: behaviour cloning (PPO, A2C, MaskablePPO), DQfD-style Q-learning (DQN, QR-DQN),
value regression."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch as th
from sb3_contrib import QRDQN
from sb3_contrib.common.utils import quantile_huber_loss
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer
from torch.nn import functional as F

from sb3_crowdnav.imitation.demonstrations import Demonstrations
from sb3_crowdnav.sim.validation import check_int, check_number, check_positive


def _check_training_args(epochs: int, learning_rate: float, batch_size: int) -> None:
    check_int("epochs", epochs, 1)
    check_int("batch_size", batch_size, 1)
    check_positive("learning_rate", learning_rate)


def _tensors(obs: dict[str, np.ndarray], idx: np.ndarray, device: th.device) -> dict[str, th.Tensor]:
    return {k: th.as_tensor(v[idx], dtype=th.float32, device=device) for k, v in obs.items()}


def pretrain_actor_critic(model, demos: Demonstrations, epochs: int = 10, learning_rate: float = 1e-3,
                          batch_size: int = 256, value_coef: float = 0.5) -> list[float]:
    """Behaviour cloning of a PPO/A2C/MaskablePPO ``model``: ``-log π(a_E|s) + value_coef · (V(s) - G)²``; loss per
    epoch.

    Uses its own Adam optimiser (the model's optimiser state is left as it was). MaskablePPO's policy is cloned without
    its action masks: at acting time the masks renormalise the cloned distribution over the allowed actions, while a
    demonstrated action that a mask forbids (the ORCA robot does drive into racks) would have a masked log-probability
    of about -1e8 and swamp the loss.
    """
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
    from stable_baselines3.common.policies import ActorCriticPolicy

    if not isinstance(model.policy, ActorCriticPolicy | MaskableActorCriticPolicy):
        raise TypeError(f"pretrain_actor_critic needs an actor-critic policy (PPO, A2C, MaskablePPO), got "
                        f"{type(model.policy).__name__}")
    _check_training_args(epochs, learning_rate, batch_size)
    policy = model.policy
    returns = th.as_tensor(demos.discounted_returns(model.gamma), device=model.device)
    actions = th.as_tensor(demos.actions, device=model.device)
    optimizer = th.optim.Adam(policy.parameters(), lr=learning_rate)
    rng = np.random.default_rng(model.seed)
    policy.set_training_mode(True)
    losses = []
    for _ in range(epochs):
        perm = rng.permutation(len(demos))
        epoch = []
        for begin in range(0, len(demos), batch_size):
            idx = perm[begin : begin + batch_size]
            values, log_prob, _ = policy.evaluate_actions(_tensors(demos.observations, idx, model.device), actions[idx])
            loss = -log_prob.mean() + value_coef * F.mse_loss(values.flatten(), returns[idx])
            optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(policy.parameters(), 10.0)
            optimizer.step()
            epoch.append(loss.item())
        losses.append(float(np.mean(epoch)))
    policy.set_training_mode(False)
    return losses


def pretrain_dqn(model, demos: Demonstrations, epochs: int = 10, learning_rate: float = 1e-3, batch_size: int = 256,
                 margin: float = 0.1, margin_coef: float = 1.0, target_update: int = 500,
                 fill_buffer: bool = True) -> list[float]:
    """Q-learning + large-margin loss on the demonstrations for a DQN or a QR-DQN ``model``; loss per epoch.

    DQN: :func:`dqfd_loss`; QR-DQN: :func:`quantile_dqfd_loss`, the same with sb3-contrib's quantile regression as the
    TD part and the margin on the mean over the quantiles (the Q-values QR-DQN acts on).

    With ``fill_buffer`` the demonstrations are also added to the model's replay buffer (single-env
    models only; :func:`add_to_replay_buffer`), so that online learning keeps replaying them until they are overwritten,
    with the model's own targets (n-step ones with :class:`~sb3_crowdnav.nn.NStepDictReplayBuffer`). The loss here
    is one-step whatever the buffer's targets: a valid Bellman target of the same Q.
    """
    q_net, q_target, loss_of = _q_learning(model)
    _check_training_args(epochs, learning_rate, batch_size)
    check_number("margin", margin, allow_zero=True)
    if demos.next_observations is None:
        raise ValueError("pretrain_dqn needs next observations: collect with keep_next_observations=True")
    if fill_buffer:
        add_to_replay_buffer(model.replay_buffer, demos)
    q_target.load_state_dict(q_net.state_dict())
    optimizer = th.optim.Adam(q_net.parameters(), lr=learning_rate)
    tensors = DemoTensors(demos, model.device)
    rng = np.random.default_rng(model.seed)
    q_net.train(True)
    losses, step = [], 0
    for _ in range(epochs):
        perm = rng.permutation(len(demos))
        epoch = []
        for begin in range(0, len(demos), batch_size):
            loss = loss_of(model, demos, tensors, perm[begin : begin + batch_size], margin, margin_coef)
            optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(q_net.parameters(), 10.0)
            optimizer.step()
            epoch.append(loss.item())
            step += 1
            if step % target_update == 0:
                q_target.load_state_dict(q_net.state_dict())
        losses.append(float(np.mean(epoch)))
    q_target.load_state_dict(q_net.state_dict())
    q_net.train(False)
    return losses


def add_to_replay_buffer(buffer: ReplayBuffer, demos: Demonstrations) -> None:
    """Add the demonstrations to a single-env replay buffer as SB3 adds a VecEnv's steps.

    An episode's last transition is ``done`` and, when the time limit ended it, ``TimeLimit.truncated``: a one-step
    target bootstraps there as before, and an n-step one (:class:`~sb3_crowdnav.nn.NStepDictReplayBuffer`) stops
    there instead of summing into the next episode.
    """
    if buffer.n_envs != 1:
        raise ValueError(f"demonstrations go into a single-env replay buffer (this one has n_envs={buffer.n_envs})")
    if demos.next_observations is None:
        raise ValueError("the replay buffer needs next observations: collect with keep_next_observations=True")
    truncated = demos.episode_end & ~demos.terminated
    for i in range(len(demos)):
        buffer.add({k: v[i : i + 1] for k, v in demos.observations.items()},
                   {k: v[i : i + 1] for k, v in demos.next_observations.items()},
                   demos.actions[i : i + 1, None], demos.rewards[i : i + 1], demos.episode_end[i : i + 1],
                   [{"TimeLimit.truncated": bool(truncated[i])}])


class DemoTensors:
    """Actions, rewards and continuation flags of the demonstrations as tensors (observations stay numpy)."""

    def __init__(self, demos: Demonstrations, device: th.device) -> None:
        self.actions = th.as_tensor(demos.actions, device=device)
        self.rewards = th.as_tensor(demos.rewards, device=device)
        self.not_done = th.as_tensor(~demos.terminated, dtype=th.float32, device=device)


def _q_learning(model) -> tuple[th.nn.Module, th.nn.Module, Callable[..., th.Tensor]]:
    """The online and target networks of a DQN (``q_net``) or a QR-DQN (``quantile_net``) model and its loss."""
    if isinstance(model, DQN):
        return model.q_net, model.q_net_target, dqfd_loss
    if isinstance(model, QRDQN):
        return model.quantile_net, model.quantile_net_target, quantile_dqfd_loss
    raise TypeError(f"pretrain_dqn needs a DQN or QR-DQN model, got {type(model).__name__}")


def _large_margin(q: th.Tensor, actions: th.Tensor, margin: float) -> th.Tensor:
    """``max_a [Q(s, a) + margin·1(a ≠ a_E)] - Q(s, a_E)``, averaged: ``q`` (b, n_actions), ``actions`` (b, 1)."""
    margins = th.full_like(q, margin).scatter_(1, actions, 0.0)
    return ((q + margins).max(dim=1).values - q.gather(1, actions).squeeze(1)).mean()


def dqfd_loss(model, demos: Demonstrations, tensors: DemoTensors, idx: np.ndarray, margin: float,
              margin_coef: float) -> th.Tensor:
    """Huber 1-step TD loss (target network) + ``margin_coef`` x large-margin loss on the demonstrations ``idx``."""
    q = model.q_net(_tensors(demos.observations, idx, model.device))  # (b, 80)
    actions = tensors.actions[idx, None]
    with th.no_grad():
        q_next = model.q_net_target(_tensors(demos.next_observations, idx, model.device)).max(dim=1).values
        target = tensors.rewards[idx] + model.gamma * tensors.not_done[idx] * q_next
    q_demo = q.gather(1, actions).squeeze(1)
    return F.smooth_l1_loss(q_demo, target) + margin_coef * _large_margin(q, actions, margin)


def quantile_dqfd_loss(model, demos: Demonstrations, tensors: DemoTensors, idx: np.ndarray, margin: float,
                       margin_coef: float) -> th.Tensor:
    """:func:`dqfd_loss` of a QR-DQN ``model`` on the demonstrations ``idx``: sb3-contrib's quantile Huber 1-step TD
    loss (target network; the next action greedy on the mean over the quantiles, as ``QRDQN.train``) + ``margin_coef``
    x the large-margin loss on Q, the mean over the quantiles."""
    quantiles = model.quantile_net(_tensors(demos.observations, idx, model.device))  # (b, n_quantiles, n_actions)
    b, n = quantiles.shape[:2]
    actions = tensors.actions[idx, None]
    with th.no_grad():
        following = model.quantile_net_target(_tensors(demos.next_observations, idx, model.device))
        greedy = following.mean(dim=1, keepdim=True).argmax(dim=2, keepdim=True).expand(b, n, 1)
        following = following.gather(2, greedy).squeeze(2)
        target = tensors.rewards[idx, None] + model.gamma * tensors.not_done[idx, None] * following
    demonstrated = quantiles.gather(2, actions[:, :, None].expand(b, n, 1)).squeeze(2)
    return (quantile_huber_loss(demonstrated, target, sum_over_quantiles=True)
            + margin_coef * _large_margin(quantiles.mean(dim=1), actions, margin))


def pretrain_value(net: th.nn.Module, observations: dict[str, np.ndarray], targets: np.ndarray,
                   optimizer: th.optim.Optimizer, epochs: int, batch_size: int, generator: th.Generator,
                   max_grad_norm: float, device: th.device | str = "cpu",
                   on_epoch: Callable[[int, float], None] | None = None) -> list[float]:
    """Regress a state-value network ``net`` (observations -> (batch,) values) on ``targets``; the loss of each epoch.

    Minibatches of ``batch_size`` in the order of ``th.randperm(generator)`` each epoch; gradients clipped to
    ``max_grad_norm``; ``on_epoch(epoch, loss)`` after each epoch (APGValue logs there).
    """
    tensors = {k: th.as_tensor(v, dtype=th.float32, device=device) for k, v in observations.items()}
    target = th.as_tensor(targets, device=device)
    size = len(targets)
    epoch_losses = []
    for epoch in range(epochs):
        perm = th.randperm(size, generator=generator)
        losses = []
        for begin in range(0, size, batch_size):
            idx = perm[begin : begin + batch_size]
            loss = F.mse_loss(net({k: v[idx] for k, v in tensors.items()}), target[idx])
            optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(net.parameters(), max_grad_norm)
            optimizer.step()
            losses.append(loss.item())
        epoch_losses.append(float(np.mean(losses)))
        if on_epoch is not None:
            on_epoch(epoch, epoch_losses[-1])
    return epoch_losses
