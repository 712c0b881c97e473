"""Temporal statistics of depth sequences, ignoring invalid (0) samples.

Streaming: :class:`RunningDepthStats` accumulates frame by frame in float64 (shifted sums,
no cancellation), so a long sequence never has to sit in memory.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

from tofmetry.errors import InputError


@dataclass
class TemporalStats:
    """Per-pixel statistics over T frames.

    Attributes
    ----------
    mean : (H, W) float64 [mm], NaN where count == 0
    std : (H, W) float64 [mm], sample std (ddof=1), NaN where count < 2
    count : (H, W) int32, number of valid (non-zero) samples
    median : (H, W) float64 [mm] or None (only from :func:`temporal_stats` with ``median=True``)
    n_frames : int
    """

    mean: np.ndarray
    std: np.ndarray
    count: np.ndarray
    n_frames: int
    median: np.ndarray | None = None

    def mean_depth_mm(self, min_count: int = 1) -> np.ndarray:
        """Mean depth as (H, W) float64 mm with 0 where fewer than ``min_count`` samples."""
        m = np.where(self.count >= min_count, self.mean, 0.0)
        return np.nan_to_num(m, nan=0.0)


class RunningDepthStats:
    """Accumulate per-pixel mean/std of depth frames, zeros ignored (one ``update`` per frame)."""

    def __init__(self, shape: tuple[int, int]):
        self.shape = tuple(shape)
        self.n = 0
        self._shift = None
        self._s1 = np.zeros(shape, np.float64)
        self._s2 = np.zeros(shape, np.float64)
        self._cnt = np.zeros(shape, np.int32)

    def update(self, depth: np.ndarray) -> None:
        """Add one (H, W) uint16/float frame [mm]; 0/NaN = invalid."""
        if depth.shape != self.shape:
            raise InputError(f"frame {self.n}: shape {depth.shape} differs from {self.shape}")
        d = depth.astype(np.float64)
        valid = d > 0  # NaN compares False
        if self._shift is None:
            self._shift = np.where(valid, d, 0.0)
            self._shift_set = valid.copy()
        else:
            newly = valid & ~self._shift_set
            if newly.any():
                # pixels first seen now: their shift must be set before any sum is taken
                self._shift[newly] = d[newly]
                self._shift_set |= newly
        x = np.where(valid, d - self._shift, 0.0)
        self._s1 += x
        self._s2 += x * x
        self._cnt += valid
        self.n += 1

    def result(self) -> TemporalStats:
        c = self._cnt.astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            m1 = self._s1 / c
            mean = np.where(c > 0, (self._shift if self._shift is not None else 0) + m1, np.nan)
            var = (self._s2 - c * m1 * m1) / (c - 1)
            std = np.where(c > 1, np.sqrt(np.maximum(var, 0.0)), np.nan)
        return TemporalStats(mean=mean, std=std, count=self._cnt.copy(), n_frames=self.n)


def temporal_stats(frames, median: bool = False) -> TemporalStats:
    """Per-pixel mean, std, count (and optionally median) of depth frames, zeros ignored.

    Parameters
    ----------
    frames : (T, H, W) array or iterable of (H, W) uint16/float [mm]
    median : bool
        Also compute the per-pixel median (needs the whole stack in memory).

    Returns
    -------
    TemporalStats
    """
    it = iter(frames)
    try:
        first = np.asarray(next(it))
    except StopIteration:
        raise InputError("temporal_stats: no frames given") from None
    if first.ndim != 2:
        raise InputError(f"temporal_stats: frames must be (H, W), found shape {first.shape}")
    rs = RunningDepthStats(first.shape)
    rs.update(first)
    keep = [first] if median else None
    for f in it:
        f = np.asarray(f)
        rs.update(f)
        if keep is not None:
            keep.append(f)
    res = rs.result()
    if median:
        st = np.stack(keep).astype(np.float64)
        st[st <= 0] = np.nan
        with np.errstate(all="ignore"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                res.median = np.nanmedian(st, axis=0)
    return res


def _nan_median(a: np.ndarray, cnt: np.ndarray) -> np.ndarray:
    """Median over axis 0 of an array whose invalid samples are NaN, by sorting (NaN sorts last)."""
    srt = np.sort(a, axis=0)
    lo = np.clip((cnt - 1) // 2, 0, None)[None]
    hi = np.clip(cnt // 2, 0, None)[None]
    return 0.5 * (np.take_along_axis(srt, lo, 0)[0] + np.take_along_axis(srt, hi, 0)[0])


def robust_mean_depth(stack: np.ndarray, k: float = 3.0, min_count: int = 1, *,
                      correct: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Temporal mean with outlier rejection: the mean of the samples within
    median +- k * max(1.4826 MAD, 0.5 mm), zeros ignored (0.5 mm: the quantisation floor of integer mm).

    Parameters
    ----------
    stack : (T, H, W) uint16/float [mm]
    k : float
        Rejection threshold in robust standard deviations.
    min_count : int
        Pixels with fewer surviving samples are 0.
    correct : optional ``correct(frame) -> corrected frame [mm]`` applied to every (H, W) frame
        first (a depth calibration's kernel: the mean of the corrected frames keeps their
        sub-millimetre values); it must keep invalid pixels at 0 (or NaN).

    Returns
    -------
    (H, W) float64 [mm], 0 where fewer than ``min_count`` samples survive.
    """
    if correct is not None:
        stack = np.stack([correct(f) for f in np.asarray(stack)])
    st = np.asarray(stack, dtype=np.float64)
    if st.ndim != 3 or st.shape[0] == 0:
        raise InputError(f"robust_mean_depth: expected (T, H, W) with T >= 1, found {st.shape}")
    st = np.where(st > 0, st, np.nan)
    cnt = np.sum(~np.isnan(st), axis=0)
    med = _nan_median(st, cnt)
    mad = np.maximum(_nan_median(np.abs(st - med), cnt) * 1.4826, 0.5)
    with np.errstate(invalid="ignore"):
        keep = np.abs(st - med) <= k * mad
    n = keep.sum(axis=0)
    s = np.where(keep, st, 0.0).sum(axis=0)
    return np.where((n >= min_count) & (cnt > 0), s / np.maximum(n, 1), 0.0)
