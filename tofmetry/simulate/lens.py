"""Random Kinect-v2-class lenses: intrinsics drawn around the real devices, checked invertible.

The spread is taken from the 9 real Kinect v2 IR calibrations of iai_kinect2
(``shared/data/kinect2-device-calibrations/*/calib_ir.yaml``, :data:`REAL_KINECT_V2_IR`):
fx 326.8-369.7 px (8 of 9 within 361-370), fy/fx within 0.7 %, principal point up to 13 px
from the image centre, k1 0.070..0.133, k2 -0.565..-0.215, k3 -0.018..0.745, |p1|, |p2| up
to 1.3e-3 (one device 4.8e-3). k2 and k3 are strongly anti-correlated (r = -0.96): they
trade off against each other in the corners, where a board calibration has few points, so
drawing them independently gives lenses that fold over. One real calibration (307004735147)
does fold over before the image corner (its radial map stops increasing): such a lens is not
physical and is never drawn.

So the radial profile ``f(s) = k1 s + k2 s^2 + k3 s^3`` (``s = r^2``, ``r`` the undistorted
normalised radius) is drawn instead of the coefficients: ``k1`` ~ U(0.05, 0.16), ``f`` at
``r = 0.6`` ~ U(-0.008, 0.014) and at ``r = 0.9`` ~ U(-0.14, 0.16) (the real devices:
0.070..0.133, -0.002..0.009 and -0.099..0.131: barrel or pincushion in the corners), and
``k2, k3`` solved from them. The draws span k2 about -0.9..-0.04 and k3 about -0.09..1.2
(wider than the real devices, with their correlation), tangential ``p1, p2`` ~ U(-2e-3, 2e-3).
A draw is kept only if :func:`lens_check` passes: the radial map is increasing with slope
>= 0.3 up to 5 % beyond the image corner, the undistorted corner radius is at most 1.2,
and the full Brown map (tangential terms included) has a positive Jacobian and is inverted by
:meth:`CameraIntrinsics.undistort_normalized` to 1e-6 px along the image border.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics

#: The 9 real Kinect v2 IR calibrations: serial -> (fx, fy, cx, cy, k1, k2, p1, p2, k3) (iai_kinect2).
REAL_KINECT_V2_IR = {
    "001530565347": (364.9673, 365.5174, 257.1881, 210.7663, 0.1313058, -0.5654264, -0.0008052062, 0.0008979589, 0.7451491),
    "002061565347": (363.45, 363.134, 255.7296, 211.4956, 0.1325716, -0.5106202, -0.0009163181, 0.0002702963, 0.4506012),
    "004429261047": (326.8135, 326.6122, 254.8466, 206.389, 0.06998515, -0.2152282, -0.00117282, -0.0009755345, 0.08173738),
    "017436750747": (365.3862, 367.6601, 255.0487, 209.3974, 0.1058091, -0.2832865, 0.0003950105, -0.0005875515, 0.09691453),
    "155954635247": (369.682, 368.5285, 254.0697, 209.2817, 0.08473032, -0.2929159, -0.001155972, -0.0002100556, 0.185303),
    "196605135147": (366.9476, 364.7912, 242.9855, 207.6985, 0.09655811, -0.2829824, 0.0001588995, -0.0005075148, 0.1052395),
    "299150235147": (366.3835, 367.1438, 255.6453, 203.9802, 0.1095276, -0.3146168, -0.00126136, -0.0007181554, 0.1256538),
    "307004735147": (366.8067, 366.2511, 248.7491, 205.9259, 0.08284573, -0.2383886, 0.0004472492, 0.004778285, -0.01755996),
    "501467543042": (361.0418, 359.682, 252.7856, 207.1256, 0.09332254, -0.2713768, 0.001182184, -0.001327787, 0.1034372),
}

WIDTH, HEIGHT = 512, 424
#: Distributions of :func:`random_intrinsics` (see the module docstring).
FX_NOMINAL, FX_REL, FY_REL, PP_PX = 365.0, 0.05, 0.01, 15.0
K1_RANGE, F06_RANGE, F09_RANGE, P_MAX = (0.05, 0.16), (-0.008, 0.014), (-0.14, 0.16), 2e-3
MIN_SLOPE, MAX_CORNER_R, MARGIN = 0.3, 1.2, 1.05


@dataclass(frozen=True)
class LensCheck:
    """Outcome of :func:`lens_check`.

    Attributes
    ----------
    ok : bool, every test passed
    corner_radius : float, undistorted normalised radius of the farthest image corner (NaN if none)
    min_radial_slope : float, min of d(r (1 + f(r^2))) / dr over [0, 1.05 corner_radius]
    min_jacobian : float, min Jacobian determinant of the Brown map along the image border
    max_roundtrip_px : float, max |project(undistort(u, v)) - (u, v)| along the image border [px]
    """

    ok: bool
    corner_radius: float
    min_radial_slope: float
    min_jacobian: float
    max_roundtrip_px: float


def _border_pixels(intr: CameraIntrinsics, step: int = 4) -> np.ndarray:
    w, h = intr.width - 1, intr.height - 1
    u, v = np.arange(0, w + 1, step, dtype=float), np.arange(0, h + 1, step, dtype=float)
    u, v = np.append(u, w), np.append(v, h)
    return np.vstack([np.column_stack([u, np.zeros_like(u)]), np.column_stack([u, np.full_like(u, h)]),
                      np.column_stack([np.zeros_like(v), v]), np.column_stack([np.full_like(v, w), v])])


def _jacobian_det(xy: np.ndarray, d: np.ndarray) -> np.ndarray:
    k1, k2, p1, p2, k3 = d
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    j11 = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
    j12 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
    j22 = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
    return j11 * j22 - j12 * j12


def lens_check(intr: CameraIntrinsics) -> LensCheck:
    """Whether the Brown model of ``intr`` is monotonic and invertible over the image (and a margin).

    Parameters
    ----------
    intr : CameraIntrinsics

    Returns
    -------
    LensCheck
    """
    k1, k2, _, _, k3 = intr.distortion
    corners = np.array([[0, 0], [intr.width - 1, 0], [0, intr.height - 1], [intr.width - 1, intr.height - 1]], float)
    rd_max = float(np.hypot((corners[:, 0] - intr.cx) / intr.fx, (corners[:, 1] - intr.cy) / intr.fy).max())
    r = np.linspace(0.0, 2.0, 8001)
    s = r * r
    radial = r * (1 + s * (k1 + s * (k2 + s * k3)))
    slope = 1 + s * (3 * k1 + s * (5 * k2 + 7 * k3 * s))
    reach = np.flatnonzero(radial >= rd_max)
    if reach.size == 0:
        return LensCheck(False, math.nan, float(slope.min()), math.nan, math.inf)
    r_c = float(r[reach[0]])
    upto = r <= MARGIN * r_c
    min_slope = float(slope[upto].min())
    uv = _border_pixels(intr)
    xy = intr.pixel_to_normalized(uv)
    back = intr.project(np.column_stack([xy, np.ones(len(xy))]))
    err = float(np.nanmax(np.abs(back - uv))) if np.all(np.isfinite(back)) else math.inf
    jac = float(_jacobian_det(xy * MARGIN, intr.dist_array).min())
    ok = min_slope >= MIN_SLOPE and r_c <= MAX_CORNER_R and jac >= MIN_SLOPE and err < 1e-6
    return LensCheck(bool(ok), r_c, min_slope, jac, err)


def random_intrinsics(rng: np.random.Generator, max_tries: int = 200) -> CameraIntrinsics:
    """Draw the intrinsics of a Kinect-v2-class IR camera (module docstring: distributions).

    Parameters
    ----------
    rng : numpy Generator (the draw is deterministic given its state)
    max_tries : int, redraws allowed to pass :func:`lens_check`

    Returns
    -------
    CameraIntrinsics, 512 x 424, that passes :func:`lens_check`.
    """
    a = np.array([[0.36 ** 2, 0.36 ** 3], [0.81 ** 2, 0.81 ** 3]])
    for _ in range(max_tries):
        fx = FX_NOMINAL * (1 + rng.uniform(-FX_REL, FX_REL))
        fy = fx * (1 + rng.uniform(-FY_REL, FY_REL))
        cx = (WIDTH - 1) / 2 + rng.uniform(-PP_PX, PP_PX)
        cy = (HEIGHT - 1) / 2 + rng.uniform(-PP_PX, PP_PX)
        k1 = rng.uniform(*K1_RANGE)
        f06, f09 = rng.uniform(*F06_RANGE), rng.uniform(*F09_RANGE)
        k2, k3 = np.linalg.solve(a, [f06 - 0.36 * k1, f09 - 0.81 * k1])
        p1, p2 = rng.uniform(-P_MAX, P_MAX, 2)
        intr = CameraIntrinsics(WIDTH, HEIGHT, fx, fy, cx, cy, (k1, float(k2), p1, p2, float(k3)))
        if lens_check(intr).ok:
            return intr
    raise InputError(f"random_intrinsics: no plausible lens in {max_tries} draws (expected one in ~2)")


def corner_rays(intr: CameraIntrinsics) -> np.ndarray:
    """(4, 2) undistorted normalised rays of the corner pixel centres (top-left, top-right,
    bottom-left, bottom-right)."""
    uv = np.array([[0, 0], [intr.width - 1, 0], [0, intr.height - 1], [intr.width - 1, intr.height - 1]], float)
    return intr.pixel_to_normalized(uv)
