"""Applying a :class:`DepthCalibration` to depth frames: fused numba kernels + numpy reference.

uint16 kernels (see :mod:`._tables`): per pixel ``p`` one 16-byte entry of a 65 536-entry table
(``d - R(dh)``, the offset of the linear-form plane of ``dh``'s node interval, ``dh`` as float,
the ray-term switch) and one 8-byte ``(b, a)`` pair: ``corrected = (d - R(dh)) - (b dh + a)``,
minus ``dh**gamma V(dh rho)`` for a calibration with a ray term (one more 8-byte table entry,
cache resident, and the pixel's ``rho``). No temporaries, ``parallel=True``.
Float input (e.g. averaged depth) is corrected with the model's numpy definition
(:meth:`DepthCalibration.correction`).

The fused correction + back-projection of a frame stream is in :mod:`._backproject`.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from tofmetry.calibrate._model import DepthCalibration
from tofmetry.errors import InputError


@nb.njit(parallel=True, fastmath=True, cache=True)
def _apply_u16(depth, lut_f, lut_i, coef, out):  # pragma: no cover - numba
    n = depth.shape[0]
    for i in nb.prange(n):
        t4 = np.uint64(depth[i]) * np.uint64(4)
        q = (np.uint64(lut_i[t4 + np.uint64(1)]) + np.uint64(i)) * np.uint64(2)
        out[i] = lut_f[t4] - (coef[q] * lut_f[t4 + np.uint64(2)] + coef[q + np.uint64(1)])


@nb.njit(inline="always")
def ray_term(rho, dh, ray_w, q0, nmax):  # pragma: no cover - numba
    """``V(dh rho)`` from the tables (see :mod:`._tables`; linear in each mm of ray length,
    clamped). Signed 32-bit conversions: one instruction each way on x86, where unsigned
    64-bit ones are not."""
    t = min(max(dh * rho - q0, np.float32(0.0)), nmax)
    j = np.int32(t)
    f = t - np.float32(j)
    j2 = np.int64(j) * 2
    return ray_w[j2] + f * ray_w[j2 + 1]


@nb.njit(parallel=True, fastmath=True, cache=True)
def _apply_u16_ray(depth, lut_f, lut_i, coef, ray_w, q0, nmax, pix, out):  # pragma: no cover - numba
    n = depth.shape[0]
    for i in nb.prange(n):
        t4 = np.uint64(depth[i]) * np.uint64(4)
        q = (np.uint64(lut_i[t4 + np.uint64(1)]) + np.uint64(i)) * np.uint64(2)
        dh = lut_f[t4 + np.uint64(2)]
        z = lut_f[t4] - (coef[q] * dh + coef[q + np.uint64(1)])
        out[i] = z - lut_f[t4 + np.uint64(3)] * ray_term(pix[i], dh, ray_w, q0, nmax)


def _check(depth: np.ndarray, cal: DepthCalibration) -> np.ndarray:
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise InputError(f"depth must be an (H, W) image, found shape {depth.shape}")
    cal.check_compatible(shape=depth.shape)
    return depth


def apply_depth_calibration(depth: np.ndarray, cal: DepthCalibration) -> np.ndarray:
    """Correct one depth image with the fused kernel.

    Parameters
    ----------
    depth : (H, W) uint16 [mm] (0 = invalid) or float [mm] (0/NaN = invalid)
    cal : DepthCalibration

    Returns
    -------
    (H, W) float32 [mm] for uint16 input, float64 [mm] for float input. Invalid pixels stay
    0 (or NaN); pixels outside ``cal.valid_range_mm`` are returned unchanged.
    """
    depth = _check(depth, cal)
    if depth.dtype == np.uint16:
        t = cal.tables
        flat = np.ascontiguousarray(depth).reshape(-1)
        out = np.empty(flat.shape, np.float32)
        if t.has_ray:
            _apply_u16_ray(flat, t.lut_f, t.lut_i, t.coef, t.ray_w, np.float32(t.ray_q0), t.ray_tmax, t.pix_rho, out)
        else:
            _apply_u16(flat, t.lut_f, t.lut_i, t.coef, out)
        return out.reshape(depth.shape)
    if not np.issubdtype(depth.dtype, np.floating):
        if np.issubdtype(depth.dtype, np.integer):
            depth = depth.astype(np.float64)
        else:
            raise InputError(f"depth must be uint16 or float [mm], found dtype {depth.dtype}")
    d = np.asarray(depth, np.float64)
    corr, _ = cal.correction(d)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(d) & (d > 0), d - corr, d)


def apply_depth_calibration_reference(depth: np.ndarray, cal: DepthCalibration) -> np.ndarray:
    """Straightforward numpy version of :func:`apply_depth_calibration` (for tests): the model's
    definition :meth:`DepthCalibration.correction`. Returns (H, W) float64 [mm]."""
    depth = _check(depth, cal)
    d = depth.astype(np.float64)
    corr, _ = cal.correction(d)
    return np.where(d > 0, d - corr, d)


def count_outside_range(depth: np.ndarray, cal: DepthCalibration) -> int:
    """Number of valid pixels (depth > 0) outside the calibration's support: outside the pixel's
    supported depth interval, or outside ``valid_range_mm`` for a calibration without a support.
    These pixels get the fallback (or no correction)."""
    d = np.asarray(depth)
    if cal.support is not None:
        return cal.support.count_outside(d)
    lo, hi = cal.valid_range_mm
    with np.errstate(invalid="ignore"):
        return int(np.count_nonzero((d > 0) & ((d < lo) | (d > hi))))
