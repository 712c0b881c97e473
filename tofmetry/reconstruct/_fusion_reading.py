"""How the fusion reads a depth map at a voxel's projection: bilinearly where the depth is smooth.

A voxel projects between pixel centres. Read at the nearest pixel, as Open3D reads it, its depth is off
by up to half a pixel's step, ``tan(incidence) z / (2 f)``, and a surface seen obliquely fuses as a
staircase of that height: 3.9 mm of depth, 1.5 mm along the normal, on a plane at 65 deg and 1.3 m
(``tests/reconstruct/test_fusion_interpolate.py``). Read bilinearly between the four pixels around
the projection, the plane fuses flat. Across a step between two surfaces, a crease or the view's
silhouette the bilinear reading would bridge two surfaces with one that no view saw, so there the
nearest pixel's depth is kept: where the depth's second difference at one of the four pixels exceeds
``kink_mm`` (:func:`smooth_depth`).
"""

from __future__ import annotations

import numpy as np


def smooth_depth(depth_mm: np.ndarray, kink_mm: float = 4.0) -> np.ndarray:
    """Pixels where the depth is locally smooth: valid, with valid neighbours on both sides along u and
    along v and a second difference along each within ``kink_mm``.

    A plane's depth changes by the same step from pixel to pixel, however oblique (its second
    difference at 80 deg and 1 m is about 0.5 mm); a step between two surfaces, or a crease, changes
    it by the step's height.

    Parameters
    ----------
    depth_mm : (H, W) float [mm] Z, 0 = invalid; kink_mm : [mm]

    Returns
    -------
    (H, W) bool
    """
    d = np.asarray(depth_mm, np.float64)
    ok = np.zeros(d.shape, bool)
    c = d[1:-1, 1:-1]
    l, r, t, b = d[1:-1, :-2], d[1:-1, 2:], d[:-2, 1:-1], d[2:, 1:-1]
    ok[1:-1, 1:-1] = ((c > 0) & (l > 0) & (r > 0) & (t > 0) & (b > 0)
                      & (np.abs(l - 2 * c + r) <= kink_mm) & (np.abs(t - 2 * c + b) <= kink_mm))
    return ok


def interpolated_reading(depth_mm: np.ndarray, u: np.ndarray, v: np.ndarray, nearest_m: np.ndarray,
                         smooth: np.ndarray | None = None) -> np.ndarray:
    """The depth at sub-pixel positions, bilinear where the four pixels around are smooth (one surface).

    A voxel projects between pixel centres; the nearest pixel's depth differs from the surface's
    there by up to half a pixel's step, ``tan(incidence) z / (2 f)`` (3.9 mm on a plane at 65 deg
    and 1.3 m). Read that way a surface seen obliquely fuses as a staircase of that height. Across
    a step between two surfaces, or at the view's silhouette, the nearest pixel's depth is kept: a
    bilinear reading there would bridge them with a surface no view saw.

    Parameters
    ----------
    depth_mm : (H, W) float [mm] Z, 0 = invalid
    u, v : (N,) float sub-pixel positions [px] (pixel centres at integers)
    nearest_m : (N,) float [m] the nearest pixel's depth, kept where one of the four is not smooth
    smooth : (H, W) bool, :func:`smooth_depth` of ``depth_mm`` (computed when None)

    Returns
    -------
    (N,) float [m]
    """
    d = np.asarray(depth_mm, np.float64)
    sm = smooth_depth(d) if smooth is None else smooth
    H, W = d.shape
    u0 = np.clip(np.floor(u).astype(np.int64), 0, W - 2)
    v0 = np.clip(np.floor(v).astype(np.int64), 0, H - 2)
    a = np.clip(u - u0, 0.0, 1.0)
    b = np.clip(v - v0, 0.0, 1.0)
    q = np.stack([d[v0, u0], d[v0, u0 + 1], d[v0 + 1, u0], d[v0 + 1, u0 + 1]])
    one = sm[v0, u0] & sm[v0, u0 + 1] & sm[v0 + 1, u0] & sm[v0 + 1, u0 + 1]
    bil = (q[0] * (1 - a) * (1 - b) + q[1] * a * (1 - b) + q[2] * (1 - a) * b + q[3] * a * b) * 1e-3
    return np.where(one, bil, nearest_m)
