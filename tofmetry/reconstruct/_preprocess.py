"""Per-view depth preparation: calibration, robust temporal mean, flying pixels, range, normals.

Each frame is corrected by the calibration's uint16 kernel (:func:`corrected_mean_depth`), the
path every frame takes, before the robust temporal mean; the mean keeps sub-millimetre values, so
it is back-projected in float (:func:`tofmetry.pointcloud.depth_to_points`), once per view.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tofmetry._shared.geometry import fit_plane_svd
from tofmetry.assess import remove_flying_pixels
from tofmetry.errors import InputError
from tofmetry.calibrate import DepthCalibration, apply_depth_calibration, count_outside_range
from tofmetry.pointcloud import depth_to_points, robust_mean_depth, temporal_stats
from tofmetry.reconstruct._amplitude import amplitude_bias_mm
from tofmetry.reconstruct._config import PreprocessConfig
from tofmetry.sensor import CameraIntrinsics


@dataclass
class ViewData:
    """One prepared view (camera frame).

    Attributes
    ----------
    name : str
    depth_mm : (H, W) float64 [mm] cleaned, calibrated Z; 0 = invalid
    points : (N, 3) float64 [m] valid points of ``depth_mm``
    index : (N,) int64 flat pixel index of each point
    normals : (N, 3) float64 unit normals oriented toward the camera
    cos_incidence : (N,) float64 cosine of the angle between normal and line of sight
    ir : (H, W) float or None, mean IR amplitude
    stats : dict of counts (valid, flying removed, out of range, grazing)
    """

    name: str
    depth_mm: np.ndarray
    points: np.ndarray
    index: np.ndarray
    normals: np.ndarray
    cos_incidence: np.ndarray
    ir: np.ndarray | None
    stats: dict


def corrected_mean_depth(stack: np.ndarray, calibration: DepthCalibration | None = None, k: float = 3.0,
                         min_count: int = 1) -> np.ndarray:
    """Robust temporal mean of raw depth frames, each corrected first by the calibration's uint16 kernel.

    Parameters
    ----------
    stack : (T, H, W) uint16 [mm] raw depth frames of one pose, 0 = invalid
    calibration : DepthCalibration or None (raw depth)
    k, min_count : as :func:`tofmetry.pointcloud.robust_mean_depth`

    Returns
    -------
    (H, W) float64 [mm], 0 where fewer than ``min_count`` samples survive; depths outside the
    calibration's support get its fallback, frame by frame (see :func:`outside_support`).
    """
    correct = None if calibration is None else (lambda f: apply_depth_calibration(f, calibration))
    mean = robust_mean_depth(stack, k=k, min_count=min_count, correct=correct)
    mean[~np.isfinite(mean)] = 0.0
    return mean


def outside_support(stack: np.ndarray, calibration, valid: np.ndarray) -> int:
    """Pixels of a view (valid after averaging) whose mean raw depth lies outside the calibration's
    support: their correction is the calibration's fallback (0 without a calibration)."""
    if calibration is None:
        return 0
    n = (stack > 0).sum(axis=0)
    mean = stack.sum(axis=0, dtype=np.float64) / np.maximum(n, 1)
    return int(count_outside_range(np.where(valid & (n > 0), mean, 0.0), calibration))


