"""Are two training runs the same run, bit for bit? Compares the checkpoints of two run folders.

    python examples/compare_runs.py runs/a runs/b

For every ``*.zip`` model present in both folders: every tensor of every ``.pth`` member (weights and
optimiser state) and every field of the ``data`` member (counters, hyperparameters, spaces), except
what differs between any two processes (start time, log folders, memory addresses in reprs, episode
wall times); the pickled entries are compared as bytes, never unpickled.
Also ``progress.json`` and the validation rows of ``eval_curve.jsonl`` without their wall times.
Exit status 0 when everything compared is identical, 1 otherwise (the differences are listed).
"""

from __future__ import annotations

import argparse
import io
import json
import re
import sys
import zipfile
from pathlib import Path
from typing import Any

import torch as th

# start time, log folder, the last observation of the envs, and the Monitor rows (their "t" is wall time)
VOLATILE = {"start_time", "tensorboard_log", "_last_obs", "_last_original_obs", "_last_episode_starts", "ep_info_buffer"}
ADDRESS = re.compile(r" at 0x[0-9a-f]+")


def read_model(path: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    with zipfile.ZipFile(path) as archive:
        for name in archive.namelist():
            raw = archive.read(name)
            if name.endswith(".pth"):
                out[name] = th.load(io.BytesIO(raw), weights_only=True)
            elif name == "data":
                out[name] = {k: v for k, v in json.loads(raw).items() if k not in VOLATILE}
            elif name != "_stable_baselines3_version" and name != "system_info.txt":
                out[name] = raw
    return out


def differences(a: Any, b: Any, path: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return [f"{path}: keys {sorted(set(a) ^ set(b))}"]
        return [d for k in a for d in differences(a[k], b[k], f"{path}/{k}")]
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return [f"{path}: length {len(a)} != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in differences(x, y, f"{path}[{i}]")]
    if isinstance(a, th.Tensor) and isinstance(b, th.Tensor):
        return [] if a.shape == b.shape and th.equal(a, b) else [f"{path}: tensors differ"]
    if isinstance(a, str) and isinstance(b, str):
        a, b = ADDRESS.sub("", a), ADDRESS.sub("", b)
    return [] if a == b or (a != a and b != b) else [f"{path}: {a!r} != {b!r}"[:200]]


def eval_rows(folder: Path) -> list[dict[str, Any]]:
    path = folder / "eval_curve.jsonl"
    if not path.exists():
        return []
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    return [{k: v for k, v in row.items() if k not in ("wall", "eval_seconds")} for row in rows]


def compare(a: Path, b: Path) -> list[str]:
    diffs: list[str] = []
    models = sorted({p.name for p in a.glob("*.zip")} & {p.name for p in b.glob("*.zip")})
    for name in models:
        found = differences(read_model(a / name), read_model(b / name), name)
        print(f"{name}: {'identical' if not found else f'{len(found)} difference(s)'}")
        diffs += found
    for name in ("progress.json",):
        if (a / name).exists() and (b / name).exists():
            found = differences(*(
                {k: v for k, v in json.loads((f / name).read_text()).items() if k != "time"} for f in (a, b)), name)
            print(f"{name}: {'identical' if not found else 'different'}")
            diffs += found
    found = differences(eval_rows(a), eval_rows(b), "eval_curve.jsonl")
    print(f"eval_curve.jsonl ({len(eval_rows(a))} rows): {'identical' if not found else 'different'}")
    return diffs + found


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    args = p.parse_args(argv)
    for folder in (args.a, args.b):
        if not folder.is_dir():
            p.error(f"{folder}: not a folder")
    diffs = compare(args.a, args.b)
    for d in diffs:
        print("  " + d)
    print("same run" if not diffs else f"{len(diffs)} difference(s)")
    return 0 if not diffs else 1


if __name__ == "__main__":
    sys.exit(main())
