"""Recorded pedestrians: the reader of the ETH/UCY text format and of a ``t,id,x,y`` CSV, checked once, and the writer
of that CSV (numpy only; no dataset is shipped: see the docs' replay page for where the public recordings are).

Two formats, told apart by the file's extension and, for any other extension, by its first line:

* **CSV** (``.csv``, or a first line with a comma): a header naming the columns ``t``, ``id``, ``x``, ``y`` (in
  any order, no other column), then one row per sample: ``t`` the time [s], ``id`` the person (any text), ``x``,
  ``y`` the position [m]. ``frame_rate`` is refused: the times are already in seconds.
* **ETH/UCY text** (any other file): four whitespace-separated numbers per line, ``frame ped_id x y`` (the
  Social-GAN/TrajNet layout of the ETH and UCY scenes), positions in metres. A time is ``frame / frame_rate``, and
  ``frame_rate`` [frames/s of the original video] must be given: the files do not say it, and the wrong one plays the
  scene too fast or too slow. The frame step (the smallest gap between two of the file's frame numbers) is inferred
  and reported, not used for the times. The trap: the widely copied Social-GAN ``biwi_eth.txt`` has a frame step of
  10 although ETH was annotated every 6th frame of its 15 fps video (0.4 s per row; sgan issue #84, Trajectron++
  issue #67); its frame numbers are the video's, so read at 15 fps it is right, and read at 0.4 s per row (as if
  25 fps) it plays ETH 1.67x too fast.

A recording is refused (``ValueError`` naming ``file:line``) for a line that cannot be read (a wrong number of
columns, a text that is not a number, NaN or inf), a CSV header with a missing or an unknown column, a person whose
times do not increase strictly (in file order), a person with one sample, and units that cannot be metres: a
coordinate beyond :data:`MAX_COORDINATE` (1 km) from the origin, or a person moving faster than :data:`MAX_SPEED`
(10 m/s) between two of its samples (pixels, millimetres or a wrong ``frame_rate``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MAX_COORDINATE = 1000.0  # [m] farther from the origin, a coordinate is not in metres (pixels, millimetres)
MAX_SPEED = 10.0  # [m/s] faster between two samples, a person's units or frame rate are wrong
CSV_COLUMNS = ("t", "id", "x", "y")
ETH_COLUMNS = ("frame", "ped_id", "x", "y")


@dataclass(frozen=True, eq=False)
class Recording:
    """The people of a recording, each a track of samples with strictly increasing times.

    :param source: the file read (for messages)
    :param ids: each person's id, as in the file (text)
    :param times: each person's sample times (k,) [s], k >= 2
    :param positions: each person's sample positions (k, 2) [m]
    :param frame_step: ETH/UCY text: the inferred frame step [frames] (None for a CSV)
    """

    source: str
    ids: tuple[str, ...]
    times: tuple[np.ndarray, ...]
    positions: tuple[np.ndarray, ...]
    frame_step: float | None = None

    @property
    def first(self) -> np.ndarray:
        """Each person's first sample time (people,) [s]."""
        return np.array([t[0] for t in self.times])

    @property
    def last(self) -> np.ndarray:
        """Each person's last sample time (people,) [s]."""
        return np.array([t[-1] for t in self.times])

    @property
    def span(self) -> tuple[float, float]:
        """The first and the last sample time of the recording [s]."""
        return float(self.first.min()), float(self.last.max())

    @property
    def max_speed(self) -> float:
        """The fastest any person moves between two of its samples [m/s] (a bound of the replayed velocities)."""
        return max(float(_segment_speeds(t, p).max()) for t, p in zip(self.times, self.positions, strict=True))

    @property
    def extent(self) -> float:
        """The largest absolute coordinate of any sample [m]."""
        return max(float(np.abs(p).max()) for p in self.positions)

    def max_present(self, window: tuple[float, float] | None = None, lead_in: float = 0.0) -> int:
        """The most people present at once (a person is present from ``lead_in`` [s] before its first sample to its
        last sample, both included), within ``window`` = (start, end) [s] when given."""
        first, last = self.first - lead_in, self.last
        if window is not None:
            inside = (last >= window[0]) & (first <= window[1])
            first, last = np.maximum(first[inside], window[0]), np.minimum(last[inside], window[1])
        if len(first) == 0:
            return 0
        # the count is largest at some person's first time: those begun by then minus those ended before it
        begun = np.searchsorted(np.sort(first), first, side="right")
        ended = np.searchsorted(np.sort(last), first, side="left")
        return int((begun - ended).max())


