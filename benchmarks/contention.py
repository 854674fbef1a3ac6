"""Does a learner beside the acting loop slow the decisions down, as a thread and as a process?

    python benchmarks/contention.py [--decisions 300]

Times greedy lookahead decisions of the shipped ``apg_rl`` on real observations three ways, in one run: alone;
while a thread runs batch-100 gradient steps on a copy of V without pause; while another process does the same.
Prints decisions/s of each and their ratio to the lone rate (the acting efficiency a learner of that kind
allows at best).
"""

from __future__ import annotations

import argparse
import copy
import multiprocessing as mp
import threading
import time

import numpy as np
import torch as th

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav.apg_value import APGValue
from sb3_crowdnav.models import check_pretrained
from sb3_crowdnav.nn import configure_cpu


def _observations(model: APGValue, n: int) -> list:
    import gymnasium as gym

    env = gym.make("CrowdNav-v0")
    out, (obs, _) = [], env.reset(seed=0)
    while len(out) < n:
        out.append({k: v[None] for k, v in obs.items()})
        obs, _, terminated, truncated, _ = env.step(int(model.predict(obs, deterministic=True)[0]))
        if terminated or truncated:
            obs, _ = env.reset()
    return out


def _rate(model: APGValue, observations: list) -> float:
    start = time.perf_counter()
    for obs in observations:
        model.policy.action_values(obs)
    return len(observations) / (time.perf_counter() - start)


def _learn_forever(stop, batch: dict) -> None:
    configure_cpu(num_threads=1)
    model = APGValue.load(check_pretrained("apg_rl"))
    net = copy.deepcopy(model.policy.value_net).train(True)
    optimizer = th.optim.Adam(net.parameters(), lr=1e-4)
    tensors = {k: th.as_tensor(v) for k, v in batch.items()}
    while not stop.is_set():
        loss = net(tensors).square().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--decisions", type=int, default=300)
    args = p.parse_args()
    configure_cpu(num_threads=1)
    model = APGValue.load(check_pretrained("apg_rl"))
    model.policy.set_training_mode(False)
    observations = _observations(model, args.decisions)
    batch = {k: np.concatenate([o[k] for o in observations[:100]]) for k in observations[0]}
    _rate(model, observations[:50])  # warm-up
    alone = _rate(model, observations)
    rates = {"alone": alone}
    for kind in ("thread", "process"):
        stop = threading.Event() if kind == "thread" else mp.get_context("spawn").Event()
        worker = (threading.Thread if kind == "thread" else mp.get_context("spawn").Process)(
            target=_learn_forever, args=(stop, batch), daemon=True)
        worker.start()
        time.sleep(3.0)  # the learner is running
        rates[f"learner in a {kind}"] = _rate(model, observations)
        stop.set()
        worker.join()
    for label, rate in rates.items():
        print(f"{label:<22} {rate:7.0f} decisions/s   {rate / alone:5.2f} of alone")


if __name__ == "__main__":
    main()
