"""Prepare the public ETH/UCY recordings for ``crowd="replay"`` (none ships with the package: their licences differ).

    python examples/prepare_recordings.py OPENTRAJ_DIR OUT_DIR

``OPENTRAJ_DIR`` is a checkout of the OpenTraj repository (crowdbotp/OpenTraj on GitHub), which keeps the original
annotations as ``obsmat.txt`` files of 8 columns, ``frame id x z y vx vz vy`` [m] (z the height, always 0). This
script writes each scene as the 4-column text format the replay reads, ``frame id x y``, into ``OUT_DIR``:
``eth.txt`` (``seq_eth``: 15 fps video, every 6th frame annotated), ``hotel.txt`` (``seq_hotel``, 25 fps),
``zara1.txt``, ``zara2.txt`` (UCY zara01/02, 25 fps) and ``univ.txt`` (UCY students03, 25 fps). A person annotated
in a single frame (one in HOTEL) is dropped and reported: the replay refuses it, since a person needs a time to
appear and one to vanish. It prints the ``--scene`` options of ``examples/generalisation.py`` with each frame rate.

Two more UCY recordings, for training only, come from OpenTraj's copy of the TrajNet training split, which is
already in the ``frame id x y`` layout (every 10th frame of the 25 fps videos): ``students001.txt`` (UCY
students001, the same university campus as UNIV on another day, its densest recording: 891 people in 3 minutes)
and ``zara3.txt`` (UCY zara03). Neither is one of the five evaluation scenes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

# name -> (obsmat.txt inside OpenTraj, the video's frame rate [frames/s])
SCENES = {
    "eth": ("datasets/ETH/seq_eth/obsmat.txt", 15.0),
    "hotel": ("datasets/ETH/seq_hotel/obsmat.txt", 25.0),
    "zara1": ("datasets/UCY/zara01/obsmat.txt", 25.0),
    "zara2": ("datasets/UCY/zara02/obsmat.txt", 25.0),
    "univ": ("datasets/UCY/students03/obsmat.txt", 25.0),
}

# name -> (a ``frame id x y`` file inside OpenTraj, the video's frame rate): more recordings to train among
TRAINING_SCENES = {
    "students001": ("datasets/TrajNet/Train/crowds/students001.txt", 25.0),
    "zara3": ("datasets/TrajNet/Train/crowds/crowds_zara03.txt", 25.0),
}


def convert(source: Path, target: Path, columns: int = 8) -> tuple[int, int, list[int]]:
    """Write ``source`` (an obsmat file, or with ``columns=4`` a ``frame id x y`` file) as ``frame id x y`` into
    ``target``; rows, people, the dropped ids."""
    if columns not in (4, 8):
        raise ValueError(f"columns must be 8 (an obsmat file) or 4 (frame id x y), got {columns!r}")
    data = np.loadtxt(source, ndmin=2)
    if data.shape[1] != columns:
        kind = "an obsmat file" if columns == 8 else "a frame id x y file"
        raise ValueError(f"{source}: expected the {columns} columns of {kind}, got {data.shape[1]}")
    ids, counts = np.unique(data[:, 1], return_counts=True)
    single = ids[counts == 1]
    keep = ~np.isin(data[:, 1], single)
    rows = data[keep][:, [0, 1, 2, 4] if columns == 8 else [0, 1, 2, 3]]
    np.savetxt(target, rows, fmt=["%d", "%d", "%.4f", "%.4f"])
    return len(rows), len(ids) - len(single), [int(i) for i in single]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("opentraj", type=Path, help="a checkout of crowdbotp/OpenTraj")
    p.add_argument("out", type=Path, help="the folder to write the scenes into")
    args = p.parse_args(argv)
    scenes = {**SCENES, **TRAINING_SCENES}
    missing = [str(args.opentraj / path) for path, _ in scenes.values() if not (args.opentraj / path).is_file()]
    if missing:
        p.error(f"not an OpenTraj checkout: missing {', '.join(missing)}")
    args.out.mkdir(parents=True, exist_ok=True)
    options = []
    for name, (path, fps) in scenes.items():
        columns = 8 if name in SCENES else 4
        rows, people, dropped = convert(args.opentraj / path, args.out / f"{name}.txt", columns)
        note = f"; dropped the single-sample person(s) {dropped}" if dropped else ""
        print(f"{name}: {rows} rows, {people} people{note}")
        if name in SCENES:
            options.append(f"--scene {name}={args.out / name}.txt,frame_rate={fps:g},tracked=nearest")
    print("\n" + " ".join(options))
    extra = " ".join(f"--recording {args.out / name}.txt,frame_rate={fps:g}" for name, (_, fps) in TRAINING_SCENES.items())
    print(f"\nmore recordings to train among (sb3-crowdnav train --variant apg_robust): {extra}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
