"""Depth maps to point clouds (pure functions on arrays)."""

from __future__ import annotations

import numpy as np

from tofmetry.errors import InputError
from tofmetry.pointcloud._colour import colour_points
from tofmetry.sensor.extrinsics import Extrinsics
from tofmetry.sensor.intrinsics import CameraIntrinsics


def _check_depth(depth: np.ndarray, intr: CameraIntrinsics, name: str = "depth") -> np.ndarray:
    depth = np.asarray(depth)
    if depth.shape != intr.shape:
        raise InputError(
            f"{name}: shape {depth.shape} does not match the intrinsics {intr.height}x{intr.width} (H, W); "
            "pass the intrinsics of the camera that took this frame"
        )
    if np.issubdtype(depth.dtype, np.floating) and np.isnan(depth).all():
        raise InputError(f"{name}: all NaN")
    return depth


def depth_to_points(depth: np.ndarray, intr: CameraIntrinsics, undistort: bool = True,
                    min_mm: float = 0.0, max_mm: float = np.inf, return_index: bool = False):
    """Back-project a depth map to camera-frame points.

    Parameters
    ----------
    depth : (H, W) uint16 or float [mm]
        Z along the optical axis; 0 or NaN = no measurement.
    intr : CameraIntrinsics
        Of the depth (IR) camera.
    undistort : bool
        Use the undistorted ray table (default) or the plain pinhole.
    min_mm, max_mm : float
        Keep only ``min_mm < Z <= max_mm`` (and Z > 0).
    return_index : bool
        Also return the flat pixel index (N,) int64 of each point.

    Returns
    -------
    points : (N, 3) float64 [m], camera frame (x right, y down, z forward).
    index : (N,) int64, if ``return_index``.
    """
    depth = _check_depth(depth, intr)
    z = depth.astype(np.float64).ravel()
    ok = np.isfinite(z) & (z > max(min_mm, 0.0)) & (z <= max_mm)
    idx = np.flatnonzero(ok)
    rays = intr.ray_table(undistort).reshape(-1, 2)[idx]
    zm = z[idx] * 1e-3
    pts = np.column_stack([rays[:, 0] * zm, rays[:, 1] * zm, zm])
    return (pts, idx) if return_index else pts


def depth_to_xyz_image(depth: np.ndarray, intr: CameraIntrinsics, undistort: bool = True) -> np.ndarray:
    """Organised point image: (H, W, 3) float64 [m], NaN where depth is 0/NaN."""
    depth = _check_depth(depth, intr)
    z = depth.astype(np.float64) * 1e-3
    z[~(z > 0)] = np.nan
    rays = intr.ray_table(undistort)
    return np.dstack([rays[..., 0] * z, rays[..., 1] * z, z])


def amplitude_colors(ir: np.ndarray, lo_pct: float = 1.0, hi_pct: float = 99.0) -> np.ndarray:
    """Grey colours from IR amplitude with a robust percentile stretch.

    Parameters
    ----------
    ir : (N,) or (H, W) amplitude (any dtype)

    Returns
    -------
    (N, 3) uint8 grey RGB.
    """
    a = np.asarray(ir, dtype=np.float64).ravel()
    valid = a[a > 0]
    if valid.size == 0:
        return np.zeros((a.size, 3), np.uint8)
    lo, hi = np.percentile(valid, [lo_pct, hi_pct])
    g = np.clip((a - lo) / max(hi - lo, 1e-9), 0, 1)
    g = np.sqrt(g)  # gamma for dark ToF amplitudes
    g8 = (g * 255).astype(np.uint8)
    return np.repeat(g8[:, None], 3, axis=1)


def sample_colors(points: np.ndarray, color_image: np.ndarray, color_intr: CameraIntrinsics,
                  depth_to_color: Extrinsics, occlusion_tol_m: float = 0.005,
                  depth_focal_px: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Colour depth points from a colour image through the extrinsics, with occlusion test.

    The array form of :func:`~tofmetry.pointcloud.colour_points` (which see): a point is coloured
    only when the colour camera sees it (colour-camera z-buffer of splatted points).

    Parameters
    ----------
    points : (N, 3) float [m] in the depth camera frame
    color_image : (Hc, Wc, 3) uint8 RGB
    color_intr : CameraIntrinsics of the colour camera (Hc, Wc)
    depth_to_color : Extrinsics, depth camera -> colour camera [m]
    occlusion_tol_m : base depth tolerance of the visibility test [m]
    depth_focal_px : focal length of the depth camera [px] (splat size); default 2 colour px

    Returns
    -------
    colors : (N, 3) uint8 (0 where uncoloured: that is *no colour*, see ``ok``)
    ok : (N,) bool, True where a colour was sampled
    """
    res = colour_points(points, color_image, color_intr, depth_to_color, depth_focal_px, occlusion_tol_m)
    return res.colors, res.colored
