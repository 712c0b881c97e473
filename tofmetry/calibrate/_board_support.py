"""Board calibration support: error statistics, core-calibration helpers (:func:`core_correction`,
:func:`constant_shift_calibration`), sample support per image cell and range bin
(:func:`support_counts`, :func:`outside_support`) and the measured dark-square bias
(:class:`DarkBias`, :func:`fit_dark_bias`). Part of :mod:`tofmetry.calibrate.board`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofmetry.calibrate._board_samples import BoardSamples
from tofmetry.calibrate._model import DepthCalibration
from tofmetry.sensor.intrinsics import CameraIntrinsics


# ----------------------------------------------------------------------------- evaluation helpers
def error_stats(err_mm: np.ndarray) -> dict:
    """n, mean, std, RMS and 95th percentile of |e| [mm] of an error sample."""
    e = np.asarray(err_mm, float)
    if e.size == 0:
        return {"n": 0, "mean_mm": float("nan"), "std_mm": float("nan"), "rms_mm": float("nan"), "p95_abs_mm": float("nan")}
    return {"n": int(e.size), "mean_mm": float(e.mean()), "std_mm": float(e.std()),
            "rms_mm": float(np.sqrt(np.mean(e ** 2))), "p95_abs_mm": float(np.percentile(np.abs(e), 95))}


def core_correction(cal, u: np.ndarray, v: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
    """Correction [mm] (to add to measured Z) of a core ``DepthCalibration`` at pixels (u, v):
    exactly what applying the calibration to a depth image does (its model's definition)."""
    return -cal.correction_at(u, v, z_mm)[0]


def constant_shift_calibration(shift_mm: float, intrinsics: CameraIntrinsics, sensor: str = "kinect_v2",
                               provenance: dict | None = None):
    """A core ``DepthCalibration`` equal to a constant shift (iai_kinect2 ``depthShift``):
    zero surfaces and a constant range curve ``R = -shift`` (corrected = measured + shift)."""
    s = float(shift_mm)
    return DepthCalibration(
        sensor=sensor, intrinsics=intrinsics, range_knots=np.array([1.0, 1.0, 65535.0, 65535.0]),
        range_coeffs=np.array([-s, -s]), range_degree=1, range_data_mm=np.array([1.0, 65535.0]),
        valid_range_mm=np.array([1.0, 65535.0]), node_mm=np.array([1000.0]),
        surfaces=np.zeros((1, *intrinsics.shape), np.float32), offset_mm=-s, surface_model="none",
        provenance={"method": "constant depth shift", **(provenance or {})},
    )


def support_counts(u: np.ndarray, v: np.ndarray, z_mm: np.ndarray, shape: tuple[int, int], cell_px: int = 16,
                   bin_mm: float = 100.0, z_edges_mm: np.ndarray | None = None) -> dict:
    """Samples per image cell and range bin: the support a fit saw.

    Parameters
    ----------
    u, v : (N,) pixel coordinates; z_mm : (N,) measured Z [mm].
    shape : (H, W); cell_px : cell size [px]; bin_mm : range bin [mm] (measured Z).
    z_edges_mm : explicit range-bin edges (default: multiples of ``bin_mm`` covering the data).

    Returns
    -------
    dict: ``counts`` (Gv, Gu, Nr) int64, ``u_edges`` (Gu+1,), ``v_edges`` (Gv+1,) [px],
    ``z_edges_mm`` (Nr+1,) [mm], ``cell_px``, ``bin_mm``.
    """
    H, W = shape
    u = np.asarray(u)
    v = np.asarray(v)
    z = np.asarray(z_mm, float)
    ue = np.arange(0, W + cell_px, cell_px, dtype=float)
    ve = np.arange(0, H + cell_px, cell_px, dtype=float)
    if z_edges_mm is None:
        if z.size:
            lo, hi = np.floor(z.min() / bin_mm) * bin_mm, (np.floor(z.max() / bin_mm) + 1) * bin_mm
        else:
            lo, hi = 0.0, bin_mm
        z_edges_mm = np.arange(lo, hi + 0.5 * bin_mm, bin_mm)
    ze = np.asarray(z_edges_mm, float)
    counts, _ = np.histogramdd(np.column_stack([v, u, z]) if z.size else np.zeros((0, 3)), bins=(ve, ue, ze))
    return {"counts": counts.astype(np.int64), "u_edges": ue, "v_edges": ve, "z_edges_mm": ze, "cell_px": cell_px,
            "bin_mm": bin_mm}


def outside_support(support: dict, u: np.ndarray, v: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
    """(N,) bool: samples whose (image cell, range bin) holds no training sample."""
    ue, ve, ze, cnt = support["u_edges"], support["v_edges"], support["z_edges_mm"], support["counts"]
    iu = np.clip(np.searchsorted(ue, u, side="right") - 1, 0, len(ue) - 2)
    iv = np.clip(np.searchsorted(ve, v, side="right") - 1, 0, len(ve) - 2)
    iz = np.searchsorted(ze, z_mm, side="right") - 1
    inside = (iz >= 0) & (iz < len(ze) - 1)
    out = np.ones(len(np.atleast_1d(u)), bool)
    out[inside] = cnt[iv[inside], iu[inside], iz[inside]] == 0
    return out


# ----------------------------------------------------------------------------- dark squares
@dataclass
class DarkBias:
    """Dark-square depth bias [mm] as a function of the dark pixel's IR amplitude (measured).

    ``b(A)`` is piecewise linear in ``ln A`` on ``knots`` (constant beyond them: never
    extrapolated), fitted to the per-view contrasts ``median(dev_dark) - median(dev_white)``
    against the views' median ``ln A_dark``, on views where both parities are valid.

    Attributes
    ----------
    ln_knots, values_mm : (K,) knots in ln(amplitude) and bias at the knots [mm] (K = 0: unknown).
    contrast_mm, ln_amplitude : (V,) the measured per-view contrasts and amplitudes.
    residual_mm : RMS of the per-view contrasts about the fitted curve [mm].
    """

    ln_knots: np.ndarray
    values_mm: np.ndarray
    contrast_mm: np.ndarray
    ln_amplitude: np.ndarray
    residual_mm: float

    def __call__(self, amplitude: np.ndarray) -> np.ndarray:
        a = np.log(np.maximum(np.asarray(amplitude, float), 1.0))
        if len(self.ln_knots) == 0:
            return np.full(a.shape, np.nan)
        if len(self.ln_knots) == 1:
            return np.full(a.shape, float(self.values_mm[0]))
        return np.interp(a, self.ln_knots, self.values_mm)

    @property
    def known(self) -> bool:
        return len(self.ln_knots) > 0

    def to_dict(self) -> dict:
        return {"amplitude_knots": np.exp(self.ln_knots).tolist(), "bias_mm": self.values_mm.tolist(),
                "views": len(self.contrast_mm), "residual_mm": self.residual_mm,
                "contrast_mm": self.contrast_mm.tolist(), "amplitude": np.exp(self.ln_amplitude).tolist()}


def fit_dark_bias(samples: list[BoardSamples], max_knots: int = 3) -> DarkBias:
    """:class:`DarkBias` from views holding at least 50 valid pixels of each parity."""
    c, la = [], []
    for s in samples:
        if s.white.sum() >= 50 and s.dark.sum() >= 50:
            dev = s.measured_mm - s.reference_mm
            c.append(float(np.median(dev[s.dark]) - np.median(dev[s.white])))
            la.append(float(np.median(np.log(np.maximum(s.amplitude[s.dark], 1.0)))))
    c, la = np.array(c), np.array(la)
    if c.size == 0:
        return DarkBias(np.zeros(0), np.zeros(0), c, la, float("nan"))
    K = int(min(max_knots, max(1, c.size // 4)))
    if K == 1 or np.ptp(la) < 1e-6:
        val = np.array([float(np.median(c))])
        return DarkBias(np.array([float(np.median(la))]), val, c, la, float(np.sqrt(np.mean((c - val[0]) ** 2))))
    knots = np.quantile(la, np.linspace(0, 1, K))
    knots = np.unique(knots)
    fz = np.clip(np.interp(la, knots, np.arange(len(knots))), 0, len(knots) - 1 - 1e-9)
    k0 = np.floor(fz).astype(int)
    a = fz - k0
    A = np.zeros((c.size, len(knots)))
    A[np.arange(c.size), k0] += 1 - a
    A[np.arange(c.size), k0 + 1] += a
    vals = np.linalg.lstsq(A, c, rcond=None)[0]
    res = float(np.sqrt(np.mean((A @ vals - c) ** 2)))
    return DarkBias(knots, vals, c, la, res)
