"""Applying a :class:`DepthCalibration` to depth frames: fused numba kernels + numpy reference.

uint16 kernels (see :class:`~tofmetry.calibrate._model.CorrectionTables`): per pixel ``p`` one
16-byte entry of a 65 536-entry table (``d - R(d)``, the offset of the linear-form plane of the
node interval of ``d``, and ``d`` as float) and one 8-byte ``(b, a)`` pair:
``corrected = (d - R(d)) - (b d + a)``.
No temporaries, ``parallel=True``. Float input (e.g. averaged depth) interpolates the range
table linearly between integer mm (error < 1e-4 mm for any curve smooth at the mm scale)
and computes the surface weight exactly.

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


@nb.njit(parallel=True, cache=True)
def _apply_float(depth, r, k0t, k1t, nodes, lo, hi, surf, out):  # pragma: no cover - numba
    n = depth.shape[0]
    kk = nodes.shape[0]
    for i in nb.prange(n):
        d = depth[i]
        if not (d > 0.0):  # 0 or NaN: invalid, kept as is
            out[i] = d
            continue
        if d < lo or d > hi:
            out[i] = d
            continue
        j = int(np.floor(d))
        f = d - j
        j1 = j + 1 if j < 65535 else j
        rr = (1.0 - f) * r[j] + f * r[j1]
        if kk == 1:
            s = surf[0, i]
        else:
            jr = int(d + 0.5)
            k0 = k0t[jr] if k0t[jr] >= 0 else max(k0t[j], 0)
            # exact bracketing for non-integer d
            while k0 > 0 and d < nodes[k0]:
                k0 -= 1
            while k0 < kk - 2 and d >= nodes[k0 + 1]:
                k0 += 1
            w = (d - nodes[k0]) / (nodes[k0 + 1] - nodes[k0])
            w = min(max(w, 0.0), 1.0)
            s = (1.0 - w) * surf[k0, i] + w * surf[k0 + 1, i]
        out[i] = d - rr - s


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
    t = cal.tables
    if depth.dtype == np.uint16:
        flat = np.ascontiguousarray(depth).reshape(-1)
        out = np.empty(flat.shape, np.float32)
        _apply_u16(flat, t.lut_f, t.lut_i, t.coef, out)
        return out.reshape(depth.shape)
    if not np.issubdtype(depth.dtype, np.floating):
        if np.issubdtype(depth.dtype, np.integer):
            depth = depth.astype(np.float64)
        else:
            raise InputError(f"depth must be uint16 or float [mm], found dtype {depth.dtype}")
    flat = np.ascontiguousarray(depth, dtype=np.float64).reshape(-1)
    out = np.empty(flat.shape, np.float64)
    surf = cal.surfaces.reshape(cal.surfaces.shape[0], -1)
    lo, hi = cal.valid_range_mm
    _apply_float(flat, t.r, t.k0, t.k1, cal.node_mm, float(lo), float(hi), surf, out)
    return out.reshape(depth.shape)


def apply_depth_calibration_reference(depth: np.ndarray, cal: DepthCalibration) -> np.ndarray:
    """Straightforward numpy version of :func:`apply_depth_calibration` (for tests).

    Evaluates the B-spline directly. Returns (H, W) float64 [mm].
    """
    depth = _check(depth, cal)
    d = depth.astype(np.float64)
    valid = d > 0
    lo, hi = cal.valid_range_mm
    inside = valid & (d >= lo) & (d <= hi)
    out = d.copy()
    di = d[inside]
    k0, k1, w = cal.surface_weights(di)
    iy, ix = np.nonzero(inside)
    s = (1 - w) * cal.surfaces[k0, iy, ix].astype(np.float64) + w * cal.surfaces[k1, iy, ix].astype(np.float64)
    out[inside] = di - cal.range_error(di) - s
    return out


def count_outside_range(depth: np.ndarray, cal: DepthCalibration) -> int:
    """Number of valid pixels whose depth lies outside ``cal.valid_range_mm`` (left uncorrected)."""
    d = np.asarray(depth)
    lo, hi = cal.valid_range_mm
    with np.errstate(invalid="ignore"):
        return int(np.count_nonzero((d > 0) & ((d < lo) | (d > hi))))
