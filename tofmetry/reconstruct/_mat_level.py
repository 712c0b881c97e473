"""The support plane a view is placed on, its offset read where the object stands: at the object's depths.

A view is placed on the dot mat by cutting its dots' rays with the support plane (:mod:`~tofmetry.reconstruct._mat_locate`),
fitted through every point of the support the view sees, from its near edge (0.5-0.6 m) to the far floor (1.5-2 m).
The depth's range error changes over that span (the calibration's residual between and beyond its stations), so the
plane that fits it best is off where the mat lies by the error's tilt and curvature over the whole floor, not by the
error at the mat. A plane off by ``h`` below the object moves the dots' cuts about ``h / sin(e)`` along their rays
(``e`` their elevation above the sheet, 20-35 deg), and the rigid match carries the camera, and the object's points
with it, as far along the view: measured on four family runs whose placements stood unrefined
(``bench.robustness.mat_lift``, session 58), the plane lay 0.48-0.82 mm below the truth at the object's foot and
the placements moved the object 1.1-2.0 mm toward the camera, against a depth error of -0.97 to +3.11 mm on the
object itself.

The object shares the range error of the support at its own depths, not the floor's: the points of the support
whose depth lies within ``band_m`` of the object's median depth read, on those runs, within 0.3-1.2 mm of the
object. So the plane keeps its orientation (the whole support and the dots give that,
:mod:`~tofmetry.reconstruct._mat_tilt`) and takes its offset from those points (their median distance to it):
the dots are then cut, and the camera placed, as if the mat read the object's range error, which the object's
points carry too, and the two cancel in the model.

**Not the default** (``registration.mat_plane_at_object``, off). On 26 development runs of draws 113-115 (session 58,
``bench/results/object_family_dev113_115_plane_at_object_rows.jsonl`` against the held-out rows), the 15 whose
placements stood unrefined came out less inflated (mean signed deviation +0.17 -> +0.07 mm on average, mean |d| p90
0.36 -> 0.30 mm) with their scale about as it was (|scale| p90 0.44 -> 0.46 %, RMS 0.26 -> 0.26 %, 5 -> 4 of 13
beyond 0.2 %), while their poses moved away from the truth at the object on 8 of 15 (a fandisk 0.97 -> 2.65 mm, a
rocker arm 2.25 -> 2.89 mm): consistent with the object, the placements carry its own range error, which the
truth counts as a pose error and the pose gate would count as wrong beyond 3 mm. The 11 runs the joint fit held
hardly moved (|scale| RMS 0.12 -> 0.10 %; plaques, boxes, bars and a vase 0.14 -> 0.12 %).

Frames: camera frame (x right, y down, z forward), planes ``n . p + d = 0`` with ``n`` toward the camera [m].
"""

from __future__ import annotations

import numpy as np


def plane_at_depth(plane: np.ndarray, points: np.ndarray, depth_m: float, band_m: float,
                   min_points: int = 500) -> tuple[np.ndarray, float, int]:
    """``plane`` moved along its normal onto the support points near the depth ``depth_m``.

    Parameters
    ----------
    plane : (4,) the support plane, unit normal toward the camera, ``n . p + d = 0`` [m]
    points : (N, 3) the support's points (on the plane within its inlier band, off the object) [m]
    depth_m : the depth Z about which the offset is read (the object's median depth) [m]
    band_m : the points within this of ``depth_m`` in Z count [m]
    min_points : with fewer points in the band the plane is returned as it is

    Returns
    -------
    (plane (4,), its move toward the camera [mm] (0 where not moved), the points it was read on)
    """
    plane = np.asarray(plane, np.float64)
    p = np.asarray(points, np.float64)
    near = p[np.abs(p[:, 2] - depth_m) < band_m]
    if len(near) < min_points:
        return plane, 0.0, len(near)
    h = float(np.median(near @ plane[:3] + plane[3]))  # their median height above the plane (toward the camera)
    out = plane.copy()
    out[3] -= h
    return out, 1e3 * h, len(near)
