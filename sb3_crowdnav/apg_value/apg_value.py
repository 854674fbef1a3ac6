"""``APGValue``: value learning with batched one-step lookahead and ORCA imitation pre-training."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_crowdnav.apg_value import checks
from sb3_crowdnav.apg_value.buffers import ValueReplayBuffer, follow_timeout_handling, is_npz, load_buffer, save_buffer
from sb3_crowdnav.apg_value.learner import Batch, Learner, ValueLearner
from sb3_crowdnav.apg_value.overlap import make_learner
from sb3_crowdnav.apg_value.policies import LOOKAHEAD_SETTINGS, POLICY_ALIASES, ValueLookaheadPolicy
from sb3_crowdnav.apg_value.pretraining import pretrain_from_orca
from sb3_crowdnav.apg_value.rollout_stats import RolloutStats
from sb3_crowdnav.serialization import UnsafeModelFileError, safe_custom_objects, write_spaces
from sb3_crowdnav.sim.observation import ObservationSchema
from sb3_crowdnav.sim.orca import OrcaPolicy

SelfAPGValue = TypeVar("SelfAPGValue", bound="APGValue")


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
    :param train_freq: train every ``train_freq`` env steps (per env); 4 (the paper's schedule) also keeps the
        gradient steps' share of a 2-core training run small next to the lookahead decisions
    :param gradient_steps: gradient steps per training call
    :param target_update_interval: copy V into V_target every this many env transitions
    :param exploration_initial_eps: ε at the first RL episode (0.5)
    :param exploration_final_eps: ε after ``exploration_episodes`` (0.1)
    :param exploration_episodes: RL episodes over which ε decays linearly (5,000)
    :param imitation_episodes: ORCA-robot episodes collected before RL (3,000; 0 disables imitation)
    :param imitation_learning_rate: learning rate of the imitation regression (0.01)
    :param imitation_optimizer_class: optimiser of the imitation regression (SGD, as the field's code). RL uses
        ``policy_kwargs["optimizer_class"]``, Adam unless given: with SGD, V does not fit the TD targets of the
        states where every action collides, and the greedy policy turns reckless
    :param imitation_optimizer_kwargs: its keyword arguments (SGD: ``{"momentum": 0.9}``)
    :param imitation_epochs: passes over the imitation data (the loss plateaus after a few; the field's code uses 50)
    :param imitation_safety_space: extra radius the ORCA demonstrator keeps from pedestrians [m]
    :param imitation_mapping: how the demonstrator maps ORCA's velocity to an action (see :class:`OrcaPolicy`);
        ``"constrained"`` reaches the goal far more often than ``"nearest"`` when the pedestrians do not see the robot
    :param max_grad_norm: gradient clipping
    :param bootstrap_timeouts: bootstrap V_target(s') through time-limit truncations (SB3's
        ``handle_timeout_termination``, the default); False ends a timed-out episode with zero future
        value, as the field's reference code does (the state carries no clock).
    :param value_target: what V is regressed on during RL.
        ``"td"``: r + γ^(Δt·v_pref)·V_target(s')·(1 - terminated) on every stored transition (paper §2.3).
        ``"greedy_td"``: the same target, but only transitions whose action was the greedy lookahead's (or the
        demonstrator's) train V, so V estimates the greedy policy rather than the ε-greedy one.
        ``"lookahead"``: max over the 80 actions of R(s, a) + γ^(Δt·v_pref)·V(s'_a), computed when the action was
        chosen (a value-iteration backup through the propagation model, frozen in the buffer as the field's
        reference code freezes its targets); transitions without one (the demonstrations) use the TD target.
    :param overlap_training: run each training call's gradient steps on the second core while the envs collect the
        next ``train_freq`` steps, acting with a copy of V one training call stale (:mod:`.overlap`): ``"thread"``
        (a learner thread), ``"process"`` (a learner process, weights handed over through shared memory), ``True``
        (= ``"thread"``) or ``False`` (the steps run in ``learn()`` itself). Deterministic, the same run with either
        learner, but not the same run as with ``False``; faster on two or more cores.

    The algorithm never changes process-wide settings: set torch's thread count where the process starts
    (``sb3_crowdnav.nn.configure_cpu(1)``: one thread is fastest for these small networks on shared CPUs), as
    the ``sb3-crowdnav`` command line and :func:`~sb3_crowdnav.training.train_schedule` do.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = dict(POLICY_ALIASES)
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
        overlap_training: bool | str = False,
        _init_setup_model: bool = True,
    ) -> None:
        checks.check_policy_name(policy, self.policy_aliases)
        checks.check_args(exploration_initial_eps=exploration_initial_eps, exploration_final_eps=exploration_final_eps,
                   gamma=gamma, tau=tau, exploration_episodes=exploration_episodes,
                   imitation_episodes=imitation_episodes, imitation_epochs=imitation_epochs,
                   target_update_interval=target_update_interval, batch_size=batch_size,
                   bootstrap_timeouts=bootstrap_timeouts, overlap_training=overlap_training, value_target=value_target)
        replay_buffer_class = checks.check_replay_buffer_class(replay_buffer_class, value_target)
        replay_buffer_kwargs = dict(replay_buffer_kwargs or {})
        replay_buffer_kwargs.setdefault("handle_timeout_termination", bootstrap_timeouts)
        policy_kwargs = dict(policy_kwargs or {})
        if "optimizer_class" not in policy_kwargs:  # RL with Adam (see imitation_optimizer_class); its multi-tensor
            # step (foreach) gives the same numbers as the per-parameter loop in fewer kernel calls
            policy_kwargs.update(optimizer_class=th.optim.Adam,
                                 optimizer_kwargs={"foreach": True, **policy_kwargs.get("optimizer_kwargs", {})})
        imitation_optimizer_kwargs = checks.check_imitation_args(
            imitation_learning_rate, imitation_optimizer_class, imitation_optimizer_kwargs, imitation_safety_space,
            imitation_mapping, OrcaPolicy.MAPPINGS)
        super().__init__(
            policy, env, learning_rate, buffer_size, learning_starts, batch_size, tau, gamma, train_freq,
            gradient_steps, action_noise=None, replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs, policy_kwargs=policy_kwargs, stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log, verbose=verbose, device=device, seed=seed, sde_support=False,
            supported_action_spaces=(spaces.Discrete,), support_multi_env=True,
        )
        checks.check_env_compatible(self.env)
        self.exploration_initial_eps, self.exploration_final_eps = exploration_initial_eps, exploration_final_eps
        self.exploration_episodes, self.target_update_interval = exploration_episodes, target_update_interval
        self.imitation_episodes, self.imitation_epochs = imitation_episodes, imitation_epochs
        self.imitation_learning_rate, self.imitation_optimizer_class = imitation_learning_rate, imitation_optimizer_class
        self.imitation_optimizer_kwargs = dict(imitation_optimizer_kwargs)
        self.imitation_safety_space, self.imitation_mapping = imitation_safety_space, imitation_mapping
        self.max_grad_norm, self.bootstrap_timeouts = max_grad_norm, bootstrap_timeouts
        self.value_target, self.overlap_training = value_target, overlap_training
        self._staged: tuple[np.ndarray, np.ndarray] | None = None
        self.exploration_rate = exploration_initial_eps
        self.imitation_done = imitation_episodes == 0
        self._n_calls = 0
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ set-up
    def _setup_model(self) -> None:
        ObservationSchema.from_space(self.observation_space)  # here, not in __init__: load() sets the spaces later
        self.policy_kwargs = checks.with_env_world(self.policy_kwargs, self.env)  # upgrades older files' entries
        given_gamma = self.policy_kwargs.setdefault("gamma", self.gamma)
        if given_gamma != self.gamma:
            raise ValueError(f"policy_kwargs['gamma'] = {given_gamma!r} differs from the algorithm's gamma = {self.gamma!r}")
        super()._setup_model()  # seeds the ε draws too (set_random_seed)
        self._rollout_stats = RolloutStats(self._stats_window_size)
        # where the gradient steps run (overlap_training); rebuilt by each learn(), never saved
        self.learner: Learner = make_learner(self.overlap_kind, self._value_learner)

    def set_random_seed(self, seed: int | None = None) -> None:
        super().set_random_seed(seed)
        self._explore_rng = np.random.default_rng(seed)  # the ε draws of predict(deterministic=False)

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        super().set_env(env, force_reset)
        checks.check_env_compatible(self.env)

    # ------------------------------------------------------------------ acting
    def _update_exploration(self) -> None:  # by episodes (the paper), not SB3's get_linear_fn of the steps left
        frac = min(1.0, self._episode_num / self.exploration_episodes)
        start, end = self.exploration_initial_eps, self.exploration_final_eps
        self.exploration_rate = start + frac * (end - start)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = False):
        """Greedy lookahead; with ``deterministic=False`` each env explores with probability ε (its own draw)."""
        if not isinstance(observation, dict):  # the policy's refusal names the mistake (an (obs, info) tuple)
            return self.policy.predict(observation, state, episode_start, deterministic)
        net = self.learner.acting_net()  # inside learn() with overlap_training, V itself may be mid-update
        robot = np.asarray(observation["robot"])
        if deterministic:
            actions = self.policy.action_values(observation, net=net).argmax(axis=1)
            return (actions if robot.ndim == 2 else actions[0]), state
        self._update_exploration()  # ε of the episodes finished so far, whatever the env count
        n = robot.shape[0] if robot.ndim == 2 else 1
        explore = self._explore_rng.random(n) < self.exploration_rate
        random_actions = self._explore_rng.integers(0, self.action_space.n, n)
        if self.value_target == "lookahead" or not explore.all():
            q = self.policy.action_values(observation, net=net)  # (n, 80)
            greedy_actions, best = q.argmax(axis=1), q.max(axis=1)
        else:  # every env explores: skip the lookahead
            greedy_actions, best = np.full(n, -1), np.full(n, np.nan)
        actions = np.where(explore, random_actions, greedy_actions)
        self._staged = (actions == greedy_actions, best)  # read by _store_transition
        return (actions if robot.ndim == 2 else actions[0]), state

    def _sample_action(self, learning_starts: int, action_noise=None, n_envs: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """ε-greedy lookahead from the first step: SB3 draws uniform actions before ``learning_starts``, which
        would fill a warm-up (or a refill after a resume without the buffer) with crashes."""
        assert self._last_obs is not None, "self._last_obs was not set"
        actions, _ = self.predict(self._last_obs, deterministic=False)
        actions = np.asarray(actions).reshape(n_envs)
        return actions, actions

    def _store_transition(self, replay_buffer, buffer_action, new_obs, reward, dones, infos) -> None:  # type: ignore[override]
        if isinstance(replay_buffer, ValueReplayBuffer) and self._staged is not None:
            replay_buffer.stage(*self._staged)
        self._staged = None
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)

    def store_demonstration(self, obs, actions, new_obs, rewards, dones, infos) -> None:
        """Add one VecEnv step of a demonstrator to the replay buffer, as ``learn()`` adds its own steps (the
        ``on_step`` of :func:`~sb3_crowdnav.imitation.collect_demonstrations`; VecEnv arrays of all envs)."""
        self._last_obs = obs
        self._store_transition(self.replay_buffer, np.asarray(actions).reshape(self.n_envs, -1), new_obs, rewards,
                               dones, infos)

    def imitation_generator(self) -> th.Generator:
        """A torch generator for the imitation regression's minibatch order, seeded by a draw of the algorithm's
        seeded random state (the same seed, the same order)."""
        return th.Generator().manual_seed(int(self._explore_rng.integers(2**31)))

    @property
    def episodes_done(self) -> int:
        """RL episodes finished so far (over all envs; a resumed model counts on from its file)."""
        return self._episode_num

    def save_replay_buffer(self, path) -> None:
        """The replay buffer as an ``.npz`` of plain arrays (:func:`~.buffers.save_buffer`), not SB3's pickle."""
        save_buffer(self.replay_buffer, path)  # type: ignore[arg-type]

    def load_replay_buffer(self, path, truncate_last_traj: bool = True, trusted: bool = False) -> None:
        """Fill the replay buffer from :meth:`save_replay_buffer`'s ``.npz``. A pickled buffer (``.pkl``, saved by
        SB3 or older versions) loads only with ``trusted=True``; a plain ``DictReplayBuffer`` is wrapped."""
        if not is_npz(path):  # told apart by content: SB3's CheckpointCallback names our .npz buffers ".pkl"
            if not trusted:
                raise UnsafeModelFileError(f"{path} is a pickle: load it with trusted=True only if you made it")
            super().load_replay_buffer(path, truncate_last_traj)
            if not isinstance(self.replay_buffer, ValueReplayBuffer) and isinstance(self.replay_buffer, DictReplayBuffer):
                self.replay_buffer = ValueReplayBuffer.from_dict_buffer(self.replay_buffer)
        else:
            load_buffer(self.replay_buffer, path)  # type: ignore[arg-type]
        follow_timeout_handling(self.replay_buffer, self.bootstrap_timeouts)

    # ------------------------------------------------------------------ learning
    def _on_step(self) -> None:
        self._n_calls += 1
        if self._n_calls % max(self.target_update_interval // self.n_envs, 1) == 0:
            self._join_learner()  # V must not be mid-update while it is copied
            self.learner.update_target(self.tau)
        self._update_exploration()
        self.logger.record("rollout/exploration_rate", self.exploration_rate)

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        # the replay buffer and its random state belong to the acting loop: the batches are sampled here, and the
        # learner applies the learning rate once the optimiser is no longer stepping the previous call
        batches = self._sample_batches(gradient_steps, batch_size)
        learning_rate = self.lr_schedule(self._current_progress_remaining)
        self.logger.record("train/learning_rate", learning_rate)
        self._record_losses(self.learner.submit(batches, learning_rate))

    def _sample_batches(self, gradient_steps: int, batch_size: int) -> list[Batch]:
        """Sample the replay batches of one training call (targets not computed yet)."""
        return [Batch(self.replay_buffer.sample(batch_size, env=self._vec_normalize_env))  # type: ignore[union-attr]
                for _ in range(gradient_steps)]

    def _record_losses(self, losses: list[float] | None) -> None:
        if losses is None:  # no training call finished at this hand-over
            return
        self._n_updates += len(losses)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))

    def _join_learner(self) -> None:
        """Wait for the training call in flight (overlap_training) and log it; re-raises its exception."""
        self._record_losses(self.learner.join())

    @property
    def overlap_kind(self) -> str | None:
        """``"thread"``, ``"process"`` or None: where ``overlap_training`` runs the gradient steps."""
        if self.overlap_training is False:
            return None
        return "thread" if self.overlap_training is True else self.overlap_training

    def _value_learner(self) -> ValueLearner:
        return ValueLearner(self.policy, self.gamma, self.value_target, self.max_grad_norm)

    def _setup_learn(self, total_timesteps: int, callback: MaybeCallback = None, reset_num_timesteps: bool = True,
                     tb_log_name: str = "run", progress_bar: bool = False):
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        follow_timeout_handling(self.replay_buffer, self.bootstrap_timeouts)
        if not self.imitation_done:
            pretrain_from_orca(self, progress_bar)
            self.imitation_done = True
            self.start_time = time.time_ns()  # SB3's fps and time_elapsed count RL only
            self._last_obs = self.env.reset()  # type: ignore[union-attr]
            self._last_episode_starts = np.ones((self.env.num_envs,), dtype=bool)  # type: ignore[union-attr]
        self.learner = make_learner(self.overlap_kind, self._value_learner)  # overlap_training may have changed
        self.learner.start()  # an overlapping learner acts with V as imitation left it
        self._update_exploration()
        return result

    def learn(self: SelfAPGValue, total_timesteps: int, callback: MaybeCallback = None, log_interval: int = 4,
              tb_log_name: str = "APGValue", reset_num_timesteps: bool = True, progress_bar: bool = False) -> SelfAPGValue:
        """Imitation pre-training (once, if not done yet), then ``total_timesteps`` RL env steps."""
        try:
            return super().learn(total_timesteps=total_timesteps, callback=callback, log_interval=log_interval,
                                 tb_log_name=tb_log_name, reset_num_timesteps=reset_num_timesteps,
                                 progress_bar=progress_bar)
        finally:
            try:
                self._join_learner()
                self.learner.pull_optimizer()
            finally:
                self.learner.stop()

    # ------------------------------------------------------------------ logging
    def _update_info_buffer(self, infos: list[dict[str, Any]], dones: np.ndarray | None = None) -> None:
        super()._update_info_buffer(infos, dones)
        self._rollout_stats.update(infos)  # the crowd's rollout/* scalars

    def dump_logs(self) -> None:
        self._rollout_stats.record(self.logger)  # then SB3's own
        super().dump_logs()

    def save(self, path, exclude=None, include=None) -> None:
        """SB3's ``save`` with the policy's current lookahead settings (:data:`LOOKAHEAD_SETTINGS`: its dtype,
        pedestrian model, stopping check and planning depth), and the spaces as plain JSON; inside ``learn()`` with
        ``overlap_training`` it first waits for the gradient steps in flight (the V of a completed step is saved)."""
        self._join_learner()
        self.learner.pull_optimizer()  # the learner process's optimiser state is saved with V
        for key, default in LOOKAHEAD_SETTINGS.items():  # a setting at its default is written only once changed
            if self.policy is not None and self.policy_kwargs.get(key, default) != getattr(self.policy, key):
                self.policy_kwargs[key] = getattr(self.policy, key)
        super().save(path, exclude, include)
        if isinstance(path, (str, Path)):  # so that loading never unpickles them
            write_spaces(path if str(path).endswith(".zip") else f"{path}.zip", self.observation_space, self.action_space)

    @classmethod
    def load(cls: type[SelfAPGValue], path, env: GymEnv | None = None, device: th.device | str = "auto",
             custom_objects: dict[str, Any] | None = None, print_system_info: bool = False, force_reset: bool = True,
             trusted: bool = False, **kwargs: Any) -> SelfAPGValue:
        """SB3's ``load`` without unpickling anything (:mod:`sb3_crowdnav.serialization`); ``trusted=True``: SB3's
        own load, which unpickles (only for files you made)."""
        if not trusted:
            custom_objects = {**safe_custom_objects(path, env, value_model=True), **(custom_objects or {})}
        return super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_explore_rng", "_rollout_stats", "_staged", "learner"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.optimizer"], []
