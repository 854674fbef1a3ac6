"""Training throughput of APGValue with the paper's settings, and the projected full schedule.

Measures (one torch thread, 6 pedestrians):
  (1) ORCA imitation collection [episodes/s] and the imitation regression [s per epoch per 1,000 states];
  (2) RL training [env steps/s and episodes/h] (ε-greedy lookahead + one batch-100 gradient step every 8 env steps);
  (3) the projected wall time of 3,000 IL + 10,000 RL episodes, for the measured RL episode length and for
      ``--episode-length`` steps per episode: the mean over the paper's schedule, where ε falls from 0.5 to 0.1
      (default 51.2, the mean of a full APG_RL run; the short run here starts from a 200-episode imitation model
      and its episodes end early in collisions, so its own mean is optimistic).

  (4) the bare decision rate (greedy lookaheads per second on real observations, the env not timed) and the
      acting efficiency: RL env steps/s with learning on over that rate, measured in the same run.

Usage: python benchmarks/training_speed.py [--n-envs 1] [--train-freq 8] [--rl-steps 3000] [--il-episodes 200]
                                          [--dtype float32|bfloat16] [--optimizer adam|sgd] [--overlap [process|thread|off]]
                                          [--from-pretrained apg_rl] [--epsilon 0.1]

``--overlap process`` (the default, as ``sb3-crowdnav train --variant``; ``thread``, or ``off``) runs the gradient
steps in a second process while the env collects the next steps (``APGValue(overlap_training=...)``): the paper's
schedule on both cores. The defaults (process, one gradient step per 8 env steps) are ``apg_rl``'s schedule.
The RL rate is timed after the first tenth of the steps, so that a learner process's start-up (a few seconds, once
per ``learn()``) is not counted in it.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.apg_value.pretraining import pretrain_from_orca
from sb3_crowdnav.imitation import pretrain_value
from sb3_crowdnav.nn import configure_cpu


def bare_decision_rate(model: APGValue, decisions: int) -> float:
    """Greedy lookahead decisions per second on observations of real episodes (the env steps are not timed)."""
    env = model.env
    observations, obs = [], env.reset()
    while len(observations) < decisions:
        observations.append(obs)
        action = model.policy.action_values(obs).argmax(axis=1)
        obs, *_ = env.step(action)
    model.policy.set_training_mode(False)
    start = time.perf_counter()
    for obs in observations:
        model.policy.action_values(obs)
    rate = decisions * env.num_envs / (time.perf_counter() - start)
    model._last_obs = env.reset()  # learn() starts from fresh episodes
    return rate


class _SteadyClock(BaseCallback):
    """Env steps/s of ``learn()`` after its first ``skip`` steps (a learner process starts up during those)."""

    def __init__(self, skip: int) -> None:
        super().__init__()
        self.skip, self._marks = skip, {}

    def _on_step(self) -> bool:
        self._marks.setdefault(self.n_calls >= self.skip, (self.n_calls, time.perf_counter()))
        self._marks[None] = (self.n_calls, time.perf_counter())
        return True

    def rate(self) -> float:
        (n0, t0), (n1, t1) = self._marks[True], self._marks[None]
        return (n1 - n0) * self.model.n_envs / (t1 - t0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--n-envs", type=int, default=1)
    p.add_argument("--train-freq", type=int, default=8,
                   help="one gradient step every this many env steps (per env; default 8, apg_rl's schedule)")
    p.add_argument("--rl-steps", type=int, default=3000)
    p.add_argument("--il-episodes", type=int, default=200)
    p.add_argument("--imitation-epochs", type=int, default=10)
    p.add_argument("--il-schedule", type=int, default=3000)
    p.add_argument("--rl-schedule", type=int, default=10000)
    p.add_argument("--epsilon", type=float, default=None,
                   help="hold ε at this value while measuring (default: the paper's 0.5 at the start of RL; late in "
                        "the schedule ε = 0.1 and nearly every step runs a lookahead)")
    p.add_argument("--episode-length", type=float, default=51.2,
                   help="mean RL episode length [steps] over the paper's schedule, for the projection")
    p.add_argument("--dtype", default="float32", choices=("float32", "bfloat16"), help="lookahead precision when acting")
    p.add_argument("--optimizer", default="adam", choices=("adam", "sgd"), help="RL optimiser (APGValue's default: adam)")
    p.add_argument("--overlap", nargs="?", const="thread", default="process", choices=("thread", "process", "off"),
                   help="APGValue(overlap_training=...): gradient steps on the second core, in a process (default, "
                        "as sb3-crowdnav train) or a thread (also a bare --overlap), or off (on the acting core)")
    p.add_argument("--from-pretrained", metavar="NAME",
                   help="start RL from a shipped model's weights (e.g. apg_rl), as the acting-efficiency measurement of "
                        "the issue tracker does; imitation is then only timed, not used")
    p.add_argument("--decisions", type=int, default=400, help="greedy decisions timed for the bare decision rate")
    args = p.parse_args()
    configure_cpu(num_threads=1)  # one torch thread + keep freed tensor memory (sb3_crowdnav.nn.perf)
    env = make_vec_env("CrowdNav-v0", n_envs=args.n_envs, seed=0)
    policy_kwargs = dict(lookahead_dtype=args.dtype)
    if args.optimizer == "sgd":
        policy_kwargs.update(optimizer_class=th.optim.SGD, optimizer_kwargs={"momentum": 0.9})
    eps = {} if args.epsilon is None else dict(exploration_initial_eps=args.epsilon, exploration_final_eps=args.epsilon)
    model = APGValue("ApgPolicy", env, seed=0, imitation_episodes=args.il_episodes, imitation_epochs=2,
                     train_freq=args.train_freq,
                     policy_kwargs=policy_kwargs, overlap_training=False if args.overlap == "off" else args.overlap,
                     **eps)

    model.set_logger(configure(None, [""]))
    epochs, model.imitation_epochs = model.imitation_epochs, 0
    t0 = time.perf_counter()
    pretrain_from_orca(model)  # epochs 0: the collection alone (into the replay buffer, as in training)
    collect = time.perf_counter() - t0
    buffer = model.replay_buffer
    states = buffer.size() * buffer.n_envs
    states_per_episode = states / args.il_episodes
    observations = {k: v[: buffer.size()].reshape(states, -1) for k, v in buffer.observations.items()}
    net = model.policy.value_net
    optimizer = th.optim.SGD(net.parameters(), lr=model.imitation_learning_rate, momentum=0.9)
    t1 = time.perf_counter()
    pretrain_value(net, observations, np.zeros(states, dtype=np.float32), optimizer, 2, model.batch_size,
                   th.Generator().manual_seed(0), model.max_grad_norm)
    per_epoch_per_k = (time.perf_counter() - t1) / 2 / (states / 1000)
    model.imitation_epochs, model.imitation_done = epochs, True
    if args.from_pretrained:
        from sb3_crowdnav.models import check_pretrained

        shipped = APGValue.load(check_pretrained(args.from_pretrained))
        model.policy.value_net.load_state_dict(shipped.policy.value_net.state_dict())
        model.policy.value_net_target.load_state_dict(shipped.policy.value_net.state_dict())

    decisions_per_s = bare_decision_rate(model, args.decisions)
    clock = _SteadyClock(args.rl_steps // 10)
    t2 = time.perf_counter()
    model.learn(args.rl_steps, reset_num_timesteps=False, callback=clock)
    rl = time.perf_counter() - t2
    episodes = max(model._episode_num, 1)
    steps_per_s = clock.rate()
    ep_len = args.rl_steps / episodes

    il_collect_s = args.il_schedule / (args.il_episodes / collect)
    il_regress_s = per_epoch_per_k * args.imitation_epochs * args.il_schedule * states_per_episode / 1000
    print(f"n_envs={args.n_envs} train_freq={args.train_freq} torch_threads={th.get_num_threads()} "
          f"overlap_training={args.overlap} optimizer={args.optimizer} dtype={args.dtype} "
          f"epsilon={model.exploration_rate:.2f}")
    print(f"imitation collection: {args.il_episodes / collect:.1f} episodes/s ({states_per_episode:.1f} states/episode)")
    print(f"imitation regression: {per_epoch_per_k:.3f} s per epoch per 1,000 states")
    print(f"RL: {steps_per_s:.0f} env steps/s (after the first {clock.skip} steps; all {args.rl_steps} in {rl:.1f} s), "
          f"mean episode length {ep_len:.1f} steps, {3600 * steps_per_s / ep_len:.0f} episodes/h")
    print(f"bare decision rate: {decisions_per_s:.0f} decisions/s (greedy lookahead of one env, real observations, "
          f"same weights); acting efficiency = RL env steps/s / decisions/s = {steps_per_s / decisions_per_s:.2f}")
    for label, length in (("measured episode length", ep_len), (f"{args.episode_length:g}-step episodes",
                                                                 args.episode_length)):
        total = il_collect_s + il_regress_s + args.rl_schedule * length / steps_per_s
        print(f"projected {args.il_schedule} IL ({args.imitation_epochs} epochs) + {args.rl_schedule} RL episodes "
              f"[{label}]: {total / 60:.1f} min (IL collect {il_collect_s / 60:.1f}, IL regress {il_regress_s / 60:.1f}, "
              f"RL {args.rl_schedule * length / steps_per_s / 60:.1f})")


if __name__ == "__main__":
    main()
