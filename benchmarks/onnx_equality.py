"""The exported ONNX graph against the PyTorch model it came from, on observations of test episodes.

Usage: python benchmarks/onnx_equality.py [--models apg_rl apg_warehouse_paper ...] [--observations 10000] [--envs 32]
    [--graphs DIR] [--episodes 60 [--seed-offset 2000000]]

For every shipped model (default) the model drives ``--envs`` envs of its world from the test seeds (1,000,000 on)
until ``--observations`` observations are seen; on each batch the PyTorch decision (the model's own ``predict`` and
its values: the lookahead's ``action_values``, DQN's Q network, PPO's logits) and the graph's (``OnnxPolicy``) are
compared. Prints per model: actions equal, the differing actions that are ties (the PyTorch values of the two actions
within 1e-6), other differences (must be 0) and the largest difference of the values (must be below 1e-4).
Graphs are exported into ``--graphs`` (default: a temporary folder), or read from it when already there.

With ``--episodes N`` each model is also evaluated by the command line, ``sb3-crowdnav evaluate --episodes N
--seed-offset S --out DIR`` (default S: the validation seeds, 2,000,000 on; the warehouse models in their world),
once as ``pretrained:NAME`` and once as the ``.onnx`` file, and the two ``episodes.csv`` must be byte-identical.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_vec_env

import sb3_crowdnav  # noqa: F401  (registers the envs)
from sb3_crowdnav.deploy import OnnxPolicy, export_onnx
from sb3_crowdnav.deploy.graph import decision_module
from sb3_crowdnav.evaluation.runner import TEST_SEED_OFFSET
from sb3_crowdnav.models import available_pretrained, check_pretrained, pretrained, pretrained_env
from sb3_crowdnav.nn import configure_cpu
from sb3_crowdnav.training.callbacks import VALIDATION_SEED_OFFSET

TIE = 1e-6  # two actions whose PyTorch values differ by at most this are a tie
VALUE_TOLERANCE = 1e-4


def torch_values(model, decision, obs: dict[str, np.ndarray]) -> np.ndarray:
    """The PyTorch values the greedy action maximises: the lookahead's own (numpy propagation), else the network's."""
    policy = model.policy
    if hasattr(policy, "action_values"):
        return policy.action_values(obs)
    with th.no_grad():
        return decision({k: th.as_tensor(v) for k, v in obs.items()})[1].numpy()


def compare(name: str, observations: int, n_envs: int, graphs: Path) -> dict:
    env_id, env_kwargs = pretrained_env(name)
    model = pretrained(name)
    path = graphs / f"{name}.onnx"
    vec = make_vec_env(env_id, n_envs=n_envs, seed=TEST_SEED_OFFSET, env_kwargs=env_kwargs)
    if not path.exists():
        start = time.perf_counter()
        export_onnx(check_pretrained(name), path, env=vec)  # the file: it records the world of an SB3 model
        print(f"  exported {path.name} in {time.perf_counter() - start:.0f} s")
    graph = OnnxPolicy(path, vec)
    decision = decision_module(model).eval()
    seen = equal = ties = other = 0
    worst = 0.0
    obs = vec.reset()
    while seen < observations:
        values = torch_values(model, decision, obs)
        # a lookahead's predict is the argmax of these values: computing them once halves the run
        actions = values.argmax(axis=1) if hasattr(model.policy, "action_values") else \
            model.predict(obs, deterministic=True)[0]
        onnx_actions, onnx_values, _ = graph.run(obs)
        worst = max(worst, float(np.abs(onnx_values - values).max()))
        rows = np.arange(len(actions))
        same = onnx_actions == actions
        tie = ~same & (np.abs(values[rows, actions] - values[rows, onnx_actions]) <= TIE)
        equal += int(same.sum())
        ties += int(tie.sum())
        other += int((~same & ~tie).sum())
        seen += len(actions)
        obs, *_ = vec.step(actions)
    vec.close()
    return dict(model=name, env=env_id, observations=seen, equal=equal, ties=ties, other=other, worst=worst)


def same_records(name: str, graph: Path, episodes: int, seed_offset: int, out: Path) -> str:
    """``sb3-crowdnav evaluate`` of the shipped model and of its graph: "identical" when their ``episodes.csv`` are
    byte-identical, else the first differing episode (a line of the CSV)."""
    from sb3_crowdnav.cli import main as cli

    env_id, env_kwargs = pretrained_env(name)
    options = ["--env", env_id, "--episodes", str(episodes), "--seed-offset", str(seed_offset), "--no-progress"]
    if env_kwargs:
        options += ["--env-kwargs", repr(env_kwargs)]
    csv = []
    for tag, policy in (("model", f"pretrained:{name}"), ("onnx", str(graph))):
        folder = out / f"{name}-{tag}"
        with contextlib.redirect_stdout(io.StringIO()):
            code = cli(["evaluate", "--policy", policy, *options, "--out", str(folder)])
        if code != 0:
            raise RuntimeError(f"sb3-crowdnav evaluate --policy {policy} exited with {code}")
        csv.append((folder / "episodes.csv").read_bytes())
    if csv[0] == csv[1]:
        return "identical"
    model, onnx = (text.decode().splitlines() for text in csv)
    first = next((i for i, (a, b) in enumerate(zip(model, onnx, strict=False)) if a != b), min(len(model), len(onnx)))
    return f"differ from CSV line {first + 1}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=available_pretrained(), choices=available_pretrained())
    parser.add_argument("--observations", type=int, default=10_000, help="observations per model")
    parser.add_argument("--envs", type=int, default=32, help="envs stepped together (the batch of each comparison)")
    parser.add_argument("--graphs", type=Path, help="folder of the .onnx files (default: a temporary one)")
    parser.add_argument("--episodes", type=int, default=0,
                        help="also compare the episodes.csv of sb3-crowdnav evaluate over this many episodes")
    parser.add_argument("--seed-offset", type=int, default=VALIDATION_SEED_OFFSET,
                        help="the first episode seed of --episodes (default: %(default)s, the validation seeds)")
    args = parser.parse_args()
    configure_cpu(1)
    with tempfile.TemporaryDirectory() as tmp:
        graphs = args.graphs or Path(tmp)
        graphs.mkdir(parents=True, exist_ok=True)
        rows = []
        for name in args.models:
            print(f"{name}:", flush=True)
            row = compare(name, args.observations, args.envs, graphs)
            if args.episodes:
                row["records"] = same_records(name, graphs / f"{name}.onnx", args.episodes, args.seed_offset, Path(tmp))
            print(f"  {row}", flush=True)
            rows.append(row)
    records = f" evaluate, {args.episodes} episodes from seed {args.seed_offset} |" if args.episodes else ""
    print("\n| model | env | observations | actions equal | ties (<= 1e-6) | other differences | max abs value diff |"
          f"{records}")
    print("|---|---|---|---|---|---|---|" + ("---|" if args.episodes else ""))
    for r in rows:
        print(f"| {r['model']} | {r['env']} | {r['observations']} | {r['equal']} | {r['ties']} | {r['other']} | "
              f"{r['worst']:.2e} |" + (f" {r['records']} |" if args.episodes else ""))
    failed = [r["model"] for r in rows
              if r["other"] or r["worst"] > VALUE_TOLERANCE or r.get("records", "identical") != "identical"]
    print(f"\n{'FAILED: ' + ', '.join(failed) if failed else 'every model equal'} (actions equal but for ties within "
          f"{TIE}; values within {VALUE_TOLERANCE}" + ("; identical episode records)" if args.episodes else ")"))
    if failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