def _segment_speeds(times: np.ndarray, positions: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(positions, axis=0), axis=-1) / np.diff(times)


class _Reader:
    """The samples of one file, checked line by line (every message starts with ``file:line``)."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.samples: dict[str, list[tuple[float, float, float, int]]] = {}  # id -> (t, x, y, line)

    def fail(self, line: int, message: str) -> ValueError:
        return ValueError(f"{self.path}:{line}: {message}")

    def number(self, line: int, column: str, text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise self.fail(line, f"{column} {text!r} is not a number") from None
        if not math.isfinite(value):
            raise self.fail(line, f"{column} is {text!r}: every time and coordinate must be finite")
        return value

    def add(self, line: int, person: str, t: float, x: float, y: float) -> None:
        for name, value in (("x", x), ("y", y)):
            if abs(value) > MAX_COORDINATE:
                raise self.fail(line, f"{name} = {value!r} is more than {MAX_COORDINATE:g} m from the origin: the "
                                      "positions must be in metres (pixels? millimetres?)")
        track = self.samples.setdefault(person, [])
        if track:
            t0, x0, y0, line0 = track[-1]
            if t <= t0:
                raise self.fail(line, f"person {person}'s time {t!r} s does not come after its sample at {t0!r} s on "
                                      f"line {line0}: each person's times must increase strictly")
            speed = math.hypot(x - x0, y - y0) / (t - t0)
            if speed > MAX_SPEED:
                raise self.fail(line, f"person {person} moves at {speed:.3g} m/s since line {line0}, faster than "
                                      f"{MAX_SPEED:g} m/s: the positions must be in metres and the times in seconds "
                                      "(a wrong frame_rate?)")
        track.append((t, x, y, line))

    def recording(self, frame_step: float | None) -> Recording:
        if not self.samples:
            raise ValueError(f"{self.path}: the recording has no samples")
        for person, track in self.samples.items():
            if len(track) < 2:
                raise self.fail(track[0][3], f"person {person} has one sample; a person needs two or more (a time "
                                             "to appear and one to vanish)")
        tracks = [np.array([s[:3] for s in track]) for track in self.samples.values()]
        return Recording(self.path, tuple(self.samples), tuple(t[:, 0].copy() for t in tracks),
                         tuple(t[:, 1:].copy() for t in tracks), frame_step)


def recording_format(path: str | os.PathLike) -> str:
    """``"csv"`` or ``"eth"``: the format :func:`read_recording` reads ``path`` in (by its extension, else its first
    line: a comma makes it a CSV)."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return "csv"
    with open(path, encoding="utf-8") as file:
        for text in file:
            if text.strip():
                return "csv" if "," in text else "eth"
    return "eth"


def read_recording(path: str | os.PathLike, frame_rate: float | None = None) -> Recording:
    """The recording at ``path``, checked (module docstring); ``frame_rate`` [frames/s] for the ETH/UCY text format
    only, where it is required.

    :raises ValueError: a bad recording (naming ``file:line``), ``frame_rate`` missing for the text format or given for
        a CSV
    """
    fmt = recording_format(path)
    name = os.fspath(path)
    if fmt == "csv":
        if frame_rate is not None:
            raise ValueError(f"frame_rate has no effect on the CSV recording {name} (its t column is in seconds); "
                             "pass frame_rate=None")
        return _read_csv(name)
    if frame_rate is None:
        raise ValueError(f"frame_rate [frames/s of the original video] is required for the ETH/UCY text recording "
                         f"{name}: the file does not say it (ETH 15, HOTEL and UCY 25; see the docs' replay page)")
    return _read_eth(name, frame_rate)