def prepare_view(stack: np.ndarray, intr: CameraIntrinsics, calibration=None, config: PreprocessConfig | None = None,
                 name: str = "view", ir: np.ndarray | None = None, white_map: np.ndarray | None = None) -> ViewData:
    """Average, calibrate and clean one view.

    Parameters
    ----------
    stack : (T, H, W) uint16 [mm] depth frames of one pose
    intr : CameraIntrinsics of the depth camera (the calibration's when calibrated)
    calibration : tofmetry.calibrate.DepthCalibration or None
    ir : (H, W) mean amplitude (optional; kept for colouring, used by the amplitude correction)
    white_map : (H, W) white amplitude at 1 m (:func:`tofmetry.reconstruct.white_amplitude_map`);
        with ``ir``, the amplitude-dependent bias ``k ln(A_white / A)`` is subtracted

    Returns
    -------
    ViewData
    """
    cfg = config or PreprocessConfig()
    stack = np.asarray(stack)
    if stack.ndim != 3 or stack.shape[1:] != intr.shape:
        raise InputError(f"view {name}: depth stack shape {stack.shape} does not match the intrinsics {intr.shape} (T, H, W)")
    min_count = max(1, int(np.ceil(cfg.min_valid_share * stack.shape[0])))
    depth = corrected_mean_depth(stack, calibration, k=cfg.robust_k, min_count=min_count)
    n_valid0 = int((depth > 0).sum())
    n_outside = outside_support(stack, calibration, depth > 0)
    amp_mean = 0.0
    if white_map is not None and ir is not None:
        b = amplitude_bias_mm(depth, ir, white_map, intr, cfg.amplitude_k_mm_per_ln)
        clip = cfg.amplitude_max_mm
        if clip is None:  # in units of the regressor: the same darkness is clipped whatever the sensor's k
            clip = cfg.amplitude_max_ln * abs(cfg.amplitude_k_mm_per_ln)
        b = np.clip(b, -clip, clip)
        depth = np.where(depth > 0, depth - b, 0.0)
        amp_mean = float(np.median(b[depth > 0])) if (depth > 0).any() else 0.0
    n_flying = 0
    if cfg.remove_flying:
        cleaned = np.asarray(remove_flying_pixels(depth, intr, max_support_between=cfg.flying_max_support_between),
                             dtype=np.float64)
        n_flying = int(((depth > 0) & (cleaned <= 0)).sum())
        depth = cleaned
    smoothed = None
    if cfg.denoise:  # every stage then works on the smoothed depth: registration, the joint fit, fusion
        se = mean_standard_error(stack)
        se = se[(depth > 0) & np.isfinite(se)]
        if len(se) >= 100:  # unknown for single frames: left as it is
            smoothed = float(np.median(se))
            depth = denoise_depth(depth, cfg.denoise_range_sigmas * smoothed, cfg.denoise_window_px).astype(np.float64)
    lo, hi = cfg.min_mm, cfg.max_mm
    if calibration is not None and calibration.support is None:
        # a calibration without a support map (format 1) leaves depth outside its range uncorrected,
        # biased by centimetres: drop it
        lo, hi = max(lo, float(calibration.valid_range_mm[0])), min(hi, float(calibration.valid_range_mm[1]))
    out_range = (depth > 0) & ((depth < lo) | (depth > hi))
    depth = np.where(out_range, 0.0, depth)
    pts, idx = depth_to_points(depth, intr, return_index=True)
    if len(pts) < 100:
        raise InputError(f"view {name}: only {len(pts)} valid depth pixels in the working range "
                         f"{lo:g}..{hi:g} mm")
    normals, cos_inc = image_normals(pts, idx, intr.shape, fx=intr.fx if cfg.normal_patch_mm > 0 else None,
                                     patch_m=cfg.normal_patch_mm * 1e-3)
    grazing = cos_inc < np.cos(np.radians(cfg.max_incidence_deg))
    keep = ~grazing
    depth.ravel()[idx[grazing]] = 0.0
    stats = {"valid_after_averaging": n_valid0, "outside_calibration_support": n_outside,
             "flying_removed": n_flying, "out_of_range": int(out_range.sum()),
             "grazing_removed": int(grazing.sum()), "points": int(keep.sum()),
             "amplitude_bias_median_mm": amp_mean, "denoised_with_standard_error_mm": smoothed}
    return ViewData(name, depth, pts[keep], idx[keep], normals[keep], cos_inc[keep], ir, stats)


