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


class CopyReference:
    """A large array copy, the memory-bandwidth reference: ``gbs()`` times one ``np.copyto`` of
    ``size_bytes`` (one thread) and returns the bytes copied per second [GB/s];
    ``gbs_threads()`` does the same copy split over the numba threads."""

    def __init__(self, size_bytes: int = 1 << 30) -> None:
        import numpy as np

        from bench._kernels import parallel_copy

        self.src = np.ones(size_bytes, dtype=np.uint8)
        self.dst = np.empty_like(self.src)
        np.copyto(self.dst, self.src)  # first touch: page faults are not bandwidth
        parallel_copy(self.dst[:4096], self.src[:4096], 1)  # compile once, outside any timing
        self.size = size_bytes

    def gbs(self) -> float:
        import numpy as np

        t0 = time.perf_counter()
        np.copyto(self.dst, self.src)
        return self.size / (time.perf_counter() - t0) / 1e9

    def gbs_threads(self) -> float:
        import numba

        from bench._kernels import parallel_copy

        n = numba.get_num_threads()
        t0 = time.perf_counter()
        parallel_copy(self.dst, self.src, n)
        return self.size / (time.perf_counter() - t0) / 1e9