def _read_csv(path: str) -> Recording:
    reader = _Reader(path)
    with open(path, encoding="utf-8") as file:
        columns: list[str] | None = None
        for line, text in enumerate(file, start=1):
            if not text.strip():
                continue
            cells = [cell.strip() for cell in text.rstrip("\r\n").split(",")]
            if columns is None:
                unknown = [c for c in cells if c not in CSV_COLUMNS]
                missing = [c for c in CSV_COLUMNS if c not in cells]
                if unknown or missing or len(cells) != len(CSV_COLUMNS):
                    raise reader.fail(line, f"the header must name the columns {','.join(CSV_COLUMNS)} (in any order) "
                                            f"and no other; got {cells} (unknown {unknown}, missing {missing})")
                columns = cells
                continue
            if len(cells) != len(columns):
                raise reader.fail(line, f"expected {len(columns)} columns ({','.join(columns)}), got {len(cells)}")
            row = dict(zip(columns, cells, strict=True))
            if not row["id"]:
                raise reader.fail(line, "the id is empty")
            reader.add(line, row["id"], *(reader.number(line, c, row[c]) for c in ("t", "x", "y")))
    return reader.recording(None)


def _read_eth(path: str, frame_rate: float) -> Recording:
    reader = _Reader(path)
    frames = set()
    with open(path, encoding="utf-8") as file:
        for line, text in enumerate(file, start=1):
            cells = text.split()
            if not cells:
                continue
            if len(cells) != len(ETH_COLUMNS):
                raise reader.fail(line, f"expected {len(ETH_COLUMNS)} whitespace-separated columns "
                                        f"({' '.join(ETH_COLUMNS)}), got {len(cells)}")
            frame, person, x, y = (reader.number(line, c, v) for c, v in zip(ETH_COLUMNS, cells, strict=True))
            frames.add(frame)
            reader.add(line, f"{person:g}", frame / frame_rate, x, y)
    gaps = np.diff(np.sort(np.array(sorted(frames))))
    return reader.recording(float(gaps.min()) if len(gaps) else None)


def write_recording(path: str | os.PathLike, times: np.ndarray, positions: np.ndarray,
                    present: np.ndarray | None = None) -> None:
    """Write people's positions as a ``t,id,x,y`` CSV that :func:`read_recording` reads back exactly.

    Person ``j`` (its id is ``j``) is written at every time ``times[k]`` it is ``present[k, j]`` (everyone at every
    time when ``present`` is None); floats are written with ``repr``, so they read back bit for bit.

    :param times: (K,) [s], increasing
    :param positions: (K, n, 2) [m]
    :param present: (K, n) bool, or None
    """
    times = np.asarray(times, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[0] != len(times) or positions.shape[2] != 2:
        raise ValueError(f"positions must be (K, n, 2) with K = len(times) = {len(times)}, got {positions.shape}")
    present = np.ones(positions.shape[:2], dtype=bool) if present is None else np.asarray(present, dtype=bool)
    if present.shape != positions.shape[:2]:
        raise ValueError(f"present must be (K, n) = {positions.shape[:2]}, got {present.shape}")
    lines = [",".join(CSV_COLUMNS)]
    for t, row, here in zip(times.tolist(), positions.tolist(), present.tolist(), strict=True):
        lines += [f"{t!r},{j},{x!r},{y!r}" for j, ((x, y), h) in enumerate(zip(row, here, strict=True)) if h]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


__all__ = ["MAX_COORDINATE", "MAX_SPEED", "Recording", "read_recording", "recording_format", "write_recording"]
