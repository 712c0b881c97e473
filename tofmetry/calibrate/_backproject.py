"""Streaming correction + back-projection: uint16 depth frame -> (N, 3) float32 points [m].

One fused numba kernel per frame (range table, per-pixel linear-form surface term, undistorted
ray table, compaction of the valid pixels), no temporaries, ``parallel=True``: one block of
pixels per thread, and each thread counts the valid pixels before its block itself (a
vectorised pass) to know where its points start. :class:`FrameCorrector` holds everything
kernel-ready (tables, float32 rays, an output buffer), so a call is one kernel launch.

Measured with ``python -m bench.run`` (benchmark 1); the README gives the figures.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from tofmetry.calibrate._simd_store import store_point4
from tofmetry.calibrate._apply import _check, ray_term
from tofmetry.calibrate._model import DepthCalibration
from tofmetry.errors import InputError

# Relative cost of counting a pixel (vectorised) to correcting + writing it, measured on the
# 2-core benchmark machine (~0.2 ns vs ~3 ns per pixel and thread): used only to balance the
# blocks of the threads.
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


@nb.njit(inline="always")
def _z(i, plane, lut_f, coef, t4):  # pragma: no cover - numba
    """Corrected depth [m] of pixel ``i`` with raw depth ``d`` [mm], ``t4 = 4 d``, in the
    linear-form plane at offset ``plane`` (``lut_i[t4 + 1]``): ``((d - R(d)) - (b d + a)) / 1000``."""
    q = (plane + i) * np.uint64(2)
    return (lut_f[t4] - (coef[q] * lut_f[t4 + np.uint64(2)] + coef[q + np.uint64(1)])) * np.float32(0.001)


@nb.njit(inline="always")
def _z_px(i, d, lut_f, lut_i, coef, rays, stride, ray_w, q0, nmax, with_ray):  # pragma: no cover - numba
    """Corrected depth [m] of pixel ``i`` with raw depth ``d`` [mm]: :func:`_z`, minus the ray term
    ``dh**gamma V(dh rho) / 1000`` when ``with_ray`` (``rho`` is the third value of the pixel's
    record in ``rays``, see :mod:`._tables`)."""
    t4 = np.uint64(d) * np.uint64(4)
    z = _z(i, np.uint64(lut_i[t4 + np.uint64(1)]), lut_f, coef, t4)
    if with_ray:
        w = ray_term(rays[i * stride + np.uint64(2)], lut_f[t4 + np.uint64(2)], ray_w, q0, nmax)
        z -= lut_f[t4 + np.uint64(3)] * w * np.float32(0.001)
    return z


@nb.njit(fastmath=True, cache=True, inline="never")
def _correct_backproject_block(depth, lut_f, lut_i, coef, rays, stride, out, p0, p1, j, ray_w, q0, nmax,
                               with_ray):  # pragma: no cover - numba
    """Pixels ``p0 .. p1-1`` of :func:`_correct_backproject`, points written from ``out[j]``;
    returns the index after the last value written.

    Every point but the block's last is written by one 16-byte store
    (:func:`~tofmetry.calibrate._simd_store.store_point4`), whose scratch fourth lane the next point of
    this block overwrites; the last point is written with three 4-byte stores, so nothing lands
    past it (the next block belongs to another thread, the buffer may end there). A function
    of its own (not inlined into the parallel loop), so that LLVM keeps the base pointers in
    registers: about 17 instructions and one store per pixel without a ray term. ``with_ray`` is
    the same for every pixel: the branch is hoisted out of the loop.

    ``ray_term`` is imported from :mod:`._apply`: numba caches a kernel by its own file, so after
    editing ``ray_term`` touch this file too (or clear ``__pycache__``).
    """
    last = p1  # one past the last valid pixel of the block
    while last > p0 and depth[last - np.uint64(1)] == 0:
        last -= np.uint64(1)
    p_vec = last - np.uint64(1) if last > p0 else p0
    one, two = np.uint64(1), np.uint64(2)
    for i in range(p0, p_vec):
        d = depth[i]
        if d == 0:
            continue
        store_point4(out, j, rays, i * stride, _z_px(i, d, lut_f, lut_i, coef, rays, stride, ray_w, q0, nmax, with_ray))
        j += np.uint64(3)
    for i in range(p_vec, p1):  # the last valid pixel (and the invalid ones after it)
        d = depth[i]
        if d == 0:
            continue
        z = _z_px(i, d, lut_f, lut_i, coef, rays, stride, ray_w, q0, nmax, with_ray)
        r = i * stride
        out[j] = rays[r] * z
        out[j + one] = rays[r + one] * z
        out[j + two] = z
        j += np.uint64(3)
    return j


@nb.njit(parallel=True, fastmath=True, cache=True)
def _correct_backproject(depth, lut_f, lut_i, coef, rays, stride, out, nthreads, ray_w, q0, nmax,
                         with_ray):  # pragma: no cover - numba
    """Fused correction + back-projection; returns the number N of points written.

    depth (H*W,) uint16 [mm]; lut_f, lut_i, coef, ray_w: :class:`CorrectionTables` arrays; rays
    float32 per-pixel records of ``stride`` values: ``(x, y)`` (stride 2) or ``(x, y, rho)``
    (stride 3, needed with a ray term); out (>= 3 N,) float32 interleaved (x, y, z) [m]. One block
    of pixels per thread; each block first counts the valid pixels before it (a vectorised pass)
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
        ends[c] = _correct_backproject_block(depth, lut_f, lut_i, coef, rays, stride, out, p0, p1, j, ray_w, q0,
                                             nmax, with_ray)
    return ends[nb_ - 1] // np.uint64(3)


def _records(rays: np.ndarray, t) -> np.ndarray:
    """Per-pixel float32 records for the kernel: the interleaved ``(x, y)`` rays, or ``(x, y, rho)``
    for a calibration with a ray term."""
    if not t.has_ray:
        return rays
    r3 = np.empty((len(rays) // 2, 3), np.float32)
    r3[:, :2] = rays.reshape(-1, 2)
    r3[:, 2] = t.pix_rho
    return r3.reshape(-1)


def _run_kernel(flat, t, rays, out, nthreads, records=None) -> int:
    """The kernel for the calibration's tables; returns the number of points. ``records``: the
    per-pixel records (:func:`_records`), built here when not given."""
    rec = records if records is not None else _records(rays, t)
    stride = np.uint64(3 if t.has_ray else 2)
    return int(_correct_backproject(flat, t.lut_f, t.lut_i, t.coef, rec, stride, out, nthreads, t.ray_w,
                                    np.float32(t.ray_q0), t.ray_tmax, t.has_ray))


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
    n = _run_kernel(flat, cal.tables, rays, out.reshape(-1), nb.get_num_threads())
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
        self._tables = cal.tables
        self._records = _records(self.rays, self._tables)
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
        n = _run_kernel(depth.reshape(-1), self._tables, self.rays, out.reshape(-1), self.n_threads, self._records)
        return out[:n]
