"""The support surface of one view as it was measured: the plane and what continues it smoothly.

Why: the support plane is found by RANSAC with a tolerance of a few millimetres. Where the depth
reads millimetres off over a large area (near the end of a calibration's range, in its
extrapolation, in an uncalibrated corner), the table bends out of that tolerance and a band of
it "stands on the plane". Measured on a family draw (a rocker arm lying flat at 0.87 m, the table
reaching 0.51 m): 6 870 of the 9 570 "object" points were table at 5-26 mm above the fitted
plane, in every view alike, so every pair of views registered to the identity (fitness 0.6)
while the object turned 28 deg between views, and the loop closed to 0.2 deg.

What continues the table is recognised on the image grid: a pixel is support-like when its
normal lies within ``max_tilt_deg`` of the plane's, it is lower than ``band_m`` and no 4-neighbour
differs from it in height by more than ``max_step_m``; the support is every connected region of
such pixels that holds a plane inlier. An object is cut off from it by its flanks (normals away
from the plane's) and by the height jumps at its occluding contours, so even a low object with a
flat top (10 mm above the table) stays out; a gently sloped mound lower than ``band_m`` would not.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def support_region(points: np.ndarray, normals: np.ndarray, index: np.ndarray, shape: tuple[int, int],
                   plane: np.ndarray, threshold_m: float, band_m: float = 0.03, max_tilt_deg: float = 20.0,
                   max_step_m: float | None = None) -> np.ndarray:
    """Points of the support surface: the plane's inliers and the smooth, level regions joined to them.

    Parameters
    ----------
    points : (N, 3) [m], camera frame; normals : (N, 3) unit, oriented toward the camera
    index : (N,) flat pixel index of each point in an image of ``shape`` (H, W)
    plane : (4,) support plane, unit normal toward the camera, height = n . p + d [m]
    threshold_m : the plane's inlier distance [m]
    band_m : support-like pixels lie below this height [m]
    max_tilt_deg : ... with normals within this of the plane's
    max_step_m : ... and no 4-neighbour higher or lower by more than this [m]; None: ``threshold_m``

    Returns
    -------
    (N,) bool: support points (plane inliers included)
    """
    p = np.asarray(points, np.float64)
    n = np.asarray(plane[:3], np.float64)
    h = p @ n + float(plane[3])
    step_max = threshold_m if max_step_m is None else max_step_m
    H, W = shape
    img = np.full(H * W, np.nan)
    img[index] = h
    img = img.reshape(H, W)
    step = np.zeros((H, W))
    for axis in (0, 1):  # largest height difference to a 4-neighbour (inf next to a pixel without depth)
        d = np.abs(np.diff(img, axis=axis))
        d = np.where(np.isnan(d), np.inf, d)
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        step[tuple(lo)] = np.maximum(step[tuple(lo)], d)
        step[tuple(hi)] = np.maximum(step[tuple(hi)], d)
    level = (np.asarray(normals) @ n) >= np.cos(np.radians(max_tilt_deg))
    inlier = np.abs(h) < threshold_m
    like = inlier | (level & (h < band_m) & (step.ravel()[index] <= step_max))
    grid = np.zeros(H * W, bool)
    grid[index[like]] = True
    labels, _ = ndimage.label(grid.reshape(H, W))
    lab = labels.ravel()[index]
    seeded = np.unique(lab[inlier & like])
    seeded = seeded[seeded > 0]
    return np.isin(lab, seeded) & like
