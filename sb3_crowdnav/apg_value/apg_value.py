"""``APGValue``: value learning with batched one-step lookahead and ORCA imitation pre-training."""

from __future__ import annotations

import copy
import dataclasses
import time
from concurrent.futures import Future, ThreadPoolExecutor
import warnings
from collections import deque
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import polyak_update, safe_mean
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecNormalize, unwrap_vec_wrapper
from torch.nn import functional as F

from sb3_crowdnav.apg_value.buffers import ValueReplayBuffer
from sb3_crowdnav.apg_value.policies import (
    OBS_KEYS,
    CadrlPolicy,
    LmPolicy,
    LstmRlPolicy,
    SarlPolicy,
    SfPolicy,
    ValueLookaheadPolicy,
    check_observation_space,
)
from sb3_crowdnav.sim.layout import Robot
from sb3_crowdnav.sim.orca import OrcaPolicy

SelfAPGValue = TypeVar("SelfAPGValue", bound="APGValue")

VALUE_TARGETS = ("td", "greedy_td", "lookahead")


@dataclasses.dataclass
class _Batch:
    """A replay batch of one gradient step; ``target`` None until computed (by the acting or the learner thread)."""

    data: Any
    target: th.Tensor | None = None
    weights: th.Tensor | None = None


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


def _check_imitation_args(learning_rate: float, optimizer_class: Any, optimizer_kwargs: dict[str, Any] | None,
                          safety_space: float, mapping: str) -> dict[str, Any]:
    """Validate the imitation arguments; return the optimiser's keyword arguments (SGD: momentum 0.9)."""
    if not (isinstance(optimizer_class, type) and issubclass(optimizer_class, th.optim.Optimizer)):
        raise TypeError(f"imitation_optimizer_class must be a torch.optim.Optimizer subclass, got {optimizer_class!r}")
    if not learning_rate > 0:
        raise ValueError(f"imitation_learning_rate must be > 0, got {learning_rate!r}")
    if not safety_space >= 0:
        raise ValueError(f"imitation_safety_space must be >= 0, got {safety_space!r}")
    if mapping not in OrcaPolicy.MAPPINGS:
        raise ValueError(f"imitation_mapping must be one of {OrcaPolicy.MAPPINGS}, got {mapping!r}")
    if optimizer_kwargs is None:
        return {"momentum": 0.9} if issubclass(optimizer_class, th.optim.SGD) else {}
    return dict(optimizer_kwargs)


