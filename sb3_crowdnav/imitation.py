"""Imitation of the ORCA robot for SB3's own algorithms (PPO, A2C, DQN).

``APGValue`` starts from 3,000 episodes of the ORCA robot (paper §3); the SB3 baselines get the
same start here, so that Table 3 compares learners, not exploration luck: with a success-only
reward, 80 actions and no lookahead, PPO and DQN from scratch rarely reach the goal at all.

- :func:`collect_demonstrations` runs :class:`~sb3_crowdnav.sim.orca.OrcaPolicy` (the
  ``"constrained"`` mapping, as ``APGValue``'s demonstrator) in a VecEnv and keeps every transition.
- :func:`pretrain_actor_critic` (PPO, A2C): behaviour cloning, maximising the log-probability of the
  demonstrator's action, plus regression of the critic on the discounted returns.
- :func:`pretrain_dqn`: the demonstrations go into the replay buffer and the Q-network takes
  gradient steps on them: 1-step Q-learning with the target network plus DQfD's large-margin loss
  ``max_a [Q(s, a) + m·1(a ≠ a_E)] - Q(s, a_E)`` (Hester et al. 2018), which keeps actions never
  demonstrated below the demonstrated one.
- :class:`DQfD`: a DQN that keeps taking gradient steps on the demonstrations during RL.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch as th
from stable_baselines3 import DQN
from torch.nn import functional as F

from sb3_crowdnav.nn.transforms import OBS_KEYS
from sb3_crowdnav.sim.orca import OrcaPolicy


@dataclass
class Demonstrations:
    """Transitions of the demonstrator, episode after episode (each episode contiguous)."""

    observations: dict[str, np.ndarray]  # (n, ...) per key
    next_observations: dict[str, np.ndarray]  # (n, ...); the terminal observation at an episode's end
    actions: np.ndarray  # (n,) int
    rewards: np.ndarray  # (n,) float32
    terminated: np.ndarray  # (n,) bool: collision or success (not a time-limit truncation)
    episode_end: np.ndarray  # (n,) bool: last transition of its episode (terminated or truncated)
    outcomes: dict[str, int]

    def __len__(self) -> int:
        return len(self.actions)

    def discounted_returns(self, gamma: float) -> np.ndarray:
        """Per-step discounted return to the end of the episode, γ per step (SB3's convention)."""
        returns = np.zeros(len(self), dtype=np.float32)
        g = 0.0
        for i in range(len(self) - 1, -1, -1):
            g = float(self.rewards[i]) + (0.0 if self.episode_end[i] else gamma * g)
            returns[i] = g
        return returns


def collect_demonstrations(env, episodes: int, mapping: str = "constrained", safety_space: float = 0.0) -> Demonstrations:
    """Run the ORCA robot in the VecEnv ``env`` until ``episodes`` episodes have finished.

    :param env: a VecEnv of CrowdNav envs (its auto-reset and ``terminal_observation`` are used)
    :param episodes: number of complete episodes to keep (>= 1)
    :param mapping: :class:`OrcaPolicy`'s velocity-to-action mapping
    :param safety_space: extra radius the demonstrator keeps from pedestrians [m]
    """
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"episodes must be an int >= 1, got {episodes!r}")
    demo = OrcaPolicy(env.get_attr("scene")[0], safety_space=safety_space, mapping=mapping)
    n = env.num_envs
    pending: list[list[tuple]] = [[] for _ in range(n)]
    kept: list[tuple] = []
    outcomes = {"success": 0, "collision": 0, "timeout": 0}
    done_episodes = 0
    obs = env.reset()
    while done_episodes < episodes:
        actions, _ = demo.predict(obs)
        new_obs, rewards, dones, infos = env.step(actions)
        for i in range(n):
            nxt = infos[i]["terminal_observation"] if dones[i] else {k: new_obs[k][i] for k in OBS_KEYS}
            truncated = bool(infos[i].get("TimeLimit.truncated", False))
            pending[i].append(({k: obs[k][i] for k in OBS_KEYS}, nxt, int(actions[i]), float(rewards[i]),
                               bool(dones[i]) and not truncated, bool(dones[i])))
            if dones[i]:
                if done_episodes < episodes:
                    kept.extend(pending[i])
                    outcomes[infos[i]["outcome"]] += 1
                    done_episodes += 1
                pending[i] = []
        obs = new_obs
    return Demonstrations(
        observations={k: np.stack([t[0][k] for t in kept]) for k in OBS_KEYS},
        next_observations={k: np.stack([t[1][k] for t in kept]) for k in OBS_KEYS},
        actions=np.array([t[2] for t in kept], dtype=np.int64),
        rewards=np.array([t[3] for t in kept], dtype=np.float32),
        terminated=np.array([t[4] for t in kept], dtype=bool),
        episode_end=np.array([t[5] for t in kept], dtype=bool),
        outcomes=outcomes,
    )


