"""Warm-up (pre-heating) drift of the depth measurement (study §3.2).

The sensor looks at a static wall while frames are recorded at intervals (study: one every
15 s for 90 min). A small patch is followed over time: the patch of highest IR amplitude
(the sensor is not exactly parallel to the wall, so the nearest, best-lit spot is not
necessarily at the centre), or, without IR, the patch of smallest depth. Its mean depth
against the operating time is smoothed by local linear regression, and the time after
which the smoothed curve stays within a tolerance of its final level is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from tofmetry.assess._source import capture_ir, check_frame, frame_iter, is_capture
from tofmetry.errors import EstimationError, InputError


@dataclass
class WarmupResult:
    """Result of :func:`assess_warmup`.

    Attributes
    ----------
    time_s : (T,) float64 [s], time since the first frame
    distance_mm : (T,) float64 [mm], mean depth of the patch per frame (NaN if the patch was empty)
    smoothed_mm : (T,) float64 [mm], local-linear smoothed distance
    patch : (u0, v0, size) top-left pixel and side of the followed patch [px]
    patch_source : "ir_max" or "depth_min" (the latter when the capture has no IR)
    final_level_mm : float, median of the smoothed curve over the final window
    stabilisation_time_s : float or None, time after which |smoothed - final| <= tolerance for good
    total_drift_mm : float, final level - smoothed value at the first frame (signed)
    drift_range_mm : float, max - min of the smoothed curve
    residual_drift_mm : float, peak-to-peak of the smoothed curve after stabilisation (whole curve if never stable)
    stable_confirmed : bool, stabilisation happened before the final window began
    stabilisation_range_s : (t at 1.1 x tolerance, t at 0.9 x tolerance): sensitivity of the
        stabilisation time to the tolerance; a wide range means the curve hovers near the
        tolerance (e.g. an overshoot of about the tolerance when the fan starts)
    notes : list of str, warnings for the user (fallbacks, short recording...)
    """

    time_s: np.ndarray
    distance_mm: np.ndarray
    smoothed_mm: np.ndarray
    patch: tuple[int, int, int]
    patch_source: str
    tolerance_mm: float
    smooth_window_s: float
    final_window_s: float
    final_level_mm: float
    stabilisation_time_s: float | None
    total_drift_mm: float
    drift_range_mm: float
    residual_drift_mm: float
    stable_confirmed: bool
    stabilisation_range_s: tuple = (None, None)
    t0_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "analysis": "warmup",
            "patch": {"u0": self.patch[0], "v0": self.patch[1], "size": self.patch[2], "source": self.patch_source},
            "tolerance_mm": self.tolerance_mm, "smooth_window_s": self.smooth_window_s,
            "final_window_s": self.final_window_s, "final_level_mm": self.final_level_mm,
            "stabilisation_time_s": self.stabilisation_time_s,
            "stabilisation_time_min": None if self.stabilisation_time_s is None else self.stabilisation_time_s / 60.0,
            "stabilisation_range_s": list(self.stabilisation_range_s),
            "total_drift_mm": self.total_drift_mm, "drift_range_mm": self.drift_range_mm,
            "residual_drift_mm": self.residual_drift_mm, "stable_confirmed": self.stable_confirmed,
            "t0_s": self.t0_s, "n_frames": int(len(self.time_s)), "duration_s": float(self.time_s[-1]),
            "notes": list(self.notes),
            "series": {"time_s": self.time_s, "distance_mm": self.distance_mm, "smoothed_mm": self.smoothed_mm},
        }


def _box_sums(img: np.ndarray, size: int) -> np.ndarray:
    """Sums over all size x size windows: (H - size + 1, W - size + 1), indexed by top-left corner."""
    c = np.pad(np.cumsum(np.cumsum(img, axis=0), axis=1), ((1, 0), (1, 0)))
    return c[size:, size:] - c[:-size, size:] - c[size:, :-size] + c[:-size, :-size]


def select_patch(depth: np.ndarray, ir: np.ndarray | None, size: int = 10) -> tuple[tuple[int, int, int], str]:
    """Choose the followed patch.

    Parameters
    ----------
    depth : (H, W) depth [mm] of one frame (patch must be fully valid in it)
    ir : (H, W) IR amplitude or None
    size : patch side [px]

    Returns
    -------
    ((u0, v0, size), source) with source "ir_max" (highest mean amplitude) or "depth_min".
    """
    h, w = depth.shape
    if not 1 <= size <= min(h, w):
        raise InputError(f"patch size must be within 1..{min(h, w)} px, found {size}")
    valid = (np.asarray(depth) > 0).astype(np.float64)
    full = _box_sums(valid, size) >= size * size
    if not full.any():
        raise EstimationError(f"no {size}x{size} patch with valid depth everywhere in the first frame")
    if ir is not None:
        if ir.shape != depth.shape:
            raise InputError(f"IR image shape {ir.shape} differs from the depth shape {depth.shape}")
        score = np.where(full, _box_sums(np.asarray(ir, np.float64), size), -np.inf)
        v0, u0 = np.unravel_index(np.argmax(score), score.shape)
        return (int(u0), int(v0), size), "ir_max"
    score = np.where(full, _box_sums(np.asarray(depth, np.float64), size), np.inf)
    v0, u0 = np.unravel_index(np.argmin(score), score.shape)
    return (int(u0), int(v0), size), "depth_min"


def local_linear_smooth(t: np.ndarray, y: np.ndarray, window_s: float) -> np.ndarray:
    """Local linear regression with tricube weights (LOWESS without robustness steps).

    Parameters
    ----------
    t : (T,) float [s], increasing
    y : (T,) float (NaN ignored)
    window_s : full width of the kernel [s]; unbiased for linear trends, also at the ends.

    Returns
    -------
    (T,) float; where fewer than 3 samples fall inside the window, the kernel is widened to
    the 3 nearest samples (all NaN only if fewer than 3 valid samples exist).
    """
    t = np.asarray(t, np.float64)
    y = np.asarray(y, np.float64)
    out = np.full_like(y, np.nan)
    ok = np.isfinite(y)
    h0 = max(window_s / 2.0, 1e-9)
    if ok.sum() < 3:
        return out
    for i, ti in enumerate(t):
        dist = np.abs(t - ti)
        # widen the kernel where it holds fewer than 3 samples (ends, gaps, coarse sampling)
        h = max(h0, np.partition(dist[ok], 2)[2] * 1.001 + 1e-9)
        r = dist / h
        m = ok & (r < 1.0)
        wgt = (1 - r[m] ** 3) ** 3
        x = t[m] - ti
        sw, sx, sxx = wgt.sum(), (wgt * x).sum(), (wgt * x * x).sum()
        sy, sxy = (wgt * y[m]).sum(), (wgt * x * y[m]).sum()
        det = sw * sxx - sx * sx
        out[i] = sy / sw if det <= 1e-12 * sw * sw * h * h else (sxx * sy - sx * sxy) / det
    return out


def _stable_after(t: np.ndarray, dev: np.ndarray, tol: float) -> float | None:
    """First time after which ``dev <= tol`` for good (NaN counts as outside); None if never."""
    outside = np.flatnonzero(~(dev <= tol))
    if outside.size == 0:
        return float(t[0])
    if outside[-1] == t.size - 1:
        return None
    return float(t[outside[-1] + 1])


def assess_warmup(source, timestamps_s=None, *, ir: np.ndarray | None = None, patch: int = 10,
                  tolerance_mm: float = 1.0, smooth_window_s: float | None = None, final_window_s: float = 600.0,
                  progress: Callable[[], None] | None = None) -> WarmupResult:
    """Warm-up drift of a static wall recording.

    Parameters
    ----------
    source : Capture or (T, H, W) uint16 array / iterable of (H, W) depth frames [mm]
        Frames are streamed (a capture is never loaded whole).
    timestamps_s : (T,) float [s], optional
        Frame times; taken from the capture if omitted. Required.
    ir : (H, W) IR amplitude, optional
        For the patch selection; the capture's mean IR if omitted. Without IR the patch of
        smallest depth is used (noted in the result).
    patch : int
        Side of the followed square patch [px] (study: 10).
    tolerance_mm : float
        The curve is "stable" once it stays within this distance of its final level.
    smooth_window_s : float, optional
        Width of the local-linear smoothing kernel [s]; default ``max(120 s, 5 x median
        frame interval)``. A 10x10 patch mean is precise to ~0.15 mm per frame, so 8 frames
        (15 s sampling) give ~0.06 mm; the kernel must stay short against the fastest
        feature of the curve (the fan start: a kink relaxing in ~4 min), which a wider
        kernel flattens (a 180 s kernel lowered the simulated fan overshoot by ~0.08 mm).
    final_window_s : float
        The final level is the median of the smoothed curve over this last stretch [s].
    progress : callable, optional
        Called once per frame.

    Returns
    -------
    WarmupResult
    """
    notes: list[str] = []
    if timestamps_s is None and is_capture(source):
        timestamps_s = getattr(source, "timestamps_s", None)
    if timestamps_s is None:
        raise InputError("warm-up needs frame timestamps: capture.json has no 'timestamps_s' "
                         "(expected one time in seconds per depth frame)")
    ts = np.asarray(timestamps_s, dtype=np.float64).ravel()
    if ts.size < 3:
        raise InputError(f"warm-up needs at least 3 timestamped frames, found {ts.size}")
    if not np.all(np.isfinite(ts)) or np.any(np.diff(ts) <= 0):
        raise InputError("timestamps_s must be finite and strictly increasing")
    if smooth_window_s is None:
        smooth_window_s = max(120.0, 5.0 * float(np.median(np.diff(ts))))
    if tolerance_mm <= 0 or smooth_window_s <= 0 or final_window_s <= 0:
        raise InputError("tolerance_mm, smooth_window_s and final_window_s must be positive")
    ir_img = capture_ir(source, ir)
    dist = np.full(ts.size, np.nan)
    sel = None
    n = 0
    for i, frame in enumerate(frame_iter(source, progress)):
        if i >= ts.size:
            raise InputError(f"more frames than timestamps ({ts.size})")
        f = check_frame(frame, None if ir_img is None else ir_img.shape, i, "warm-up")
        if sel is None:
            (u0, v0, s), src = select_patch(f, ir_img, patch)
            sel = (u0, v0, s)
            if src == "depth_min":
                notes.append("no IR amplitude available: followed the patch of smallest depth instead of highest IR")
        p = f[sel[1]:sel[1] + sel[2], sel[0]:sel[0] + sel[2]].astype(np.float64)
        good = p > 0
        if good.sum() >= max(1, p.size // 2):
            dist[i] = p[good].mean()
        n += 1
    if n != ts.size:
        raise InputError(f"{ts.size} timestamps for {n} frames")
    return warmup_from_series(ts, dist, sel, "ir_max" if ir_img is not None else "depth_min", tolerance_mm=tolerance_mm,
                              smooth_window_s=smooth_window_s, final_window_s=final_window_s, notes=notes)


def warmup_from_series(timestamps_s: np.ndarray, distance_mm: np.ndarray, patch: tuple[int, int, int], patch_source: str,
                       *, tolerance_mm: float, smooth_window_s: float | None, final_window_s: float,
                       notes: list[str] | None = None) -> WarmupResult:
    """The warm-up analysis of a patch-distance series (the second half of :func:`assess_warmup`).

    Lets the series be measured in pieces (e.g. chunks of a long recording on several workers,
    concatenated in frame order) and analysed once, with the same result as one pass.

    Parameters
    ----------
    timestamps_s : (T,) float [s], strictly increasing frame times
    distance_mm : (T,) float [mm], mean depth of the patch per frame (NaN: patch less than half valid)
    patch : (u0, v0, size) of the followed patch [px]
    patch_source : "ir_max" or "depth_min"
    tolerance_mm, smooth_window_s, final_window_s : as in :func:`assess_warmup` (> 0; smooth_window_s None:
        the same default)
    notes : notes gathered so far (extended, not copied)

    Returns
    -------
    WarmupResult
    """
    ts = np.asarray(timestamps_s, np.float64)
    dist = np.asarray(distance_mm, np.float64)
    if ts.shape != dist.shape or ts.ndim != 1:
        raise InputError(f"warm-up series: {ts.shape} timestamps for {dist.shape} distances (expected two equal (T,) arrays)")
    notes = [] if notes is None else notes
    if smooth_window_s is None:
        smooth_window_s = max(120.0, 5.0 * float(np.median(np.diff(ts))))
    sel = tuple(int(x) for x in patch)
    t = ts - ts[0]
    if np.isnan(dist).sum() > 0:
        notes.append(f"{int(np.isnan(dist).sum())} frame(s) with less than half of the patch valid were skipped")
    duration = float(t[-1])
    if final_window_s >= duration / 2:
        final_window_s = duration / 4
        notes.append(f"recording short for the final window: final level taken over the last {final_window_s:.0f} s")
    sm = local_linear_smooth(t, dist, smooth_window_s)
    if np.isnan(sm).all():
        raise EstimationError("too few valid samples to smooth the distance curve (check the patch and smoothing window)")
    tail = t >= duration - final_window_s
    final = float(np.nanmedian(sm[tail]))
    dev = np.abs(sm - final)
    t_stab = _stable_after(t, dev, tolerance_mm)
    if t_stab is None:
        notes.append(f"the smoothed distance never stays within {tolerance_mm} mm of its final level")
    t_range = (_stable_after(t, dev, 1.1 * tolerance_mm), _stable_after(t, dev, 0.9 * tolerance_mm))
    first = sm[np.flatnonzero(np.isfinite(sm))[0]]
    after = sm[t >= t_stab] if t_stab is not None else sm
    confirmed = t_stab is not None and t_stab < duration - final_window_s
    if t_stab is not None and not confirmed:
        notes.append("stabilisation only reached within the final window: record longer to confirm it")
    return WarmupResult(
        time_s=t, distance_mm=dist, smoothed_mm=sm, patch=sel, patch_source=patch_source,
        tolerance_mm=float(tolerance_mm), smooth_window_s=float(smooth_window_s), final_window_s=float(final_window_s),
        final_level_mm=final, stabilisation_time_s=t_stab, total_drift_mm=float(final - first),
        drift_range_mm=float(np.nanmax(sm) - np.nanmin(sm)),
        residual_drift_mm=float(np.nanmax(after) - np.nanmin(after)),
        stable_confirmed=bool(confirmed), stabilisation_range_s=t_range, t0_s=float(ts[0]), notes=notes,
    )