def denoise_depth(depth_mm: np.ndarray, range_sigma_mm: float, window_px: int = 3) -> np.ndarray:
    """Edge-preserving smoothing of a depth map (a bilateral filter), before registration and fusion.

    Open3D's projective TSDF skips an observation that puts a voxel more than the truncation
    behind the measured surface and keeps one in front of it, however far. Where a pixel's noise is
    not small against the truncation this keeps the voxels inside the surface positive more often
    than negative, and the zero crossing moves into the object: measured on a simulated slab at
    0.65 m, 5 frames per view (the standard error of a pixel's mean 1.3-3.1 mm, the truncation
    3.8 mm), its faces came out 0.3-0.4 mm inside with the true poses, 0.05 with this filter over
    each pixel and its 4 neighbours (the noise halved).
    Neighbours farther in depth than a few range sigmas (another surface) get no weight, so
    silhouettes and depth jumps are kept.

    Parameters
    ----------
    depth_mm : (H, W) float [mm] Z, 0 = invalid
    range_sigma_mm : range (depth-difference) sigma of the filter [mm]
    window_px : window diameter [px] (odd; OpenCV's window is round: 3 px is the pixel and its 4
        neighbours); its spatial sigma is half of it

    Returns
    -------
    (H, W) float32 [mm], 0 where ``depth_mm`` is 0
    """
    d = np.asarray(depth_mm, np.float32)
    if not range_sigma_mm > 0:
        return d
    f = cv2.bilateralFilter(d, int(window_px), float(range_sigma_mm), 0.5 * float(window_px))
    return np.where(d > 0, f, 0.0).astype(np.float32)


def mean_standard_error(stack: np.ndarray) -> np.ndarray:
    """Standard error of each pixel's temporal mean, from the frames themselves.

    Parameters
    ----------
    stack : (T, H, W) uint16 [mm] depth frames of one pose, 0 = invalid

    Returns
    -------
    (H, W) float32 [mm]: sample standard deviation (ddof 1) of the valid frames / sqrt(their
    count); NaN where fewer than two frames are valid. A depth calibration shifts a pixel's frames
    alike, so the raw frames give the calibrated mean's spread.
    """
    st = temporal_stats(stack)
    with np.errstate(invalid="ignore", divide="ignore"):
        se = st.std / np.sqrt(st.count)
    return np.where(st.count >= 2, se, np.nan).astype(np.float32)


def image_normals(points: np.ndarray, index: np.ndarray, shape: tuple[int, int], fx: float | None = None,
                  patch_m: float = 0.012) -> tuple[np.ndarray, np.ndarray]:
    """Normals of an organised cloud: a plane fitted to each pixel's neighbourhood on the pixel grid.

    With ``fx`` the neighbourhood is a square window spanning about ``patch_m`` on the surface
    (``patch_m fx / z`` pixels, odd, 3 to 9: 7 px at 0.65 m, 3 px beyond 1.4 m on a Kinect v2), its
    normal the least-variance direction of the valid points in it (the integral-image plane fit
    of Holzer et al. 2012, by box filters). Near the minimum range a ToF camera's noise reaches
    1-3 mm while its pixels are 1.8 mm apart: central differences there tilt the normal by ~30
    degrees, the grazing test then drops frontal pixels and a point-to-plane ICP slides (measured on
    a head at 0.65 m, noise alone, ICP started at the true pose: 0.7-9.5 degrees off on its 7 pairs
    with differences, 0.2-1.7 on 5 of them with the window; the other two still slid 4.5 and 56).
    Where the window reaches across a depth jump, and without ``fx``, the normal comes from central
    differences over 2 pixels.

    Parameters
    ----------
    points : (N, 3) [m]; index : (N,) flat pixel index; shape : (H, W)
    fx : focal length [px] (enables the window fit), or None
    patch_m : surface span of the window [m]

    Returns
    -------
    normals : (N, 3) unit, oriented toward the camera (origin)
    cos_incidence : (N,) |n . line of sight|; 0 where a normal could not be formed
    """
    H, W = shape
    img = np.full((H, W, 3), np.nan)
    img.reshape(-1, 3)[index] = points
    # 2-pixel baselines (v +- 1, u +- 1)
    du = np.full_like(img, np.nan)
    dv = np.full_like(img, np.nan)
    du[:, 1:-1] = img[:, 2:] - img[:, :-2]
    dv[1:-1, :] = img[2:, :] - img[:-2, :]
    n = np.cross(du.reshape(-1, 3)[index], dv.reshape(-1, 3)[index])
    # reject normals across depth jumps: both baselines must be short relative to the range
    z = points[:, 2]
    lu = np.linalg.norm(du.reshape(-1, 3)[index], axis=1)
    lv = np.linalg.norm(dv.reshape(-1, 3)[index], axis=1)
    ok = np.isfinite(n).all(1) & (lu < 0.05 * z) & (lv < 0.05 * z)
    nn = np.linalg.norm(n, axis=1)
    ok &= nn > 0
    normals = np.zeros_like(points)
    normals[ok] = n[ok] / nn[ok, None]
    if fx is not None and len(points):
        jump = np.ones(H * W, bool)
        jump[index[ok]] = False  # invalid pixels and depth jumps
        win = np.clip(2 * np.round(0.5 * (patch_m * fx / np.maximum(z, 1e-3) - 1)) + 1, 3, 9).astype(int)
        for w in np.unique(win[ok]):
            sel = np.flatnonzero(ok & (win == w))
            fit, clean = _window_plane_normals(img, jump.reshape(H, W), index[sel], int(w))
            normals[sel[clean]] = fit[clean]
    flip = np.einsum("ij,ij->i", normals, points) > 0
    normals[flip] *= -1
    los = points / np.linalg.norm(points, axis=1, keepdims=True)
    cos_inc = np.abs(np.einsum("ij,ij->i", normals, los))
    cos_inc[~ok] = 0.0
    return normals, cos_inc


