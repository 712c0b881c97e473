"""The global adjustment's depth corrections applied to the views it was fitted on.

The joint fit (:func:`~tofmetry.reconstruct._adjust.global_adjust`) estimates, besides the poses, a
depth gain, a range curve, an amplitude-bias increment ``dk`` and an image tilt, each a function of
what one pixel measured. :func:`correct_views` applies them to the views' points and depth maps, as
the fusion needs them, and refits each view's support plane on its moved points.
"""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import fit_plane_svd
from tofmetry.reconstruct._adjust import apply_depth_gain
from tofmetry.reconstruct._adjust_result import AdjustResult
from tofmetry.reconstruct._adjust_terms import image_tilt_m
from tofmetry.reconstruct._amplitude import amplitude_log_ratio
from tofmetry.reconstruct._preprocess import ViewData
from tofmetry.reconstruct._range_curve import apply_range_curve, range_curve_m
from tofmetry.reconstruct._segment import Segmentation
from tofmetry.sensor import CameraIntrinsics


def correct_views(views: list[ViewData], segs: list[Segmentation], res: AdjustResult, z_ref: float,
                  intr: CameraIntrinsics, white_map: np.ndarray | None, plane_threshold_m: float) -> None:
    """Apply the adjustment's depth corrections to ``views`` (points and depth maps) in place.

    Parameters
    ----------
    views : the views the adjustment was fitted on; ``points`` (N, 3) [m] in each camera frame
        (x right, y down, z forward) and ``depth_mm`` (H, W) [mm] (Z along the optical axis) are replaced
    segs : their segmentations; a support plane is refitted on the points that lay on it
        (within ``plane_threshold_m`` [m]) before the correction
    res : the adjustment kept
    z_ref : depth the gain and the range curve are referred to [m]
    intr : the views' intrinsics (the pixels' rays for the tilt, the amplitude's log ratio)
    white_map : (H, W) white amplitude reference, or None (then ``dk`` is not estimated)
    """
    curve = res.range_curve_m if res.range_curve_estimated else None
    dk_mm = res.amplitude_dk_m * 1e3 if res.amplitude_estimated else 0.0
    tilt = res.image_tilt_m if res.image_tilt_estimated else None
    if res.depth_gain == 0.0 and curve is None and dk_mm == 0.0 and tilt is None:
        return
    rays = None if tilt is None else intr.ray_table()
    h = res.range_curve_half_span_m
    for v, s in zip(views, segs):
        on_plane = None if s.plane is None else np.abs(v.points @ s.plane[:3] + s.plane[3]) < plane_threshold_m
        p0, d0 = v.points, v.depth_mm
        v.points = apply_depth_gain(p0, res.depth_gain, z_ref)
        v.depth_mm = np.where(d0 > 0, d0 + res.depth_gain * (d0 - z_ref * 1e3), 0.0)
        if curve is not None:  # a function of the measured depth, like the gain
            v.points = v.points + apply_range_curve(p0, curve, z_ref, h) - p0
            v.depth_mm = np.where(d0 > 0, v.depth_mm + 1e3 * range_curve_m(d0.ravel() * 1e-3, curve, z_ref, h)
                                  .reshape(d0.shape), 0.0)
        if dk_mm != 0.0:  # Z -> Z - dk ln(A_white / A), like the preprocessing's own correction
            L = amplitude_log_ratio(d0, v.ir, white_map, intr)
            v.points = v.points - p0 * (dk_mm * 1e-3 * L.ravel()[v.index] / p0[:, 2])[:, None]
            v.depth_mm = np.where(d0 > 0, v.depth_mm - dk_mm * L, 0.0)
        if tilt is not None:  # Z -> Z + a (x - x0) + b (y - y0), (x, y) the pixel's ray
            dz = image_tilt_m(p0[:, :2] / p0[:, 2:3], tilt, res.image_tilt_centre)
            v.points = v.points + p0 * (dz / p0[:, 2])[:, None]
            v.depth_mm = np.where(d0 > 0, v.depth_mm + 1e3 * image_tilt_m(rays, tilt, res.image_tilt_centre), 0.0)
        if on_plane is not None and on_plane.sum() >= 3:  # the support plane moved with its points
            s.plane = fit_plane_svd(v.points[on_plane], orient=s.plane[:3])