def _check_training_args(epochs: int, learning_rate: float, batch_size: int) -> None:
    for name, value in (("epochs", epochs), ("batch_size", batch_size)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be an int >= 1, got {value!r}")
    if not learning_rate > 0:
        raise ValueError(f"learning_rate must be > 0, got {learning_rate!r}")


def _tensors(obs: dict[str, np.ndarray], idx: np.ndarray, device: th.device) -> dict[str, th.Tensor]:
    return {k: th.as_tensor(v[idx], dtype=th.float32, device=device) for k, v in obs.items()}


def pretrain_actor_critic(model, demos: Demonstrations, epochs: int = 10, learning_rate: float = 1e-3,
                          batch_size: int = 256, value_coef: float = 0.5) -> list[float]:
    """Behaviour cloning of a PPO/A2C ``model``: ``-log π(a_E|s) + value_coef · (V(s) - G)²``; loss per epoch.

    Uses its own Adam optimiser (the model's optimiser state is left as it was).
    """
    from stable_baselines3.common.policies import ActorCriticPolicy

    if not isinstance(model.policy, ActorCriticPolicy):
        raise TypeError(f"pretrain_actor_critic needs an actor-critic policy (PPO, A2C), got {type(model.policy).__name__}")
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
    """Q-learning + large-margin loss on the demonstrations for a DQN ``model``; loss per epoch.

    With ``fill_buffer`` the demonstrations are also added to the model's replay buffer (single-env
    DQN only), so that online learning keeps replaying them until they are overwritten.
    """
    if not isinstance(model, DQN):
        raise TypeError(f"pretrain_dqn needs a DQN model, got {type(model).__name__}")
    _check_training_args(epochs, learning_rate, batch_size)
    if not margin >= 0:
        raise ValueError(f"margin must be >= 0, got {margin!r}")
    if fill_buffer:
        buffer = model.replay_buffer
        if buffer.n_envs != 1:
            raise ValueError(f"fill_buffer needs a single-env DQN (its replay buffer has n_envs={buffer.n_envs})")
        for i in range(len(demos)):
            buffer.add({k: v[i : i + 1] for k, v in demos.observations.items()},
                       {k: v[i : i + 1] for k, v in demos.next_observations.items()},
                       demos.actions[i : i + 1, None], demos.rewards[i : i + 1], demos.terminated[i : i + 1],
                       [{}])
    q_net, q_target = model.q_net, model.q_net_target
    q_target.load_state_dict(q_net.state_dict())
    optimizer = th.optim.Adam(q_net.parameters(), lr=learning_rate)
    tensors = _DemoTensors(demos, model.device)
    rng = np.random.default_rng(model.seed)
    q_net.train(True)
    losses, step = [], 0
    for _ in range(epochs):
        perm = rng.permutation(len(demos))
        epoch = []
        for begin in range(0, len(demos), batch_size):
            loss = _dqfd_loss(model, demos, tensors, perm[begin : begin + batch_size], margin, margin_coef)
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


class _DemoTensors:
    """Actions, rewards and continuation flags of the demonstrations as tensors (observations stay numpy)."""

    def __init__(self, demos: Demonstrations, device: th.device) -> None:
        self.actions = th.as_tensor(demos.actions, device=device)
        self.rewards = th.as_tensor(demos.rewards, device=device)
        self.not_done = th.as_tensor(~demos.terminated, dtype=th.float32, device=device)


def _dqfd_loss(model, demos: Demonstrations, tensors: _DemoTensors, idx: np.ndarray, margin: float,
               margin_coef: float) -> th.Tensor:
    """Huber 1-step TD loss (target network) + ``margin_coef`` x large-margin loss on the demonstrations ``idx``."""
    q = model.q_net(_tensors(demos.observations, idx, model.device))  # (b, 80)
    actions = tensors.actions[idx, None]
    with th.no_grad():
        q_next = model.q_net_target(_tensors(demos.next_observations, idx, model.device)).max(dim=1).values
        target = tensors.rewards[idx] + model.gamma * tensors.not_done[idx] * q_next
    q_demo = q.gather(1, actions).squeeze(1)
    margins = th.full_like(q, margin).scatter_(1, actions, 0.0)
    large_margin = ((q + margins).max(dim=1).values - q_demo).mean()
    return F.smooth_l1_loss(q_demo, target) + margin_coef * large_margin


class DQfD(DQN):
    """SB3 ``DQN`` that keeps learning from its demonstrations (DQfD, Hester et al. 2018).

    After each of DQN's gradient steps on its replay buffer, one more step on ``demo_batch_size``
    demonstration transitions: their 1-step TD loss plus ``margin_coef`` x the large-margin loss
    ``max_a [Q(s, a) + margin·1(a ≠ a_E)] - Q(s, a_E)``. Plain DQN started from the same
    pre-training drifted to wandering (98 % timeouts after 40 k steps, README); the supervised term keeps
    the greedy policy anchored to the demonstrator while Q-learning improves on it.

    Give the demonstrations with :meth:`set_demonstrations` (``sb3-crowdnav train --algo dqfd
    --imitation-episodes N`` does it after :func:`pretrain_dqn`). They are not saved with the model
    (hundreds of MB); the file loads with ``DQN.load`` (and ``DQfD.load``, which continues as plain
    DQN until demonstrations are set again).

    :param demo_batch_size: demonstration transitions per extra gradient step
    :param margin: the large margin m
    :param margin_coef: weight of the large-margin loss
    """

    def __init__(self, *args, demo_batch_size: int = 64, margin: float = 0.1, margin_coef: float = 1.0, **kwargs) -> None:
        if isinstance(demo_batch_size, bool) or not isinstance(demo_batch_size, (int, np.integer)) or demo_batch_size < 1:
            raise ValueError(f"demo_batch_size must be an int >= 1, got {demo_batch_size!r}")
        for name, value in (("margin", margin), ("margin_coef", margin_coef)):
            if not value >= 0:
                raise ValueError(f"{name} must be >= 0, got {value!r}")
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
        self.demonstrations = demos
        self._demo_tensors = None if demos is None else _DemoTensors(demos, self.device)
        self._demo_rng = np.random.default_rng(self.seed)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        super().train(gradient_steps, batch_size)
        demos = self.demonstrations
        if demos is None:
            return
        losses = []
        for _ in range(gradient_steps):
            idx = self._demo_rng.integers(0, len(demos), self.demo_batch_size)
            loss = _dqfd_loss(self, demos, self._demo_tensors, idx, self.margin, self.margin_coef)
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
            losses.append(loss.item())
        self.logger.record("train/demo_loss", float(np.mean(losses)))

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "demonstrations", "_demo_tensors", "_demo_rng"]


__all__ = ["DQfD", "Demonstrations", "collect_demonstrations", "pretrain_actor_critic", "pretrain_dqn"]