def _window_plane_normals(img: np.ndarray, jump: np.ndarray, index: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Least-variance direction of the valid points of ``img`` ((H, W, 3) [m], NaN = invalid) in the
    ``w`` x ``w`` window of each pixel ``index``, and whether the window is clean (no pixel of
    ``jump``, the invalid pixels and depth jumps, and at least half of it valid)."""
    valid = np.isfinite(img[..., 0])
    x = np.where(valid[..., None], img, 0.0)
    m = valid.astype(np.float64)

    def box(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, -1, (w, w), normalize=False, borderType=cv2.BORDER_CONSTANT).reshape(-1)[index]

    cnt = box(m)
    bad = box((jump & valid).astype(np.float64))
    mu = np.stack([box(x[..., k]) for k in range(3)], 1) / np.maximum(cnt, 1.0)[:, None]
    C = np.empty((len(index), 3, 3))
    for a in range(3):
        for b in range(a, 3):
            C[:, a, b] = C[:, b, a] = box(x[..., a] * x[..., b]) / np.maximum(cnt, 1.0) - mu[:, a] * mu[:, b]
    # least-variance direction: the dominant eigenvector of adj(C) (eigenvalues l1 l2 > l0 l2 > l0 l1),
    # its largest column refined by two power steps (the ratio l0 / l1 is small on a surface patch)
    A = np.cross(C[:, [1, 2, 0]], C[:, [2, 0, 1]])
    v = A[np.arange(len(A)), np.argmax(np.einsum("nij,nij->nj", A, A), axis=1)]
    for _ in range(2):
        v = np.einsum("nij,nj->ni", A, v)
        v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)
    return v, (bad == 0) & (cnt >= 0.5 * w * w)


def correct_views(views: list[ViewData], segs, plane_threshold_m: float, correct) -> None:
    """Every view's depth corrected in place, ``correct(view) -> (points (N, 3) [m], depth_mm (H, W))``
    (each point moved along its ray, the depth map with it), and each support plane (``segs[k].plane``)
    refitted on the points that lay within ``plane_threshold_m`` of it before."""
    for v, s in zip(views, segs):
        on = None if s.plane is None else np.abs(v.points @ s.plane[:3] + s.plane[3]) < plane_threshold_m
        v.points, v.depth_mm = correct(v)
        if on is not None and on.sum() >= 3:
            s.plane = fit_plane_svd(v.points[on], orient=s.plane[:3])
