"""Per-pixel moments of depth frames, combined exactly across chunks (Welford + Chan's parallel merge).

A long recording is split into chunks of frames, each measured on its own worker; the chunks'
moments ``(count, mean, M2)`` merge into the moments of the whole recording with the parallel
variance formula of Chan, Golub & LeVeque (1979). This is exact algebra, not an approximation: the
merged mean and variance equal the one-pass ones up to floating-point rounding (about 1e-12 mm
for depths in mm), whatever the chunk boundaries. Depth 0 (or NaN) is "no measurement" and is
not counted, as in :class:`tofmetry.pointcloud.RunningDepthStats`.

Pure functions on arrays; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from tofmetry.errors import InputError
from tofmetry.pointcloud import TemporalStats


@dataclass
class Moments:
    """Per-pixel moments of the valid samples of a run of frames.

    Attributes
    ----------
    count : (H, W) int64, valid samples per pixel
    mean : (H, W) float64 [mm], mean of the valid samples (0 where count == 0)
    m2 : (H, W) float64 [mm^2], sum of squared deviations from ``mean``
    n_frames : int, frames accumulated (valid or not)
    """

    count: np.ndarray
    mean: np.ndarray
    m2: np.ndarray
    n_frames: int = 0

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> "Moments":
        """Moments of no frame, for (H, W) frames."""
        return cls(np.zeros(shape, np.int64), np.zeros(shape, np.float64), np.zeros(shape, np.float64), 0)

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.count.shape)

    def update(self, frame: np.ndarray) -> None:
        """Add one (H, W) depth frame [mm] in place (Welford's update; 0 / NaN = invalid)."""
        d = np.asarray(frame, np.float64)
        if d.shape != self.shape:
            raise InputError(f"frame {self.n_frames}: shape {d.shape} differs from {self.shape}")
        valid = d > 0
        self.count += valid
        delta = np.where(valid, d - self.mean, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            self.mean += np.where(valid, delta / np.maximum(self.count, 1), 0.0)
        self.m2 += np.where(valid, delta * (d - self.mean), 0.0)
        self.n_frames += 1

    def std(self) -> np.ndarray:
        """(H, W) float64 sample std [mm] (ddof=1), NaN where fewer than 2 samples."""
        c = self.count.astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(c > 1, np.sqrt(np.maximum(self.m2, 0.0) / (c - 1)), np.nan)

    def to_temporal(self) -> TemporalStats:
        """The same statistics as :class:`~tofmetry.pointcloud.TemporalStats` (mean NaN where no sample)."""
        return TemporalStats(mean=np.where(self.count > 0, self.mean, np.nan), std=self.std(),
                             count=self.count.astype(np.int32), n_frames=self.n_frames)


def frame_moments(frames: Iterable[np.ndarray], shape: tuple[int, int]) -> Moments:
    """Moments of a run of (H, W) depth frames [mm] (streamed, one frame in memory at a time).

    Parameters
    ----------
    frames : iterable of (H, W) uint16 / float depth [mm]; 0 or NaN = invalid
    shape : (H, W)

    Returns
    -------
    Moments
    """
    m = Moments.empty(shape)
    for f in frames:
        m.update(f)
    return m


def merge_moments(a: Moments, b: Moments) -> Moments:
    """Moments of two runs of frames taken together (Chan et al.'s parallel variance formula).

    ``n = na + nb``, ``delta = mean_b - mean_a``, ``mean = mean_a + delta nb / n``,
    ``M2 = M2_a + M2_b + delta^2 na nb / n``, per pixel. Order does not matter (up to rounding).

    Parameters
    ----------
    a, b : Moments of the same (H, W)

    Returns
    -------
    Moments (new arrays)
    """
    if a.shape != b.shape:
        raise InputError(f"merge_moments: chunks of different frame sizes {a.shape} and {b.shape}")
    na, nb = a.count.astype(np.float64), b.count.astype(np.float64)
    n = na + nb
    delta = b.mean - a.mean
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(n > 0, nb / n, 0.0)
        mean = a.mean + delta * share
        m2 = a.m2 + b.m2 + np.where(n > 0, delta * delta * na * share, 0.0)
    return Moments(a.count + b.count, mean, m2, a.n_frames + b.n_frames)


def merge_all(parts: Iterable[Moments]) -> Moments:
    """Merge the moments of several chunks (pairwise, in the given order).

    Raises
    ------
    InputError
        No chunk given.
    """
    parts = list(parts)
    if not parts:
        raise InputError("merge_all: no chunk moments to merge")
    out = parts[0]
    for p in parts[1:]:
        out = merge_moments(out, p)
    return out
