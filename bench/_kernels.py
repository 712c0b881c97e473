"""numba helpers of the benchmarks (not part of the library)."""

from __future__ import annotations

import numba as nb


@nb.njit(parallel=True, cache=True)
def parallel_copy(dst, src, nthreads):  # pragma: no cover - numba
    """``dst[:] = src`` in ``nthreads`` contiguous blocks, one per thread (uint8 arrays)."""
    n = src.shape[0]
    for c in nb.prange(nthreads):
        a = n * c // nthreads
        b = n * (c + 1) // nthreads
        dst[a:b] = src[a:b]
