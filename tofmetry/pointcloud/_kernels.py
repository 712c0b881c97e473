"""numba kernels for per-pixel temporal statistics of uint16 depth stacks.

One pass over the stack, parallel over pixel blocks (not over frames: a (T, H*W) uint16 stack
has a frame stride that is a multiple of 4096 B, so a per-pixel loop across frames thrashes the
cache sets; we walk a block of pixels frame by frame instead). Sums are shifted by the first valid
sample of each pixel, so they stay noise-sized and float32 accumulators are exact to ~1e-4 mm over
hundreds of frames (unshifted float32 sums of squares would be wrong by ~1 mm: cancellation).
"""

from __future__ import annotations

import numba
import numpy as np

_BLOCK = 2048


@numba.njit(parallel=True, cache=True, fastmath=False)
def _stack_stats(stack, mean, std, count):  # pragma: no cover - compiled
    T = stack.shape[0]
    N = stack.shape[1]
    nblocks = (N + _BLOCK - 1) // _BLOCK
    for b in numba.prange(nblocks):
        lo = b * _BLOCK
        hi = min(N, lo + _BLOCK)
        n = hi - lo
        shift = np.zeros(n, np.float32)
        s1 = np.zeros(n, np.float32)
        s2 = np.zeros(n, np.float32)
        c = np.zeros(n, np.float32)  # float: keeps the inner loop free of int/float conversions (SIMD)
        # shift = first valid sample of each pixel (usually frame 0)
        for k in range(n):
            for t in range(T):
                v = stack[t, lo + k]
                if v > 0:
                    shift[k] = v
                    break
        # branch-free accumulation of shifted sums (values are noise-sized: float32 is exact enough)
        for t in range(T):
            row = stack[t, lo:hi]
            for k in range(n):
                v = np.float32(row[k])
                w = np.float32(1.0) if v > 0 else np.float32(0.0)
                x = (v - shift[k]) * w
                s1[k] += x
                s2[k] += x * x
                c[k] += w
        for k in range(n):
            ck = c[k]
            count[lo + k] = np.int32(ck)
            if ck > 0:
                m1 = np.float64(s1[k]) / ck
                mean[lo + k] = shift[k] + m1
                if ck > 1:
                    var = (np.float64(s2[k]) - ck * m1 * m1) / (ck - 1)
                    std[lo + k] = np.sqrt(var) if var > 0 else 0.0
                else:
                    std[lo + k] = np.nan
            else:
                mean[lo + k] = np.nan
                std[lo + k] = np.nan


def stack_stats(stack: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel mean, std (ddof=1) and valid count of a depth stack, zeros ignored.

    Parameters
    ----------
    stack : (T, H, W) uint16 [mm], 0 = invalid

    Returns
    -------
    mean : (H, W) float32 [mm] (NaN where no valid sample)
    std : (H, W) float32 [mm] (NaN where fewer than 2 valid samples)
    count : (H, W) int32
    """
    st = np.ascontiguousarray(stack)
    if st.dtype != np.uint16 or st.ndim != 3:
        raise ValueError(f"stack_stats: expected (T, H, W) uint16, found {st.shape} {st.dtype}")
    T, H, W = st.shape
    flat = st.reshape(T, H * W)
    mean = np.empty(H * W, np.float32)
    std = np.empty(H * W, np.float32)
    count = np.empty(H * W, np.int32)
    _stack_stats(flat, mean, std, count)
    return mean.reshape(H, W), std.reshape(H, W), count.reshape(H, W)
