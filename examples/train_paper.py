"""Train one of the paper's variants with its schedule, with checkpoints and resume.

    python examples/train_paper.py --variant apg_rl --out runs/apg_rl            # 3,000 IL + 10,000 RL episodes
    python examples/train_paper.py --variant apg_rl --out runs/apg_rl            # run again: resumes from the last checkpoint
    nohup python examples/train_paper.py --variant apg_crl --out runs/apg_crl > runs/apg_crl.log 2>&1 &

Every ``--checkpoint-episodes`` RL episodes the model (and its replay buffer) is written to
``OUT/checkpoint.zip`` / ``OUT/replay_buffer.pkl`` (written to a temporary name first, so an
interrupted save never destroys the previous checkpoint); TensorBoard logs go to ``OUT/tb``.
At the end the final model is ``OUT/final.zip``.

SIGTERM or SIGINT (Ctrl-C, ``kill PID``, the end of a session) during the RL phase stops the run at the
end of the current step and writes the checkpoint first, so no more than the unfinished episode is
lost; the process then exits with status 128 + the signal number and no ``final.zip``, and running the
same command again resumes. A second signal kills at once (the checkpoint files are replaced
atomically, so the previous checkpoint survives). During imitation a signal kills the run as usual
(imitation restarts; it takes minutes).

To continue a run on another machine, copying ``checkpoint.zip`` and ``progress.json`` is enough (add
``eval_curve.jsonl``, ``best.json`` and ``best.zip`` to keep the validation curve and the best-so-far
selection); the replay buffer (~200 MB) can stay behind: a run resumed without ``replay_buffer.pkl`` starts
with an empty buffer and makes no gradient step until it has collected ``--refill-steps`` new transitions.

A run takes an hour or more; if you keep editing the package meanwhile, start it from a frozen copy
(``git worktree add --detach ../frozen HEAD`` and ``PYTHONPATH=../frozen python ../frozen/examples/train_paper.py ...``)
so that modules imported late (rendering, a checkpoint's classes) come from the same version.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sys
import time
from pathlib import Path

import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.nn import configure_cpu
from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.apg_value.apg_value import VALUE_TARGETS
# imported up front, not at the first validation: a run that lasts an hour must not mix this package's
# modules from before and after an edit of the working tree (a run died that way on a changed episode record)
from sb3_crowdnav.evaluation import run_episodes, summarize

VARIANTS = {
    # name: (policy alias, reward)
    "apg_rl": ("ApgPolicy", "crowdnav"),
    "apg_crl": ("ApgPolicy", "comfort"),
    "apg_carl": ("ApgPolicy", "comfort_angular"),
    "cadrl": ("CadrlPolicy", "crowdnav"),
    "sf_rl": ("SfPolicy", "crowdnav"),
    "lm_rl": ("LmPolicy", "crowdnav"),
    "lstm_rl": ("LstmRlPolicy", "crowdnav"),
    "sarl": ("SarlPolicy", "crowdnav"),
}


VALIDATION_SEED_OFFSET = 2_000_000  # greedy validation episodes: disjoint from training and from the test seeds


class EpisodeCheckpoint(BaseCallback):
    """Stop after ``max_episodes`` RL episodes in total; every ``every`` episodes checkpoint and validate.

    Validation: ``eval_episodes`` greedy episodes on fixed seeds (the ε-greedy rollout rates of the
    training log understate the greedy policy while ε is large), logged as ``eval/*`` and appended
    to ``OUT/eval_curve.jsonl``; a copy of each checkpoint is kept as ``OUT/checkpoint_<episodes>.zip``
    and the best one so far as ``OUT/best.zip``: highest success, then shortest navigation time
    (``select_by="success"``), or highest mean discounted return under the variant's own reward
    (``select_by="return"``, which counts the comfort and angular penalties of APG_CRL/APG_CARL).
    Validation episodes run with ``env_kwargs`` (the training reward and crowd).
    """

    def __init__(self, out: Path, max_episodes: int, every: int, eval_episodes: int = 100,
                 select_by: str = "success", env_kwargs: dict | None = None) -> None:
        super().__init__()
        self.out, self.max_episodes, self.every, self.eval_episodes = out, max_episodes, every, eval_episodes
        self.select_by, self.env_kwargs = select_by, dict(env_kwargs or {})
        self._last = -1
        self.stopped_by: int | None = None  # the signal that stopped training early, if any
        self._previous_handlers: dict[int, object] = {}

    def validate(self) -> None:
        model = self.model
        start = time.time()
        s = summarize(run_episodes(model, self.eval_episodes, self.env_kwargs, seed_offset=VALIDATION_SEED_OFFSET))
        row = {"episodes": model._episode_num, "timesteps": model.num_timesteps, "wall": time.time(),
               "eval_seconds": time.time() - start,
               "success": s.success_rate, "collision": s.collision_rate, "timeout": s.timeout_rate,
               "time": s.navigation_time, "gap": s.min_separation, "return": s.discounted_return,
               "comfort_time": s.comfort_zone_time, "heading": s.heading_change, "sharp_turns": s.sharp_turns}
        for key in ("success", "collision", "timeout", "time", "gap", "return"):
            model.logger.record(f"eval/{key}", row[key])
        with open(self.out / "eval_curve.jsonl", "a") as f:
            f.write(json.dumps(row) + "\n")
        if self.select_by == "return":
            score = (s.discounted_return,)
        else:
            score = (s.success_rate, -s.navigation_time if s.navigation_time == s.navigation_time else 0.0)
        best_file = self.out / "best.json"
        best = json.loads(best_file.read_text()) if best_file.exists() else None
        if best is None or best.get("select_by", "success") != self.select_by or score > tuple(best["score"]):
            shutil.copy(self.out / "checkpoint.zip", self.out / "best.zip")
            best_file.write_text(json.dumps({"score": score, "select_by": self.select_by, **row}))
        print(f"validation after {row['episodes']} RL episodes: success {s.success_rate:.2f}, "
              f"collision {s.collision_rate:.2f}, time {s.navigation_time:.2f} s", flush=True)

    def save(self) -> None:
        model = self.model
        tmp = self.out / "checkpoint.tmp.zip"
        model.save(tmp)
        model.save_replay_buffer(self.out / "replay_buffer.tmp.pkl")
        os.replace(tmp, self.out / "checkpoint.zip")
        os.replace(self.out / "replay_buffer.tmp.pkl", self.out / "replay_buffer.pkl")
        (self.out / "progress.json").write_text(json.dumps(
            {"episodes": model._episode_num, "timesteps": model.num_timesteps, "time": time.time()}))

    def _stop(self, signum: int, _frame) -> None:
        self.stopped_by = signum
        self._restore_handlers()  # a second signal acts as usual

    def _restore_handlers(self) -> None:
        for signum, handler in self._previous_handlers.items():
            signal.signal(signum, handler)
        self._previous_handlers = {}

    def _on_training_start(self) -> None:
        self._last = self.model._episode_num  # a resumed run does not checkpoint and validate its first episode count again
        self._previous_handlers = {s: signal.signal(s, self._stop) for s in (signal.SIGTERM, signal.SIGINT)}

    def _on_training_end(self) -> None:
        self._restore_handlers()

    def _on_step(self) -> bool:
        if self.stopped_by is not None:
            return False
        episodes = self.model._episode_num
        if episodes != self._last and episodes > 0 and episodes % self.every == 0:
            self._last = episodes
            self.save()
            shutil.copy(self.out / "checkpoint.zip", self.out / f"checkpoint_{episodes}.zip")
            if self.eval_episodes:
                self.validate()
        return episodes < self.max_episodes

OPTIMIZERS = {"adam": (th.optim.Adam, {}), "sgd": (th.optim.SGD, {"momentum": 0.9})}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variant", choices=sorted(VARIANTS), default="apg_rl")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--rl-episodes", type=int, default=10_000)
    p.add_argument("--il-episodes", type=int, default=3_000)
    p.add_argument("--il-epochs", type=int, default=10)
    p.add_argument("--n-envs", type=int, default=1)
    p.add_argument("--num-humans", type=int, default=6)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--learning-rate", type=float, default=1e-3, help="RL learning rate (Table 1: 0.001)")
    p.add_argument("--train-freq", type=int, default=4, help="one gradient step every this many env steps")
    p.add_argument("--buffer-size", type=int, default=100_000, help="replay capacity [transitions]")
    p.add_argument("--checkpoint-episodes", type=int, default=500)
    p.add_argument("--eval-episodes", type=int, default=100, help="greedy validation episodes at each checkpoint (0: none)")
    p.add_argument("--no-bootstrap-timeouts", dest="bootstrap_timeouts", action="store_false",
                   help="end timed-out episodes with zero future value (the field's reference code) instead of bootstrapping")
    p.add_argument("--exploration-episodes", type=int, default=5_000,
                   help="RL episodes over which ε decays from 0.5 to 0.1 (the paper: 5,000)")
    p.add_argument("--select-by", choices=("success", "return"), default="success",
                   help="best.zip = highest validation success then shortest time, or highest return under the "
                        "variant's own reward (use for apg_crl / apg_carl)")
    p.add_argument("--optimizer", choices=("sgd", "adam"), default="adam",
                   help="RL optimiser: adam (APGValue's default) or sgd (SGD with momentum 0.9, the field's code); "
                        "imitation always uses SGD with momentum 0.9")
    p.add_argument("--il-learning-rate", type=float, default=0.01, help="imitation learning rate (Table 1: 0.01)")
    p.add_argument("--value-target", choices=VALUE_TARGETS, default="td",
                   help="what V is regressed on in RL (see APGValue's value_target)")
    p.add_argument("--from-imitation", type=Path, help="start from a saved post-imitation model (skips imitation)")
    p.add_argument("--overlap", action="store_true",
                   help="APGValue(overlap_training=True): gradient steps on the second core while acting (~1.4-1.6x)")
    p.add_argument("--refill-steps", type=int, default=5_000,
                   help="resuming without OUT/replay_buffer.pkl (a run moved to another machine): env steps collected "
                        "into the empty buffer before gradient steps start again")
    p.add_argument("--lookahead-dtype", choices=("float32", "bfloat16"), default="float32",
                   help="precision of the acting lookahead (bfloat16 needs native CPU kernels; TD targets and gradient "
                        "steps stay float32)")
    args = p.parse_args()
    if args.refill_steps < 0:
        p.error(f"--refill-steps must be >= 0, got {args.refill_steps}")
    configure_cpu(num_threads=1)  # one torch thread + keep freed tensor memory (sb3_crowdnav.nn.perf)
    policy, reward = VARIANTS[args.variant]
    args.out.mkdir(parents=True, exist_ok=True)
    ckpt = args.out / "checkpoint.zip"
    progress = args.out / "progress.json"
    done_episodes = json.loads(progress.read_text())["episodes"] if ckpt.exists() and progress.exists() else 0
    # a resumed run draws new training episodes instead of replaying the first ones
    env = make_vec_env("CrowdNav-v0", n_envs=args.n_envs, seed=args.seed + 7919 * done_episodes,
                       env_kwargs=dict(reward=reward, num_humans=args.num_humans))
    if ckpt.exists():
        model = APGValue.load(ckpt, env=env, tensorboard_log=str(args.out / "tb"), overlap_training=args.overlap)
        print(f"resuming from {ckpt} at episode {model._episode_num}, {model.num_timesteps} steps", flush=True)
        if (args.out / "replay_buffer.pkl").exists():
            model.load_replay_buffer(args.out / "replay_buffer.pkl")
        else:  # a run carried to another machine without its (large) buffer: refill it before the next gradient step
            model.learning_starts = model.num_timesteps + args.refill_steps
            print(f"no replay buffer in {args.out}: collecting {args.refill_steps} transitions before training again",
                  flush=True)
        reset = False
    elif args.from_imitation is not None:
        model = APGValue.load(args.from_imitation, env=env, tensorboard_log=str(args.out / "tb"), verbose=1,
                              bootstrap_timeouts=args.bootstrap_timeouts, learning_rate=args.learning_rate,
                              train_freq=args.train_freq, value_target=args.value_target,
                              exploration_episodes=args.exploration_episodes, overlap_training=args.overlap)
        optimizer_class, optimizer_kwargs = OPTIMIZERS[args.optimizer]
        if model.policy.optimizer_class is not optimizer_class:  # swap the RL optimiser; policy_kwargs follow (save/load)
            model.policy_kwargs.update(optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs)
            model.policy.optimizer_class, model.policy.optimizer_kwargs = optimizer_class, optimizer_kwargs
            model.policy.optimizer = optimizer_class(model.policy.value_net.parameters(), lr=args.learning_rate,
                                                     **optimizer_kwargs)
        if (args.from_imitation.parent / "imitation_replay_buffer.pkl").exists():
            model.load_replay_buffer(args.from_imitation.parent / "imitation_replay_buffer.pkl")
        reset = True
    else:
        model = APGValue(policy, env, seed=args.seed, imitation_episodes=args.il_episodes,
                         imitation_epochs=args.il_epochs, tensorboard_log=str(args.out / "tb"), verbose=1,
                         bootstrap_timeouts=args.bootstrap_timeouts, learning_rate=args.learning_rate,
                         train_freq=args.train_freq, buffer_size=args.buffer_size, value_target=args.value_target,
                         exploration_episodes=args.exploration_episodes, imitation_learning_rate=args.il_learning_rate,
                         overlap_training=args.overlap,
                         policy_kwargs=dict(zip(("optimizer_class", "optimizer_kwargs"), OPTIMIZERS[args.optimizer],
                                                strict=True), lookahead_dtype=args.lookahead_dtype))
        model.learn(0, tb_log_name=args.variant)  # imitation pre-training only; kept so variants can restart from it
        model.save(args.out / "imitation.zip")
        model.save_replay_buffer(args.out / "imitation_replay_buffer.pkl")
        reset = False
    model.policy.set_lookahead_dtype(args.lookahead_dtype)  # also for a resumed or --from-imitation run
    callback = EpisodeCheckpoint(args.out, args.rl_episodes, args.checkpoint_episodes, args.eval_episodes,
                                 select_by=args.select_by, env_kwargs=dict(reward=reward, num_humans=args.num_humans))
    start = time.time()
    # the episode budget stops training; the step budget is only an upper bound (100 steps per episode)
    model.learn(total_timesteps=args.rl_episodes * 100 * 2, callback=callback, reset_num_timesteps=reset,
                tb_log_name=args.variant, log_interval=50)
    callback.save()
    if callback.stopped_by is not None:
        print(f"stopped by signal {callback.stopped_by} after {model._episode_num} RL episodes, "
              f"{model.num_timesteps} steps; checkpoint written, run the same command again to resume", flush=True)
        sys.exit(128 + callback.stopped_by)
    model.save(args.out / "final.zip")
    print(f"done: {model._episode_num} RL episodes, {model.num_timesteps} steps, {time.time() - start:.0f} s this run",
          flush=True)


if __name__ == "__main__":
    main()
