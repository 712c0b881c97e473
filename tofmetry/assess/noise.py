"""Temporal noise and frame averaging (study §3.2, Figure 3).

From N frames of a static scene: per-pixel temporal std maps over the first n frames for
n = 10, 25, 50, 100 (subsets <= N), their summary (median, spread, corner/centre ratio),
a row profile (Fig. 3c), a recommended n, and the precision of the n-frame *mean* depth
measured as its std across disjoint blocks (what averaging buys, about sigma / sqrt(n)).
Frames are streamed; only the block means (N / n maps) are kept.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.special import gammaincinv

from tofmetry.assess._source import check_frame, frame_iter, n_frames
from tofmetry.errors import InputError
from tofmetry.pointcloud import RunningDepthStats

DEFAULT_SUBSETS = (10, 25, 50, 100)
DEFAULT_BLOCKS = (1, 5, 10, 25, 50)


@dataclass
class StdSummary:
    """Summary of one std map [mm] (valid pixels only)."""

    n: int
    median_mm: float
    spread_mm: float      # robust spread: 1.4826 * MAD of the std map
    p05_mm: float
    p95_mm: float
    corner_mm: float      # median std in the four corner blocks (10 % x 10 % of the image)
    centre_mm: float      # median std in the central block (20 % x 20 %)
    corner_centre_ratio: float
    sampling_spread_mm: float  # spread expected from sampling alone: median / sqrt(2 (n - 1))
    sigma_mm: float = float("nan")  # median std corrected for the chi bias of n samples (Gaussian)

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class NoiseResult:
    """Result of :func:`assess_noise`.

    Attributes
    ----------
    std_maps : dict n -> (H, W) float64 [mm], temporal std over the first n frames (NaN invalid)
    summaries : list of StdSummary, one per n
    row : int, image row of the profile
    profiles : dict n -> (W,) float64 [mm], std along ``row``
    recommended_n : int, smallest n beyond which the std map stops becoming more uniform
    block_precision : list of dict(n, n_blocks, std_of_mean_mm, expected_mm, ratio): std of the
        n-frame mean across disjoint blocks (chi-square corrected median over pixels) against sigma/sqrt(n)
    sigma_single_mm : float, single-frame sigma over all N frames (chi-square corrected median)
    mean_depth_mm : (H, W) float64, mean over all frames
    """

    n_frames: int
    shape: tuple[int, int]
    std_maps: dict
    summaries: list
    row: int
    profiles: dict
    recommended_n: int
    recommendation_reason: str
    block_precision: list
    sigma_single_mm: float
    mean_depth_mm: np.ndarray
    min_gain: float
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "analysis": "noise", "n_frames": self.n_frames, "shape": list(self.shape),
            "subsets": [s.n for s in self.summaries], "summaries": [s.to_dict() for s in self.summaries],
            "row": self.row, "profiles": {str(k): v for k, v in self.profiles.items()},
            "recommended_n": self.recommended_n, "recommendation_reason": self.recommendation_reason,
            "min_gain": self.min_gain, "block_precision": self.block_precision,
            "sigma_single_mm": self.sigma_single_mm, "notes": list(self.notes),
        }


def sigma_from_stds(std: np.ndarray, n: int) -> float:
    """Noise sigma [mm] from per-pixel sample stds of ``n`` samples: median, chi-square corrected.

    ``(n-1) s^2 / sigma^2`` follows chi-square with n - 1 dof, so the median of s^2 is
    ``sigma^2 * median(chi2_{n-1}) / (n - 1)``; the median makes it robust to outlier pixels.
    The chi-square median is ``2 P^-1(k / 2, 1 / 2)`` (inverse regularised lower incomplete gamma).
    """
    v = np.asarray(std, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0 or n < 2:
        return float("nan")
    chi2_median = 2.0 * gammaincinv((n - 1) / 2.0, 0.5)
    return float(math.sqrt(np.median(v * v) * (n - 1) / chi2_median))


def summarize_std_map(std: np.ndarray, n: int) -> StdSummary:
    """Summary statistics of a temporal std map (see :class:`StdSummary`)."""
    h, w = std.shape
    v = std[np.isfinite(std)]
    if v.size == 0:
        nan = float("nan")
        return StdSummary(n, nan, nan, nan, nan, nan, nan, nan, nan)
    med = float(np.median(v))
    mad = float(np.median(np.abs(v - med))) * 1.4826
    ch, cw = max(1, h // 10), max(1, w // 10)
    corners = np.concatenate([std[:ch, :cw].ravel(), std[:ch, -cw:].ravel(), std[-ch:, :cw].ravel(), std[-ch:, -cw:].ravel()])
    centre = std[int(h * 0.4):int(math.ceil(h * 0.6)), int(w * 0.4):int(math.ceil(w * 0.6))].ravel()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        c_mm = float(np.nanmedian(corners)) if np.isfinite(corners).any() else float("nan")
        m_mm = float(np.nanmedian(centre)) if np.isfinite(centre).any() else float("nan")
    p05, p95 = np.percentile(v, [5, 95])
    return StdSummary(
        n=n, median_mm=med, spread_mm=mad, p05_mm=float(p05), p95_mm=float(p95), corner_mm=c_mm, centre_mm=m_mm,
        corner_centre_ratio=c_mm / m_mm if m_mm > 0 else float("nan"),
        sampling_spread_mm=med / math.sqrt(2 * (n - 1)), sigma_mm=sigma_from_stds(v, n),
    )


def recommend_n(summaries: list[StdSummary], min_gain: float = 0.15) -> tuple[int, str]:
    """Smallest n after which the std map stops becoming more uniform.

    Uniformity is measured by the robust spread of the std map. Going from n_k to the next
    subset n_{k+1}, the spread falls by sampling alone as 1/sqrt(n) (about 30-40 % per
    step here) as long as sampling scatter dominates; once the map is dominated by the real
    spatial pattern of the noise (corners noisier than the centre), the fall becomes small.
    The recommended n is the first n_k whose step to n_{k+1} reduces the spread by less
    than ``min_gain`` (relative); if every step still gains, the largest n.
    """
    if len(summaries) == 1:
        return summaries[0].n, "only one subset size available"
    for a, b in zip(summaries[:-1], summaries[1:]):
        if not (a.spread_mm > 0):
            return a.n, f"std map already uniform at n={a.n}"
        gain = (a.spread_mm - b.spread_mm) / a.spread_mm
        if gain < min_gain:
            return a.n, (f"going from n={a.n} to n={b.n} reduces the spread of the std map by only "
                         f"{gain * 100:.0f} % (< {min_gain * 100:.0f} %)")
    last = summaries[-1]
    return last.n, f"the spread still falls by >= {min_gain * 100:.0f} % per step up to n={last.n}"


def assess_noise(source, *, subsets=DEFAULT_SUBSETS, row: int | None = None, block_sizes=DEFAULT_BLOCKS,
                 min_gain: float = 0.15, progress: Callable[[], None] | None = None) -> NoiseResult:
    """Temporal noise and the effect of frame averaging on a static scene.

    Parameters
    ----------
    source : Capture or (T, H, W) array / iterable of (H, W) depth frames [mm] (streamed)
    subsets : ints
        Numbers of frames n for the std maps (the first n frames); sizes above N are dropped
        (if all are, N itself is used).
    row : int, optional
        Image row of the profile (default: the middle row).
    block_sizes : ints
        Block lengths n for the precision of the n-frame mean (needs >= 2 disjoint blocks).
    min_gain : float
        See :func:`recommend_n`.

    Returns
    -------
    NoiseResult
    """
    total = n_frames(source)
    if total is not None and total < 2:
        raise InputError(f"noise analysis needs at least 2 frames of a static scene, found {total}")
    wanted = sorted({int(n) for n in subsets if int(n) >= 2})
    if not wanted:
        raise InputError(f"subsets must contain sizes >= 2, found {list(subsets)}")
    blocks = sorted({int(b) for b in block_sizes if int(b) >= 1})
    rs = None
    snaps: dict[int, np.ndarray] = {}
    block_stats: dict[int, RunningDepthStats] = {}
    block_acc: dict[int, tuple[np.ndarray, np.ndarray, int]] = {}
    shape = None
    n = 0
    for i, frame in enumerate(frame_iter(source, progress)):
        f = check_frame(frame, shape, i, "noise")
        if shape is None:
            shape = f.shape
            rs = RunningDepthStats(shape)
            block_stats = {b: RunningDepthStats(shape) for b in blocks}
            block_acc = {b: (np.zeros(shape), np.zeros(shape, np.int32), 0) for b in blocks}
        rs.update(f)
        n += 1
        if n in wanted:
            snaps[n] = rs.result().std
        fv = f.astype(np.float64)
        for b in blocks:
            s, c, k = block_acc[b]
            s += fv
            c += fv > 0
            k += 1
            if k == b:
                # block mean only where every frame of the block was valid (no bias from dropouts)
                block_stats[b].update(np.where(c == b, s / b, 0.0))
                s[:] = 0
                c[:] = 0
                k = 0
            block_acc[b] = (s, c, k)
    if n < 2:
        raise InputError(f"noise analysis needs at least 2 frames of a static scene, found {n}")
    block_stds = []
    for b in blocks:
        st = block_stats[b]
        if st.n >= 2:
            res = st.result()
            block_stds.append((b, st.n, res.std[res.count == st.n]))
    return noise_result_from(n, shape, rs.result(), snaps, wanted, row, min_gain, block_stds)


def noise_result_from(n: int, shape: tuple[int, int], full, snaps: dict[int, np.ndarray], wanted: list[int],
                      row: int | None, min_gain: float, block_stds: list) -> NoiseResult:
    """The :class:`NoiseResult` of ``n`` frames from their accumulated statistics (one pass or merged chunks).

    Parameters
    ----------
    n : frames; shape : (H, W)
    full : the per-pixel statistics of all frames (``TemporalStats``: ``std``, ``mean_depth_mm()``)
    snaps : {k: (H, W) std map of the first k frames [mm]}, for the sizes ``wanted`` reached
    wanted : the requested sizes (>= 2); row : profile row (None: the middle row)
    block_stds : [(b, n_blocks, (M,) std [mm] of the b-frame block means at pixels valid in every block)]
    """
    notes = []
    snaps = dict(snaps)
    if not snaps:
        snaps[n] = full.std
        notes.append(f"only {n} frames: std map over all of them (subsets {wanted} need more frames)")
    elif max(wanted) > n:
        notes.append(f"subsets larger than the {n} frames were skipped: {[w for w in wanted if w > n]}")
    sizes = sorted(snaps)
    summaries = [summarize_std_map(snaps[k], k) for k in sizes]
    h, w = shape
    r = h // 2 if row is None else int(row)
    if not 0 <= r < h:
        raise InputError(f"row {r} outside the image rows 0..{h - 1}")
    rec, reason = recommend_n(summaries, min_gain)
    sigma1 = sigma_from_stds(full.std, n)
    prec = []
    for b, nb, stds in block_stds:
        m = sigma_from_stds(stds, nb)
        prec.append({"n": b, "n_blocks": nb, "std_of_mean_mm": m, "expected_mm": sigma1 / math.sqrt(b),
                     "ratio": m / (sigma1 / math.sqrt(b)) if sigma1 > 0 else float("nan")})
    return NoiseResult(
        n_frames=n, shape=(h, w), std_maps=snaps, summaries=summaries, row=r,
        profiles={k: snaps[k][r].copy() for k in sizes}, recommended_n=rec, recommendation_reason=reason,
        block_precision=prec, sigma_single_mm=sigma1, mean_depth_mm=full.mean_depth_mm(), min_gain=min_gain,
        notes=notes,
    )
