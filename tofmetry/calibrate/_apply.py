"""Applying a :class:`DepthCalibration` to depth frames: fused numba kernels + numpy reference.

The uint16 kernel reads, per pixel, one entry of each 65 536-entry table (range term, the
two bracketing surface indices and the lerp weight) and two float32 surface values: no
temporaries, ``parallel=True``. Float input (e.g. averaged depth) interpolates the range
table linearly between integer mm (error < 1e-4 mm for any curve smooth at the mm scale)
and computes the surface weight exactly.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from tofmetry.calibrate._model import DepthCalibration
from tofmetry.errors import InputError


@nb.njit(parallel=True, fastmath=True, cache=True)
def _apply_u16(depth, r, k0t, k1t, wt, surf, out):  # pragma: no cover - numba
    n = depth.shape[0]
    for i in nb.prange(n):
        d = depth[i]
        if d == 0:
            out[i] = 0.0
            continue
        k0 = k0t[d]
        if k0 < 0:
            out[i] = np.float32(d)
            continue
        w = wt[d]
        s = (np.float32(1.0) - w) * surf[k0, i] + w * surf[k1t[d], i]
        out[i] = np.float32(d) - r[d] - s


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
            k0 = k0t[jr] if k0t[jr] >= 0 else (k0t[j] if k0t[j] >= 0 else 0)
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
    surf = cal.surfaces.reshape(cal.surfaces.shape[0], -1)
    if depth.dtype == np.uint16:
        flat = np.ascontiguousarray(depth).reshape(-1)
        out = np.empty(flat.shape, np.float32)
        _apply_u16(flat, t.r, t.k0, t.k1, t.w, surf, out)
        return out.reshape(depth.shape)
    if not np.issubdtype(depth.dtype, np.floating):
        if np.issubdtype(depth.dtype, np.integer):
            depth = depth.astype(np.float64)
        else:
            raise InputError(f"depth must be uint16 or float [mm], found dtype {depth.dtype}")
    flat = np.ascontiguousarray(depth, dtype=np.float64).reshape(-1)
    out = np.empty(flat.shape, np.float64)
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


@nb.njit(parallel=True, cache=True)
def _count_rows(depth):  # pragma: no cover - numba
    h, w = depth.shape
    cnt = np.zeros(h, np.int64)
    for y in nb.prange(h):
        c = 0
        for x in range(w):
            if depth[y, x] != 0:
                c += 1
        cnt[y] = c
    return cnt


@nb.njit(parallel=True, fastmath=True, cache=True)
def _correct_backproject(depth, r, k0t, k1t, wt, surf, rays, start, out):  # pragma: no cover - numba
    h, w = depth.shape
    for y in nb.prange(h):
        j = start[y]
        for x in range(w):
            d = depth[y, x]
            if d == 0:
                continue
            i = y * w + x
            k0 = k0t[d]
            z = np.float32(d)
            if k0 >= 0:
                ww = wt[d]
                z = z - r[d] - ((np.float32(1.0) - ww) * surf[k0, i] + ww * surf[k1t[d], i])
            z = z * np.float32(0.001)
            out[j, 0] = rays[y, x, 0] * z
            out[j, 1] = rays[y, x, 1] * z
            out[j, 2] = z
            j += 1


def correct_and_backproject(depth: np.ndarray, cal: DepthCalibration, ray_table: np.ndarray,
                            out: np.ndarray | None = None) -> np.ndarray:
    """Correct a depth frame and back-project it in one pass.

    Parameters
    ----------
    depth : (H, W) uint16 [mm], 0 = invalid
    cal : DepthCalibration
    ray_table : (H, W, 2) normalised rays ``(x, y)`` (point = Z (x, y, 1)); pass float32
        (e.g. ``intr.ray_table().astype(np.float32)`` once) to avoid a conversion per call.
    out : optional (H*W, 3) float32 buffer reused across frames (a live stream): the result is then
        a view of its first N rows, and no memory is allocated per frame.

    Returns
    -------
    (N, 3) float32 [m], valid pixels in row-major order (same order as ``depth_to_points``).
    """
    depth = _check(depth, cal)
    if depth.dtype != np.uint16:
        raise InputError(f"correct_and_backproject: depth must be uint16 [mm], found {depth.dtype}")
    if ray_table.shape != (*depth.shape, 2):
        raise InputError(f"ray_table: expected shape {(*depth.shape, 2)}, found {ray_table.shape}")
    rays = np.ascontiguousarray(ray_table, dtype=np.float32)
    depth = np.ascontiguousarray(depth)
    cnt = _count_rows(depth)
    start = np.zeros(len(cnt), np.int64)
    np.cumsum(cnt[:-1], out=start[1:])
    n = int(cnt.sum())
    if out is None:
        out = np.empty((n, 3), np.float32)
    elif out.dtype != np.float32 or out.ndim != 2 or out.shape[1] != 3 or out.shape[0] < n or not out.flags.c_contiguous:
        raise InputError(f"out: expected a C-contiguous (>= {n}, 3) float32 buffer, found {out.shape} {out.dtype}")
    out = out[:n]
    t = cal.tables
    surf = cal.surfaces.reshape(cal.surfaces.shape[0], -1)
    _correct_backproject(depth, t.r, t.k0, t.k1, t.w, surf, rays, start, out)
    return out
