"""Timing helpers: median of repeated runs after warm-up; peak RSS."""

from __future__ import annotations

import resource
import statistics
import time
from typing import Callable


def median_time(fn: Callable[[], object], repeat: int = 30, warmup: int = 3, min_time_s: float = 0.0) -> float:
    """Median wall time [s] of ``fn()`` over ``repeat`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    times = []
    t_end = time.perf_counter() + min_time_s
    while len(times) < repeat or time.perf_counter() < t_end:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def peak_rss_mb() -> float:
    """Peak resident set size of this process [MiB] (Linux ru_maxrss is in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def memory_bandwidth_gbs(size_bytes: int = 1 << 30, repeat: int = 5) -> float:
    """Copy bandwidth [GB/s]: bytes copied per second by ``np.copyto`` of a ``size_bytes`` array."""
    import numpy as np

    src = np.ones(size_bytes, dtype=np.uint8)
    dst = np.empty_like(src)
    t = median_time(lambda: np.copyto(dst, src), repeat=repeat, warmup=1)
    return size_bytes / t / 1e9
