"""Process-wide CPU settings that make the small networks of this package fast (opt-in).

Nothing here runs on import: these calls change the whole process, so the entry point
(a training script, the CLI, a benchmark) decides.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

import torch as th

_M_TRIM_THRESHOLD = -1  # glibc mallopt parameters (malloc.h)
_M_MMAP_THRESHOLD = -3


def tune_malloc(trim_threshold: int = 512 << 20, mmap_threshold: int = 64 << 20) -> bool:
    """Keep freed tensor memory in the process instead of returning it to the OS (glibc only).

    A forward pass allocates activation tensors of a few MB; by default glibc gives that
    memory back at every free and the next pass page-faults it in again. For the APG encoder on
    80 states that is about 800 page faults and a third of the CPU time per pass
    (``benchmarks/network_speed.py --no-tune-malloc`` shows it). Memory held: at most
    ``trim_threshold`` bytes of freed heap.

    :param trim_threshold: free heap kept at the top before trimming [bytes]
    :param mmap_threshold: allocations at least this large use their own mmap [bytes]
    :return: whether the settings were applied (False on non-glibc platforms)
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))) and bool(
            libc.mallopt(_M_TRIM_THRESHOLD, int(trim_threshold))
        )
    except (OSError, AttributeError):
        return False


def configure_cpu(num_threads: int = 1, malloc: bool = True) -> None:
    """One torch intra-op thread (much faster than two for these networks on small shared CPUs) and :func:`tune_malloc`."""
    th.set_num_threads(num_threads)
    if malloc:
        tune_malloc()