class APGValue(OffPolicyAlgorithm):
    """State-value learning with one-step lookahead over the 80 actions (paper §1, §2.3, §3).

    Before RL, ``imitation_episodes`` episodes of the ORCA robot are collected; V is regressed
    on their discounted returns at ``imitation_learning_rate`` and the transitions also seed the
    replay buffer. Then TD(0) on V with uniform replay and a fixed target network,
    target ``r + γ^(Δt·v_pref) · V_target(s') · (1 - terminated)`` (timeouts bootstrap), acting
    ε-greedily per env with ε decaying linearly **by episodes**.

    :param policy: ``"ApgPolicy"`` (or another alias, or a :class:`ValueLookaheadPolicy` subclass)
    :param env: a CrowdNav env (or id), or a VecEnv of them; n_envs > 1 share one batched lookahead
    :param learning_rate: RL learning rate (Table 1: 0.001); may be a schedule
    :param buffer_size: replay capacity [transitions]
    :param learning_starts: transitions to collect (greedy lookahead, no random warm-up) before training
    :param batch_size: Table 1: 100
    :param tau: target-network update coefficient (1 = hard copy)
    :param gamma: discount per second at v_pref = 1 (Table 1: 0.9); a step is discounted by γ^(Δt·v_pref)
    :param train_freq: train every ``train_freq`` env steps (per env); 4 keeps the paper's schedule near one
        hour on 2 CPU cores (a batch-100 gradient step of the Table 2 network costs ~15 ms, a decision ~3.5 ms)
    :param gradient_steps: gradient steps per training call
    :param target_update_interval: copy V into V_target every this many env transitions
    :param exploration_initial_eps: ε at the first RL episode (0.5)
    :param exploration_final_eps: ε after ``exploration_episodes`` (0.1)
    :param exploration_episodes: RL episodes over which ε decays linearly (5,000)
    :param imitation_episodes: ORCA-robot episodes collected before RL (3,000; 0 disables imitation)
    :param imitation_learning_rate: learning rate of the imitation regression (0.01)
    :param imitation_optimizer_class: optimiser of the imitation regression (SGD, the field's code and Table 1's
        learning rate); RL uses the policy's optimiser, ``policy_kwargs["optimizer_class"]``, which APGValue sets
        to Adam unless given: with SGD (momentum 0.9, lr 0.001) V never fitted the TD targets of the states where
        every action collides, and the greedy policy turned reckless after ~500 RL episodes (README, "Training
        stability")
    :param imitation_optimizer_kwargs: its keyword arguments (SGD: ``{"momentum": 0.9}``)
    :param imitation_epochs: passes over the imitation data (the loss plateaus after a few; the field's code uses 50)
    :param imitation_safety_space: extra radius the ORCA demonstrator keeps from pedestrians [m]
    :param imitation_mapping: how the demonstrator maps ORCA's velocity to an action (see :class:`OrcaPolicy`);
        ``"constrained"`` succeeds in ~0.95 of the episodes with an invisible robot, ``"nearest"`` in ~0.3
    :param max_grad_norm: gradient clipping
    :param bootstrap_timeouts: bootstrap V_target(s') through time-limit truncations (SB3's
        ``handle_timeout_termination``, the default); False ends a timed-out episode with zero future
        value, as the field's reference code does (the state carries no clock).
    :param value_target: what V is regressed on during RL.
        ``"td"``: r + γ^(Δt·v_pref)·V_target(s')·(1 - terminated) on every stored transition (SPEC §4).
        ``"greedy_td"``: the same target, but only transitions whose action was the greedy lookahead's (or the
        demonstrator's) train V, so V estimates the greedy policy rather than the ε-greedy one.
        ``"lookahead"``: max over the 80 actions of R(s, a) + γ^(Δt·v_pref)·V(s'_a), computed when the action was
        chosen (a value-iteration backup through the propagation model, frozen in the buffer as the field's
        reference code freezes its targets); transitions without one (the demonstrations) use the TD target.
    :param torch_threads: ``torch.set_num_threads`` at construction (1 is fastest on small CPUs); None leaves it
    :param overlap_training: run each training call's gradient steps in a second thread while the envs collect the
        next ``train_freq`` steps, acting with a copy of V taken when the steps started (V is one training call
        stale when acting). Uses a second CPU core (torch ops release the GIL); the run stays deterministic, because
        every hand-over happens at a fixed point of the schedule (the next training call, a target-network update,
        ``save`` and the end of ``learn``), but it is not the same run as with ``False``. The TD targets are
        computed by whichever thread waited at the last hand-over (same numbers either way). 1.2-1.6x faster
        training on 2 cores (``benchmarks/training_speed.py --overlap``); the paper's schedule in ~66 min.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "ApgPolicy": ValueLookaheadPolicy,
        "ValueLookaheadPolicy": ValueLookaheadPolicy,
        "CadrlPolicy": CadrlPolicy,
        "SfPolicy": SfPolicy,
        "LmPolicy": LmPolicy,
        "LstmRlPolicy": LstmRlPolicy,
        "SarlPolicy": SarlPolicy,
    }
    policy: ValueLookaheadPolicy

    def __init__(
        self,
        policy: str | type[ValueLookaheadPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-3,
        buffer_size: int = 100_000,
        learning_starts: int = 0,
        batch_size: int = 100,
        tau: float = 1.0,
        gamma: float = 0.9,
        train_freq: int | tuple[int, str] = 4,
        gradient_steps: int = 1,
        target_update_interval: int = 2_000,
        exploration_initial_eps: float = 0.5,
        exploration_final_eps: float = 0.1,
        exploration_episodes: int = 5_000,
        imitation_episodes: int = 3_000,
        imitation_learning_rate: float = 0.01,
        imitation_optimizer_class: type[th.optim.Optimizer] = th.optim.SGD,
        imitation_optimizer_kwargs: dict[str, Any] | None = None,
        imitation_epochs: int = 10,
        imitation_safety_space: float = 0.0,
        imitation_mapping: str = "constrained",
        max_grad_norm: float = 10.0,
        bootstrap_timeouts: bool = True,
        value_target: str = "td",
        replay_buffer_class: type[DictReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        torch_threads: int | None = 1,
        overlap_training: bool = False,
        _init_setup_model: bool = True,
    ) -> None:
        if torch_threads is not None:
            th.set_num_threads(int(torch_threads))
        if replay_buffer_class is not None and issubclass(replay_buffer_class, HerReplayBuffer):
            raise ValueError("APGValue does not support HerReplayBuffer: CrowdNav has no goal relabelling")
        for name, value, lo, hi in (
            ("exploration_initial_eps", exploration_initial_eps, 0.0, 1.0),
            ("exploration_final_eps", exploration_final_eps, 0.0, 1.0),
            ("gamma", gamma, 1e-9, 1.0),
            ("tau", tau, 1e-9, 1.0),
        ):
            if not lo <= value <= hi:
                raise ValueError(f"{name} must be in [{lo}, {hi}], got {value!r}")
        for name, value, minimum in (
            ("exploration_episodes", exploration_episodes, 1),
            ("imitation_episodes", imitation_episodes, 0),
            ("imitation_epochs", imitation_epochs, 0),
            ("target_update_interval", target_update_interval, 1),
            ("batch_size", batch_size, 1),
        ):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
                raise ValueError(f"{name} must be an int >= {minimum}, got {value!r}")
        for name, flag in (("bootstrap_timeouts", bootstrap_timeouts), ("overlap_training", overlap_training)):
            if not isinstance(flag, bool):
                raise TypeError(f"{name} must be a bool, got {flag!r}")
        if value_target not in VALUE_TARGETS:
            raise ValueError(f"value_target must be one of {VALUE_TARGETS}, got {value_target!r}")
        if replay_buffer_class is None:
            replay_buffer_class = ValueReplayBuffer
        elif value_target != "td" and not issubclass(replay_buffer_class, ValueReplayBuffer):
            raise ValueError(
                f"value_target={value_target!r} needs a ValueReplayBuffer (it stores how each action was chosen); "
                f"got replay_buffer_class={replay_buffer_class.__name__}"
            )
        replay_buffer_kwargs = dict(replay_buffer_kwargs or {})
        replay_buffer_kwargs.setdefault("handle_timeout_termination", bootstrap_timeouts)
        policy_kwargs = dict(policy_kwargs or {})
        if "optimizer_class" not in policy_kwargs:  # RL with Adam (see imitation_optimizer_class)
            policy_kwargs.update(optimizer_class=th.optim.Adam, optimizer_kwargs=policy_kwargs.get("optimizer_kwargs", {}))
        imitation_optimizer_kwargs = _check_imitation_args(
            imitation_learning_rate, imitation_optimizer_class, imitation_optimizer_kwargs, imitation_safety_space,
            imitation_mapping)
        super().__init__(
            policy,
            env,
            learning_rate,
            buffer_size,
            learning_starts,
            batch_size,
            tau,
            gamma,
            train_freq,
            gradient_steps,
            action_noise=None,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            seed=seed,
            sde_support=False,
            supported_action_spaces=(spaces.Discrete,),
            support_multi_env=True,
        )
        check_env_compatible(self.env)
        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.exploration_episodes = exploration_episodes
        self.target_update_interval = target_update_interval
        self.imitation_episodes = imitation_episodes
        self.imitation_learning_rate = imitation_learning_rate
        self.imitation_optimizer_class = imitation_optimizer_class
        self.imitation_optimizer_kwargs = dict(imitation_optimizer_kwargs)
        self.imitation_epochs = imitation_epochs
        self.imitation_safety_space = imitation_safety_space
        self.imitation_mapping = imitation_mapping
        self.max_grad_norm = max_grad_norm
        self.bootstrap_timeouts = bootstrap_timeouts
        self.value_target = value_target
        self.overlap_training = overlap_training
        self._staged: tuple[np.ndarray, np.ndarray] | None = None
        self.exploration_rate = exploration_initial_eps
        self.imitation_done = imitation_episodes == 0
        self._n_calls = 0
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ set-up
    def _env_settings(self) -> dict[str, Any]:
        """The env's scene and reward settings that the lookahead must share (read once, at set-up)."""
        if self.env is None:
            return {}
        try:
            scene = self.env.get_attr("scene")[0]
            reward = self.env.get_attr("reward_config")[0]
        except AttributeError:
            return {}
        return {
            "time_step": scene.time_step,
            "kinematics": scene.kinematics,
            "rotation_range": scene.rotation_range,
            "reward": dataclasses.asdict(reward),
        }

    def _setup_model(self) -> None:
        check_observation_space(self.observation_space)  # here, not in __init__: load() sets the spaces later
        settings = self._env_settings()
        for key, value in settings.items():
            given = self.policy_kwargs.get(key, value)
            if given != value:
                raise ValueError(f"policy_kwargs[{key!r}] = {given!r} does not match the env's {key} = {value!r}")
            self.policy_kwargs[key] = value
        given_gamma = self.policy_kwargs.setdefault("gamma", self.gamma)
        if given_gamma != self.gamma:
            raise ValueError(f"policy_kwargs['gamma'] = {given_gamma!r} differs from the algorithm's gamma = {self.gamma!r}")
        super()._setup_model()
        self._explore_rng = np.random.default_rng(self.seed)
        self._outcomes: deque[str] = deque(maxlen=self._stats_window_size)
        self._nav_times: deque[float] = deque(maxlen=self._stats_window_size)
        self._min_seps: deque[float] = deque(maxlen=self._stats_window_size)
        self._init_learner()

    def _init_learner(self) -> None:
        """State of ``overlap_training``: the acting copy of V and the gradient steps in flight (never saved)."""
        self._acting_net: th.nn.Module | None = None
        self._learner: ThreadPoolExecutor | None = None
        self._learner_job: Future | None = None

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        super().set_env(env, force_reset)
        check_env_compatible(self.env)

    # ------------------------------------------------------------------ acting
    def _update_exploration(self) -> None:
        frac = min(1.0, self._episode_num / self.exploration_episodes)
        start, end = self.exploration_initial_eps, self.exploration_final_eps
        self.exploration_rate = start + frac * (end - start)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = False):
        """Greedy lookahead; with ``deterministic=False`` each env explores with probability ε (its own draw)."""
        if self._acting_net is not None:  # overlap_training inside learn(): V itself may be mid-update
            if deterministic:
                actions = self.policy.action_values(observation, net=self._acting_net).argmax(axis=1)
                return (actions if np.asarray(observation["robot"]).ndim == 2 else actions[0]), state
        elif deterministic:
            return self.policy.predict(observation, state, episode_start, deterministic=True)
        self._update_exploration()  # ε of the episodes finished so far, whatever the env count
        robot = np.asarray(observation["robot"])
        n = robot.shape[0] if robot.ndim == 2 else 1
        explore = self._explore_rng.random(n) < self.exploration_rate
        random_actions = self._explore_rng.integers(0, self.action_space.n, n)
        if self.value_target == "lookahead" or not explore.all():
            if self._acting_net is None:
                self.policy.set_training_mode(False)
            q = self.policy.action_values(observation, net=self._acting_net)  # (n, 80)
            greedy_actions, best = q.argmax(axis=1), q.max(axis=1)
        else:  # every env explores: skip the lookahead
            greedy_actions, best = np.full(n, -1), np.full(n, np.nan)
        actions = np.where(explore, random_actions, greedy_actions)
        self._staged = (actions == greedy_actions, best)  # read by _store_transition
        return (actions if robot.ndim == 2 else actions[0]), state

    def _store_transition(self, replay_buffer, buffer_action, new_obs, reward, dones, infos) -> None:  # type: ignore[override]
        if isinstance(replay_buffer, ValueReplayBuffer) and self._staged is not None:
            replay_buffer.stage(*self._staged)
        self._staged = None
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)

    def load_replay_buffer(self, path, truncate_last_traj: bool = True) -> None:
        """SB3's ``load_replay_buffer``; a plain ``DictReplayBuffer`` (older saves) is wrapped as a ``ValueReplayBuffer``."""
        super().load_replay_buffer(path, truncate_last_traj)
        if not isinstance(self.replay_buffer, ValueReplayBuffer) and isinstance(self.replay_buffer, DictReplayBuffer):
            self.replay_buffer = ValueReplayBuffer.from_dict_buffer(self.replay_buffer)
        self._sync_timeout_handling()

    # ------------------------------------------------------------------ learning
    def _on_step(self) -> None:
        self._n_calls += 1
        if self._n_calls % max(self.target_update_interval // self.n_envs, 1) == 0:
            self._join_learner()  # V must not be mid-update while it is copied
            polyak_update(self.policy.value_net.parameters(), self.policy.value_net_target.parameters(), self.tau)
        self._update_exploration()
        self.logger.record("rollout/exploration_rate", self.exploration_rate)

    def _td_target(self, rewards: th.Tensor, next_obs: dict[str, th.Tensor], obs: dict[str, th.Tensor],
                   dones: th.Tensor) -> th.Tensor:
        with th.no_grad():
            v_next = self.policy.values(next_obs, target=True)
            discount = self.gamma ** (self.policy.time_step * obs["robot"][:, Robot.V_PREF])
            return rewards + discount * (1.0 - dones) * v_next

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        if self._acting_net is None:
            self.policy.set_training_mode(True)
            self._update_learning_rate(self.policy.optimizer)
            self._record_losses(self._gradient_steps(self._sample_batches(gradient_steps, batch_size)))
            return
        # overlap_training: sample the next batches here (the replay buffer and its random state belong to the acting
        # thread), act with the result of the previous steps, hand the batches to the learner thread. Their targets
        # (V_target only, fixed until the next join) are computed by whichever thread waited at the last hand-over:
        # early in training most actions are ε-random and acting is cheap, late it runs a lookahead at nearly every
        # step. The numbers are the same in either thread, so this timing-based choice does not change the run.
        batches = self._sample_batches(gradient_steps, batch_size)
        learner_was_slower = self._learner_job is not None and not self._learner_job.done()
        if learner_was_slower:
            batches = [_Batch(b.data, *self._batch_target(b.data)) for b in batches]
        self._join_learner()
        self._sync_acting_net()
        self._update_learning_rate(self.policy.optimizer)
        assert self._learner is not None
        self._learner_job = self._learner.submit(self._gradient_steps, batches)

    def _sample_batches(self, gradient_steps: int, batch_size: int) -> list[_Batch]:
        """Sample the replay batches of one training call (targets not computed yet)."""
        return [_Batch(self.replay_buffer.sample(batch_size, env=self._vec_normalize_env))  # type: ignore[union-attr]
                for _ in range(gradient_steps)]

    def _batch_target(self, data: Any) -> tuple[th.Tensor, th.Tensor | None]:
        """Regression target of a sampled batch (see ``value_target``) and per-sample weights (None: all count).

        Targets only read V_target, which changes between training calls only (``_on_step`` waits for the learner
        thread before updating it), so the numbers do not depend on which thread computes them or when.
        """
        if self.value_target == "lookahead":
            target = data.lookahead_targets.flatten()
            known = th.isfinite(target)
            if not known.all():
                td = self._td_target(data.rewards.flatten(), data.next_observations, data.observations,
                                     data.dones.flatten())
                target = th.where(known, target, td)
            return target, None
        target = self._td_target(data.rewards.flatten(), data.next_observations, data.observations, data.dones.flatten())
        return target, (data.greedy.flatten() if self.value_target == "greedy_td" else None)

    def _record_losses(self, losses: list[float]) -> None:
        self._n_updates += len(losses)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))

    def _join_learner(self) -> None:
        """Wait for the gradient steps in flight (overlap_training) and log them; re-raises their exception."""
        job, self._learner_job = self._learner_job, None
        if job is not None:
            self._record_losses(job.result())

    def _sync_acting_net(self) -> None:
        assert self._acting_net is not None
        self._acting_net.load_state_dict(self.policy.value_net.state_dict())

    def _start_overlap(self) -> None:
        self.policy.set_training_mode(True)  # V only trains from here on; the acting copy only acts
        self._acting_net = copy.deepcopy(self.policy.value_net).train(False)
        if hasattr(self._acting_net.features_extractor, "bfloat16_inference"):  # bf16 acting on the copy only
            self._acting_net.features_extractor.bfloat16_inference = self.policy.lookahead_dtype == "bfloat16"
            self.policy.value_net.features_extractor.bfloat16_inference = False
        self._learner = ThreadPoolExecutor(max_workers=1, thread_name_prefix="apg-learner")

    def _stop_overlap(self) -> None:
        try:
            self._join_learner()
        finally:
            if self._learner is not None:
                self._learner.shutdown(wait=True)
            self.policy.set_lookahead_dtype(self.policy.lookahead_dtype)  # give V back its acting precision
            self._init_learner()

    def _gradient_steps(self, batches: list[_Batch]) -> list[float]:
        """One gradient step on V per sampled batch; returns the losses (the learner thread's work when overlapping)."""
        losses = []
        for batch in batches:
            data, target, weights = batch.data, batch.target, batch.weights
            if target is None:
                target, weights = self._batch_target(data)
            error = self.policy.values(data.observations) - target
            if weights is None:
                loss = error.square().mean()
            else:  # ε-drawn transitions do not train V
                loss = (weights * error.square()).sum() / weights.sum().clamp_min(1.0)
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.value_net.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
            losses.append(loss.item())
        return losses

    # ------------------------------------------------------------------ imitation
    def _collect_imitation(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Run the ORCA robot for ``imitation_episodes`` episodes; return observations and discounted returns."""
        env = self.env
        assert env is not None
        demo = OrcaPolicy(env.get_attr("scene")[0], safety_space=self.imitation_safety_space,
                          mapping=self.imitation_mapping)
        obs = env.reset()
        self._last_obs = obs
        n = env.num_envs
        pending: list[list[tuple[dict[str, np.ndarray], float]]] = [[] for _ in range(n)]
        data: dict[str, list[np.ndarray]] = {k: [] for k in OBS_KEYS}
        returns: list[float] = []
        episodes = 0
        outcomes = {"success": 0, "collision": 0, "timeout": 0}
        while episodes < self.imitation_episodes:
            actions, _ = demo.predict(obs)
            new_obs, rewards, dones, infos = env.step(actions)
            self._store_transition(self.replay_buffer, actions.reshape(n, -1), new_obs, rewards, dones, infos)  # type: ignore[arg-type]
            for i in range(n):
                pending[i].append(({k: obs[k][i] for k in OBS_KEYS}, float(rewards[i])))
                if dones[i]:
                    if episodes < self.imitation_episodes:
                        g = 0.0
                        for step_obs, r in reversed(pending[i]):
                            g = r + self.gamma ** (self.policy.time_step * float(step_obs["robot"][Robot.V_PREF])) * g
                            returns.append(g)
                            for k in OBS_KEYS:
                                data[k].append(step_obs[k])
                        episodes += 1
                        outcomes[infos[i]["outcome"]] += 1
                    pending[i] = []
            obs = new_obs
        total = max(episodes, 1)
        for key, count in outcomes.items():
            self.logger.record(f"imitation/{key}_rate", count / total)
        return {k: np.stack(v) for k, v in data.items()}, np.asarray(returns, dtype=np.float32)

    def _fit_imitation(self, obs: dict[str, np.ndarray], returns: np.ndarray, epochs: int) -> list[float]:
        """Regress V on the demonstrations' discounted returns; return the loss of each epoch."""
        net = self.policy.value_net
        optimizer = self.imitation_optimizer_class(net.parameters(), lr=self.imitation_learning_rate,
                                                   **self.imitation_optimizer_kwargs)
        tensors = {k: th.as_tensor(v, dtype=th.float32, device=self.device) for k, v in obs.items()}
        targets = th.as_tensor(returns, device=self.device)
        size = len(returns)
        gen = th.Generator().manual_seed(int(self._explore_rng.integers(2**31)))
        self.policy.set_training_mode(True)
        epoch_losses = []
        for epoch in range(epochs):
            perm = th.randperm(size, generator=gen)
            losses = []
            for begin in range(0, size, self.batch_size):
                idx = perm[begin : begin + self.batch_size]
                loss = F.mse_loss(net({k: v[idx] for k, v in tensors.items()}), targets[idx])
                optimizer.zero_grad()
                loss.backward()
                th.nn.utils.clip_grad_norm_(net.parameters(), self.max_grad_norm)
                optimizer.step()
                losses.append(loss.item())
            epoch_losses.append(float(np.mean(losses)))
            self.logger.record("train/imitation_loss", epoch_losses[-1])
            self.logger.record("train/imitation_epoch", epoch + 1)
            self.logger.dump(step=epoch + 1 - epochs)
        self.policy.set_training_mode(False)
        self.policy.value_net_target.load_state_dict(net.state_dict())
        return epoch_losses

    def _run_imitation(self) -> None:
        start = time.time()
        obs, returns = self._collect_imitation()
        collect_time = time.time() - start
        self._fit_imitation(obs, returns, self.imitation_epochs)
        self.imitation_done = True
        if self.verbose >= 1:
            print(f"imitation: {len(returns)} states from {self.imitation_episodes} ORCA episodes in {collect_time:.0f} s, "
                  f"{self.imitation_epochs} epochs in {time.time() - start - collect_time:.0f} s")

    def _sync_timeout_handling(self) -> None:
        """Make the replay buffer follow ``bootstrap_timeouts`` (it may come from a model saved with the other setting)."""
        buffer = self.replay_buffer
        if buffer is None or buffer.handle_timeout_termination == self.bootstrap_timeouts:
            return
        if not self.bootstrap_timeouts:  # stored dones include truncations: forget which ones were timeouts
            buffer.timeouts[:] = 0
            buffer.handle_timeout_termination = False
        else:
            warnings.warn("the replay buffer did not record timeouts: its old truncations stay terminal")
            buffer.handle_timeout_termination = True

    def _setup_learn(self, total_timesteps: int, callback: MaybeCallback = None, reset_num_timesteps: bool = True,
                     tb_log_name: str = "run", progress_bar: bool = False):
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        self._sync_timeout_handling()
        if not self.imitation_done:
            self._run_imitation()
            self._last_obs = self.env.reset()  # type: ignore[union-attr]
            self._last_episode_starts = np.ones((self.env.num_envs,), dtype=bool)  # type: ignore[union-attr]
        if self._acting_net is not None:  # overlap_training: act with V as imitation left it
            self._sync_acting_net()
        self._update_exploration()
        return result

    def learn(self: SelfAPGValue, total_timesteps: int, callback: MaybeCallback = None, log_interval: int = 4,
              tb_log_name: str = "APGValue", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfAPGValue:
        """Imitation pre-training (once, if not done yet), then ``total_timesteps`` RL env steps."""
        if not self.overlap_training:
            return super().learn(total_timesteps=total_timesteps, callback=callback, log_interval=log_interval,
                                 tb_log_name=tb_log_name, reset_num_timesteps=reset_num_timesteps,
                                 progress_bar=progress_bar)
        self._start_overlap()
        try:
            return super().learn(total_timesteps=total_timesteps, callback=callback, log_interval=log_interval,
                                 tb_log_name=tb_log_name, reset_num_timesteps=reset_num_timesteps,
                                 progress_bar=progress_bar)
        finally:
            self._stop_overlap()

    # ------------------------------------------------------------------ logging
    def _update_info_buffer(self, infos: list[dict[str, Any]], dones: np.ndarray | None = None) -> None:
        super()._update_info_buffer(infos, dones)
        for info in infos:
            stats = info.get("episode_stats")
            if stats is None:
                continue
            self._outcomes.append(stats["outcome"])
            self._min_seps.append(stats["min_separation"])
            if stats["outcome"] == "success":
                self._nav_times.append(stats["navigation_time"])

    def dump_logs(self) -> None:
        if self._outcomes:
            # rollout/success_rate comes from SB3 (info["is_success"])
            for outcome in ("collision", "timeout"):
                self.logger.record(f"rollout/{outcome}_rate", self._outcomes.count(outcome) / len(self._outcomes))
            if self._nav_times:
                self.logger.record("rollout/navigation_time", safe_mean(list(self._nav_times)))
            finite = [d for d in self._min_seps if np.isfinite(d)]
            if finite:
                self.logger.record("rollout/min_separation", safe_mean(finite))
        super().dump_logs()

    def save(self, path, exclude=None, include=None) -> None:
        """SB3's ``save``; the policy's current ``lookahead_dtype`` is saved with it.

        With ``overlap_training``, a save inside ``learn()`` (a checkpoint callback) first waits for the gradient
        steps in flight, so the saved V and optimiser are those of a completed step.
        """
        self._join_learner()
        if self.policy is not None and self.policy_kwargs.get("lookahead_dtype", "float32") != self.policy.lookahead_dtype:
            self.policy_kwargs["lookahead_dtype"] = self.policy.lookahead_dtype
        super().save(path, exclude, include)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_explore_rng", "_outcomes", "_nav_times", "_min_seps", "_staged",
                "_acting_net", "_learner", "_learner_job"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.optimizer"], []
