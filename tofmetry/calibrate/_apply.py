"""Applying a :class:`DepthCalibration` to depth frames: fused numba kernels + numpy reference.

uint16 kernels (see :class:`~tofmetry.calibrate._model.CorrectionTables`): per pixel ``p`` one
8-byte entry of a 65 536-entry table (``R(d)`` and the offset of the linear-form plane of the
node interval of ``d``) and one 8-byte ``(b, a)`` pair: ``corrected = d - (b d + (a + R(d)))``.
No temporaries, ``parallel=True``. Float input (e.g. averaged depth) interpolates the range
table linearly between integer mm (error < 1e-4 mm for any curve smooth at the mm scale)
and computes the surface weight exactly.

Streaming (one frame after another): :class:`FrameCorrector` holds everything kernel-ready
(tables, float32 rays, an output buffer) so a call is one kernel launch; each thread of the
kernel counts the valid pixels before its block itself (no separate counting pass). Measured
with ``python -m bench.run`` (benchmark 1).
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
        d = depth[i]
        t2 = np.uint64(d) * np.uint64(2)
        q = (np.uint64(lut_i[t2 + np.uint64(1)]) + np.uint64(i)) * np.uint64(2)
        df = np.float32(d)
        out[i] = df - (coef[q] * df + (coef[q + np.uint64(1)] + lut_f[t2]))


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


# Relative cost of counting a pixel (vectorised) to correcting + writing it, measured on the
# 2-core benchmark machine (~0.14 ns vs ~2 ns): used only to balance the blocks of the threads.
_COUNT_COST = 0.07


@nb.njit(fastmath=True, cache=True)
def _count_valid(depth, p1):  # pragma: no cover - numba
    """Number of non-zero entries of ``depth[:p1]`` (vectorised: 16-bit lane counters)."""
    total = np.uint64(0)
    p = np.uint64(0)
    while p < p1:
        e = min(p1, p + np.uint64(32768))
        c = np.uint16(0)
        for k in range(p, e):
            c += np.uint16(depth[k] != 0)
        total += np.uint64(c)
        p = e
    return total


@nb.njit(parallel=True, fastmath=True, cache=True)
def _correct_backproject(depth, lut_f, lut_i, coef, rays, out, nthreads):  # pragma: no cover - numba
    """Fused correction + back-projection; returns the number N of points written.

    depth (H*W,) uint16 [mm]; lut_f, lut_i, coef: :class:`CorrectionTables` arrays; rays (2*H*W,)
    float32 interleaved (x, y); out (>= 3 N,) float32 interleaved (x, y, z) [m]. One block of
    pixels per thread; each block first counts the valid pixels before it (a vectorised pass)
    to know where its points start, and the later blocks are made shorter to pay for that.
    ``nthreads`` = ``numba.get_num_threads()`` (not callable here: it would prevent caching).
    Flat arrays with constant strides and unsigned indices keep the loop free of multiplies
    and negative-index checks.
    """
    npix = depth.shape[0]
    nb_ = max(1, min(nthreads, 64, npix // 4096 + 1))  # blocks of >= ~4096 pixels
    ends = np.empty(nb_, np.uint64)
    keep = 1.0 - _COUNT_COST
    for c in nb.prange(nb_):
        # block starts s_c = N (1 - keep^c) / (1 - keep^nb): equal count + work per block
        p0 = np.uint64(npix * (1.0 - keep ** c) / (1.0 - keep ** nb_)) if c > 0 else np.uint64(0)
        p1 = np.uint64(npix * (1.0 - keep ** (c + 1)) / (1.0 - keep ** nb_)) if c < nb_ - 1 else np.uint64(npix)
        j = _count_valid(depth, p0) * np.uint64(3)
        for i in range(p0, p1):
            d = depth[i]
            if d == 0:
                continue
            t2 = np.uint64(d) * np.uint64(2)
            q = (np.uint64(lut_i[t2 + np.uint64(1)]) + i) * np.uint64(2)
            df = np.float32(d)
            z = (df - (coef[q] * df + (coef[q + np.uint64(1)] + lut_f[t2]))) * np.float32(0.001)
            i2 = i * np.uint64(2)
            out[j] = rays[i2] * z
            out[j + np.uint64(1)] = rays[i2 + np.uint64(1)] * z
            out[j + np.uint64(2)] = z
            j += np.uint64(3)
        ends[c] = j
    return ends[nb_ - 1] // np.uint64(3)


def _check_rays(ray_table: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    if ray_table.shape != (*shape, 2):
        raise InputError(f"ray_table: expected shape {(*shape, 2)}, found {ray_table.shape}")
    return np.ascontiguousarray(ray_table, dtype=np.float32).reshape(-1)


def _check_out(out: np.ndarray, n: int) -> None:
    if (not isinstance(out, np.ndarray) or out.dtype != np.float32 or out.ndim != 2 or out.shape[1] != 3
            or out.shape[0] < n or not out.flags.c_contiguous or not out.flags.writeable):
        raise InputError(f"out: expected a writeable C-contiguous (>= {n}, 3) float32 buffer, "
                         f"found {getattr(out, 'shape', None)} {getattr(out, 'dtype', type(out).__name__)}")


def correct_and_backproject(depth: np.ndarray, cal: DepthCalibration, ray_table: np.ndarray,
                            out: np.ndarray | None = None) -> np.ndarray:
    """Correct a depth frame and back-project it in one pass.

    Parameters
    ----------
    depth : (H, W) uint16 [mm], 0 = invalid
    cal : DepthCalibration
    ray_table : (H, W, 2) normalised rays ``(x, y)`` (point = Z (x, y, 1)); pass float32
        (e.g. ``intr.ray_table().astype(np.float32)`` once) to avoid a conversion per call.
    out : optional (M, 3) float32 C-contiguous buffer reused across frames (a live stream): the
        result is then a view of its first N rows, and no memory is allocated per frame. With
        M >= H*W no counting pass is needed; a smaller M is accepted if it holds the N points.

    Returns
    -------
    (N, 3) float32 [m], valid (non-zero) pixels in row-major order (same order as
    ``depth_to_points``). For a stream, :class:`FrameCorrector` does the same with the per-call
    checks and conversions done once.
    """
    depth = _check(depth, cal)
    if depth.dtype != np.uint16:
        raise InputError(f"correct_and_backproject: depth must be uint16 [mm], found {depth.dtype}")
    rays = _check_rays(ray_table, depth.shape)
    flat = np.ascontiguousarray(depth).reshape(-1)
    if out is None:
        out = np.empty((int(np.count_nonzero(flat)), 3), np.float32)
    else:  # a buffer of H*W rows always suffices; a smaller one needs the count
        big = isinstance(out, np.ndarray) and out.ndim == 2 and out.shape[0] >= flat.shape[0]
        _check_out(out, 0 if big else int(np.count_nonzero(flat)))
    t = cal.tables
    n = int(_correct_backproject(flat, t.lut_f, t.lut_i, t.coef, rays, out.reshape(-1), nb.get_num_threads()))
    return out[:n]


class FrameCorrector:
    """Prepared per-frame pipeline for a stream: correct + undistort + back-project.

    Holds the kernel-ready tables of ``cal``, the float32 ray table and one (H*W, 3) float32
    output buffer, so each call does only a dtype/shape check and one kernel launch. Same
    result as :func:`correct_and_backproject`. One corrector per consumer thread (the buffer
    is reused by every call).

    Parameters
    ----------
    cal : DepthCalibration
    ray_table : optional (H, W, 2) normalised rays; default ``cal.intrinsics.ray_table()``
        (undistorted rays of the intrinsics the calibration was fitted with).

    Attributes
    ----------
    buffer : (H*W, 3) float32, the default output buffer
    rays : (2*H*W,) float32 interleaved ``(x, y)`` rays
    n_threads : int, pixel blocks per frame (``numba.get_num_threads()`` at construction; set
        it again after ``numba.set_num_threads``; any value gives the same result)

    Examples
    --------
    >>> fc = FrameCorrector(cal)                          # doctest: +SKIP
    >>> for depth in frames:                              # doctest: +SKIP
    ...     pts = fc(depth)        # (N, 3) float32 [m], a view of fc's buffer
    ...     consume(pts)           # copy it (pts.copy()) to keep it past the next call
    """

    def __init__(self, cal: DepthCalibration, ray_table: np.ndarray | None = None) -> None:
        self.cal = cal
        self.shape = cal.shape
        if ray_table is None:
            ray_table = cal.intrinsics.ray_table()
        self.rays = _check_rays(np.asarray(ray_table), self.shape).copy()
        t = cal.tables
        self._lut_f, self._lut_i, self._coef = t.lut_f, t.lut_i, t.coef
        self.buffer = np.empty((self.shape[0] * self.shape[1], 3), np.float32)
        # blocks per frame (one per thread); numba.get_num_threads() costs ~2 us per call
        self.n_threads = nb.get_num_threads()

    def __call__(self, depth: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Points of one frame.

        Parameters
        ----------
        depth : (H, W) uint16 [mm], 0 = invalid
        out : optional (>= H*W, 3) float32 C-contiguous buffer; default: the corrector's own
            buffer (the result is then overwritten by the next call).

        Returns
        -------
        (N, 3) float32 [m], a view of the first N rows of the buffer, row-major pixel order.
        """
        if not isinstance(depth, np.ndarray) or depth.dtype != np.uint16 or depth.shape != self.shape:
            raise InputError(f"FrameCorrector: depth must be a {self.shape} uint16 image [mm], found "
                             f"{getattr(depth, 'shape', None)} {getattr(depth, 'dtype', type(depth).__name__)}")
        if out is None:
            out = self.buffer
        else:
            _check_out(out, depth.size)
        if not depth.flags.c_contiguous:
            depth = np.ascontiguousarray(depth)
        n = _correct_backproject(depth.reshape(-1), self._lut_f, self._lut_i, self._coef, self.rays, out.reshape(-1),
                                 self.n_threads)
        return out[:n]
