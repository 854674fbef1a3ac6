"""The files of a training run: written atomically, found again after any kill, one writer at a time.

Layout of a run folder ``OUT``:

- ``checkpoint_<N>.zip``: the model after N RL episodes (kept for every checkpoint);
- ``replay_buffer_<N>.npz``: its replay buffer (plain arrays; only the newest is kept);
- ``progress.json``: the newest checkpoint's counters (episodes, env steps, the wall time the run has used over all
  its segments, :class:`RunClock`), which checkpoints were validated, and ``finished``;
- ``eval_curve.jsonl``, ``best.json``, ``best.zip``: validation rows and the best checkpoint so far;
- ``imitation.zip`` / ``imitation_replay_buffer.npz``; ``final.zip``; ``run.lock`` while a process writes.

Every file is written under a temporary name in the folder and renamed (an atomic step on POSIX), so a
file either exists whole or not at all. The buffer of a checkpoint is written before the checkpoint, and
older buffers are removed only after that: the newest ``checkpoint_<N>.zip`` whose ``replay_buffer_<N>.npz``
exists is always a consistent pair, and a resumed run starts from it (:func:`latest_checkpoint`) even when
the process was killed before ``progress.json`` caught up. Nothing but the unfinished episodes is lost.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sb3_crowdnav.models import file_sha256

CHECKPOINT = re.compile(r"checkpoint_(\d+)\.zip")
LOCK = "run.lock"


class RunClock:
    """Wall time of a run over its segments: ``used`` seconds before this segment, plus this segment's so far."""

    def __init__(self, used: float = 0.0, start: float | None = None) -> None:
        self.used, self.start = float(used), time.perf_counter() if start is None else start

    def total(self) -> float:
        return self.used + time.perf_counter() - self.start


class RunLockedError(RuntimeError):
    """Another live process is writing to the same run folder."""


def atomic_write(path: Path, write: Callable[[Path], Any]) -> Path:
    """Call ``write(tmp)`` for a temporary name beside ``path``, then rename it to ``path``."""
    tmp = path.with_name(f".{path.name}.tmp{path.suffix}")
    write(tmp)
    os.replace(tmp, path)
    return path


def write_json(path: Path, value: Any) -> Path:
    return atomic_write(path, lambda tmp: tmp.write_text(json.dumps(value) + "\n"))


def read_json(path: Path) -> Any:
    return json.loads(path.read_text()) if path.exists() else None


sha256 = file_sha256  # the run folder's records use the package's one file hash


def checkpoint_path(out: Path, episodes: int) -> Path:
    return out / f"checkpoint_{episodes}.zip"


def buffer_path(out: Path, episodes: int) -> Path:
    return out / f"replay_buffer_{episodes}.npz"


def checkpoints(out: Path) -> list[int]:
    """Episode counts of the complete checkpoints in ``out``, ascending."""
    found = (CHECKPOINT.fullmatch(p.name) for p in out.glob("checkpoint_*.zip"))
    return sorted(int(m.group(1)) for m in found if m)


def latest_checkpoint(out: Path) -> tuple[int, bool] | None:
    """``(episodes, has_buffer)`` of the checkpoint to resume from: the newest with its replay buffer, else (a run
    moved without its buffers) the newest at all; None in a new run."""
    found = checkpoints(out)
    with_buffer = [n for n in found if buffer_path(out, n).exists()]
    if with_buffer:
        return with_buffer[-1], True
    return (found[-1], False) if found else None


def remove_stale(out: Path, keep: int) -> None:
    """Delete replay buffers other than ``keep``'s and temporary files left by a killed writer."""
    for path in out.glob("replay_buffer_*.npz"):
        if path != buffer_path(out, keep):
            path.unlink(missing_ok=True)
    for path in out.glob(".*.tmp*"):
        path.unlink(missing_ok=True)


class RunLock:
    """``run.lock`` in the folder, created exclusively; a lock whose process is gone (same host) is taken over."""

    def __init__(self, out: Path) -> None:
        self.path = out / LOCK
        self.owned = False

    def __enter__(self) -> RunLock:
        me = {"pid": os.getpid(), "host": socket.gethostname()}
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                holder = self._holder()
                if holder is not None and _alive(holder, me["host"]):
                    raise RunLockedError(f"{self.path.parent} is in use by process {holder.get('pid')} on "
                                         f"{holder.get('host')}; one run per folder (stop it, or use another --out)"
                                         ) from None
                self.path.unlink(missing_ok=True)  # left by a run that died: take it over
                continue
            with os.fdopen(fd, "w") as f:
                json.dump(me, f)
            self.owned = True
            return self
        raise RunLockedError(f"could not take {self.path}")

    def _holder(self) -> dict[str, Any] | None:
        try:
            return json.loads(self.path.read_text())
        except (OSError, ValueError):
            return None

    def __exit__(self, *exc: Any) -> None:
        if self.owned:
            self.path.unlink(missing_ok=True)
            self.owned = False


def _alive(holder: dict[str, Any], host: str) -> bool:
    if holder.get("host") != host:
        return True  # another machine's process cannot be checked: assume it runs
    try:
        os.kill(int(holder["pid"]), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, KeyError, TypeError, ValueError):
        return True
    return True


def kill_point(name: str) -> None:
    """Fault injection for tests: ``SB3_CROWDNAV_KILL_AT=name:k`` SIGKILLs this process at the k-th ``name``."""
    spec = os.environ.get("SB3_CROWDNAV_KILL_AT")
    if not spec or spec.rpartition(":")[0] != name:
        return
    count = _KILL_COUNTS[name] = _KILL_COUNTS.get(name, 0) + 1
    if count == int(spec.rpartition(":")[2]):
        os.kill(os.getpid(), signal.SIGKILL)


_KILL_COUNTS: dict[str, int] = {}


class SignalStop:
    """SIGTERM and SIGINT recorded while installed instead of acted on: a training loop asks :attr:`stopped_by` (the
    signal, or None) after each step, stops and writes its checkpoint; after the first signal the previous handlers
    are back, so a second one acts as usual."""

    def __init__(self) -> None:
        self.stopped_by: int | None = None
        self._previous: dict[int, Any] = {}

    def install(self) -> None:
        self._previous = {s: signal.signal(s, self._stop) for s in (signal.SIGTERM, signal.SIGINT)}

    def restore(self) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous = {}

    def _stop(self, signum: int, _frame: Any) -> None:
        self.stopped_by = signum
        self.restore()
