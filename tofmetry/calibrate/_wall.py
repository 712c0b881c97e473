"""Wall mode: station statistics (streamed), robust plane fit, wall samples for the generic fit.

A station is a flat wall seen at a reference distance ``D`` [mm] measured along the optical
axis. The wall may be slightly tilted: its orientation is fitted on the averaged cloud
(robust least squares), and the plane is anchored at ``(0, 0, D)`` on the optical axis, so
the reference depth of pixel ray ``(x, y)`` is ``D n_z / (n . (x, y, 1))``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

import numba as nb

from tofmetry._shared.geometry import principal_axes
from tofmetry.calibrate._sample import DepthSample
from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor import CameraIntrinsics


@nb.njit(cache=True)
def _accumulate(frame, shift, s1, s2, cnt):  # pragma: no cover - numba
    """Shifted running sums of one uint16 frame (0 = invalid); shift set at first valid sample.

    Serial on purpose: it runs while reader threads decode the next PNGs (memory-bound anyway).
    """
    n = frame.shape[0]
    for i in range(n):
        d = frame[i]
        if d == 0:
            continue
        if cnt[i] == 0:
            shift[i] = d
        x = np.float64(d) - shift[i]
        s1[i] += x
        s2[i] += x * x
        cnt[i] += 1


@dataclass(eq=False)
class StationStats:
    """Temporal statistics of one station.

    Attributes
    ----------
    mean_mm : (H, W) float64 [mm], NaN where fewer than ``min_valid_fraction`` of frames valid
    std_mm : (H, W) float64 [mm] temporal std per pixel
    n_frames : int
    frame_center_mm : (T,) float64 [mm] per-frame mean of the central patch
    valid_fraction : (H, W) float64, fraction of the frames in which each pixel was valid (a pixel
        that drops out in some frames, e.g. at the sensor's maximum range, has a biased mean:
        the frames that read long are the ones lost)
    """

    mean_mm: np.ndarray
    std_mm: np.ndarray
    n_frames: int
    frame_center_mm: np.ndarray
    valid_fraction: np.ndarray | None = None

    @property
    def center_std_mm(self) -> float:
        """Std [mm] of the per-frame central-patch means (study Fig. 7b)."""
        f = self.frame_center_mm[np.isfinite(self.frame_center_mm)]
        return float(np.std(f, ddof=1)) if len(f) > 1 else float("nan")


def central_patch(shape: tuple[int, int], cx: float, cy: float, half: int = 5) -> tuple[slice, slice]:
    """Slices of the ``2 half x 2 half`` pixel patch around the principal point (10x10 default)."""
    h, w = shape
    u0 = int(np.clip(round(cx) - half, 0, w - 2 * half))
    v0 = int(np.clip(round(cy) - half, 0, h - 2 * half))
    return slice(v0, v0 + 2 * half), slice(u0, u0 + 2 * half)


def station_statistics(frames: Iterable[np.ndarray], shape: tuple[int, int], cx: float, cy: float,
                       half: int = 5, min_valid_fraction: float = 0.5, advance=None) -> StationStats:
    """Stream depth frames of one station into running statistics (bounded memory).

    Parameters
    ----------
    frames : iterable of (H, W) uint16 [mm], 0 = invalid
    shape : (H, W)
    cx, cy : principal point [px] (centre of the patch)
    half : half size of the central patch [px]
    min_valid_fraction : pixels valid in fewer frames are NaN in the mean
    advance : optional callable run after each frame (progress)
    """
    shape = tuple(shape)
    npx = shape[0] * shape[1]
    shift = np.zeros(npx)
    s1 = np.zeros(npx)
    s2 = np.zeros(npx)
    cnt = np.zeros(npx, np.int64)
    sl = central_patch(shape, cx, cy, half)
    cen = []
    n = 0
    for f in frames:
        f = np.asarray(f)
        if f.shape != shape or f.dtype != np.uint16:
            raise InputError(f"station frame {n}: expected {shape} uint16 depth [mm], found {f.shape} {f.dtype}")
        _accumulate(np.ascontiguousarray(f).reshape(-1), shift, s1, s2, cnt)
        p = f[sl].astype(np.float64)
        p = p[p > 0]
        cen.append(p.mean() if len(p) else np.nan)
        n += 1
        if advance is not None:
            advance()
    if n == 0:
        raise InputError("station has no frames")
    c = cnt.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        m1 = s1 / c
        mean = np.where(c >= max(1.0, min_valid_fraction * n), shift + m1, np.nan)
        std = np.where(c > 1, np.sqrt(np.maximum((s2 - c * m1 * m1) / (c - 1), 0.0)), np.nan)
    return StationStats(mean_mm=mean.reshape(shape), std_mm=std.reshape(shape), n_frames=n,
                        frame_center_mm=np.array(cen), valid_fraction=(c / n).reshape(shape))


@dataclass(eq=False)
class PlaneFit:
    """Robust plane ``n . X = c`` fitted to a depth map's cloud.

    Attributes
    ----------
    normal : (3,) unit, n_z > 0
    c_mm : float, plane offset [mm]
    inliers : (H, W) bool
    residual_mm : (H, W) float64, measured - plane depth along Z [mm] (NaN invalid)
    std_mm : float, std of ``residual_mm`` over inliers
    """

    normal: np.ndarray
    c_mm: float
    inliers: np.ndarray
    residual_mm: np.ndarray
    std_mm: float

    def depth_at(self, rays: np.ndarray) -> np.ndarray:
        """Plane depth Z [mm] along rays (H, W, 2)."""
        n = self.normal
        return self.c_mm / (n[0] * rays[..., 0] + n[1] * rays[..., 1] + n[2])


def _plane(X: np.ndarray):
    """Unit normal (n_z > 0) and centroid of the least-squares plane of (N, 3) points."""
    c0, axes = principal_axes(X)
    n = axes[2]
    return (n if n[2] > 0 else -n), c0


def fit_plane(depth_mm: np.ndarray, intrinsics: CameraIntrinsics, k: float = 3.0, iterations: int = 6,
              mask: np.ndarray | None = None, min_points: int = 50) -> PlaneFit:
    """Least-squares plane of the cloud of a depth map, with iterative k-MAD outlier removal.

    Parameters
    ----------
    depth_mm : (H, W) float [mm], 0/NaN invalid
    intrinsics : CameraIntrinsics (rays with distortion removed)
    k : rejection threshold in robust sigmas of the orthogonal residuals
    mask : optional (H, W) bool of pixels allowed in the fit
    """
    d = np.asarray(depth_mm, np.float64)
    rays = intrinsics.ray_table()
    valid = np.isfinite(d) & (d > 0)
    if mask is not None:
        valid &= mask
    if valid.sum() < min_points:
        raise EstimationError(f"plane fit: {int(valid.sum())} valid pixels, at least {min_points} needed")
    P = np.stack([rays[..., 0] * d, rays[..., 1] * d, d], axis=-1)
    inl = valid.copy()
    sub = np.zeros(d.shape, bool)
    sub[::2, ::2] = True  # robust scale from a quarter of the pixels (plenty, 4x cheaper)
    for _ in range(iterations):
        n, c0 = _plane(P[inl])
        res = (P - c0) @ n
        r = res[valid & sub] if (valid & sub).sum() >= min_points else res[valid]
        med = np.median(r)
        sig = 1.4826 * np.median(np.abs(r - med)) + 1e-9
        new = valid & (np.abs(res - med) <= k * sig)
        if new.sum() < min_points or np.array_equal(new, inl):
            inl = new if new.sum() >= min_points else inl
            break
        inl = new
    n, c0 = _plane(P[inl])
    c = float(n @ c0)
    zp = c / (n[0] * rays[..., 0] + n[1] * rays[..., 1] + n[2])
    resid = np.where(valid, d - zp, np.nan)
    return PlaneFit(normal=n, c_mm=c, inliers=inl, residual_mm=resid, std_mm=float(np.std(resid[inl])))


def wall_reference(intrinsics: CameraIntrinsics, distance_mm: float, normal: np.ndarray | None = None) -> np.ndarray:
    """Reference depth [mm] (H, W) of a wall through ``(0, 0, distance_mm)`` with unit ``normal``.

    ``normal=None`` means a wall perpendicular to the optical axis (constant depth).
    """
    if normal is None:
        return np.full(intrinsics.shape, float(distance_mm))
    n = np.asarray(normal, np.float64)
    rays = intrinsics.ray_table()
    return distance_mm * n[2] / (n[0] * rays[..., 0] + n[1] * rays[..., 1] + n[2])


def wall_sample(mean_mm: np.ndarray, distance_mm: float, intrinsics: CameraIntrinsics, name: str = "",
                frontal: bool = False, sem_mm: np.ndarray | None = None,
                valid_fraction: np.ndarray | None = None, min_valid_fraction: float = 0.95) -> tuple[DepthSample, PlaneFit]:
    """Build a :class:`DepthSample` from a station's averaged depth.

    Pixels rejected by the robust plane fit (edges, flying pixels) keep their reference but
    get weight 0 when grossly off (> max(10 robust sigma, 50 mm + 2 % of D) from the plane), so real deformation
    in the corners stays in the data.

    Parameters
    ----------
    mean_mm : (H, W) float [mm], NaN/0 invalid
    distance_mm : reference distance along the optical axis [mm]
    frontal : if True the wall is taken perpendicular to the optical axis (no tilt fitted);
        otherwise its orientation is fitted here and refined by the calibration (``free_tilt``)
    sem_mm : (H, W) float [mm], optional standard error of ``mean_mm`` (std / sqrt(frames))
    valid_fraction : (H, W) float, optional fraction of frames in which each pixel was valid;
        pixels below ``min_valid_fraction`` get weight 0 (their mean is biased by the frames lost)
    """
    pf = fit_plane(mean_mm, intrinsics)
    ref = wall_reference(intrinsics, distance_mm, None if frontal else pf.normal)
    m = np.asarray(mean_mm, np.float64)
    r = pf.residual_mm
    fin = np.isfinite(r)
    med = np.median(r[pf.inliers])
    sig = 1.4826 * np.median(np.abs(r[pf.inliers] - med)) + 1e-6
    gross = fin & (np.abs(r - med) > max(10 * sig, 50.0 + 0.02 * distance_mm))
    w = np.where(fin & ~gross, 1.0, 0.0)
    if valid_fraction is not None:
        w = np.where(np.asarray(valid_fraction) >= min_valid_fraction, w, 0.0)
    return DepthSample(measured_mm=np.where(fin, m, np.nan), reference_mm=ref, weight=w, name=name, sem_mm=sem_mm,
                       free_tilt=not frontal), pf
