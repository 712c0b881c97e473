"""Judging a lens by ray error: the angle between two models' rays over the full pixel grid,
in pixels at the focal length, and the ray error predicted from a calibration's parameter
covariance (first-order propagation). A reprojection RMS on the board points says nothing about
the image where no board was."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor import CameraIntrinsics

PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
#: Fraction of the image width/height of each of the four corner regions (coverage, ray error).
CORNER_FRAC = 0.1
_CORNER_NAMES = ("top-left", "top-right", "bottom-left", "bottom-right")


@dataclass(eq=False)
class RayError:
    """Ray error of one lens model against another over the full pixel grid.

    Attributes
    ----------
    map_px : (H, W) float64 [px] (or the sub-sampled grid, see ``step``), the angle between the
        two models' rays through each pixel times the reference focal length; NaN outside a mask
    step : grid step of ``map_px`` [px] (pixel ``(u, v) = (step j, step i)``)
    rms_px, p90_px, max_px : over the (masked) grid [px]
    corners_max_px, corners_rms_px : over the four corner regions (``corner_frac`` of the width
        and height at each image corner) [px]
    per_corner_max_px : dict region name -> max there [px]
    focal_px : the focal length used to express angles in pixels [px]
    u_px, v_px : (W',) and (H',) pixel coordinates of the columns and rows of ``map_px`` [px]
    """

    map_px: np.ndarray
    step: int
    rms_px: float
    p90_px: float
    max_px: float
    corners_max_px: float
    corners_rms_px: float
    per_corner_max_px: dict
    focal_px: float
    u_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    v_px: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def to_dict(self, with_map: bool = False) -> dict:
        d = {"rms_px": self.rms_px, "p90_px": self.p90_px, "max_px": self.max_px,
             "corners_max_px": self.corners_max_px, "corners_rms_px": self.corners_rms_px,
             "per_corner_max_px": self.per_corner_max_px, "focal_px": self.focal_px, "step_px": self.step}
        if with_map:
            d["map_px"] = np.round(self.map_px, 5).tolist()
            d["u_px"], d["v_px"] = self.u_px.tolist(), self.v_px.tolist()
        return d


def _grid_uv(width: int, height: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    us = np.arange(0, width, step, dtype=np.float64)
    vs = np.arange(0, height, step, dtype=np.float64)
    if us[-1] != width - 1:
        us = np.append(us, width - 1.0)
    if vs[-1] != height - 1:
        vs = np.append(vs, height - 1.0)
    return np.meshgrid(us, vs)


def corner_regions(u: np.ndarray, v: np.ndarray, width: int, height: int, frac: float = CORNER_FRAC) -> dict:
    """Masks of the four image-corner regions (``frac`` of the width and height at each corner).

    Parameters
    ----------
    u, v : pixel coordinates (any shape) [px]; width, height : image size [px]

    Returns
    -------
    dict name (``top-left``, ``top-right``, ``bottom-left``, ``bottom-right``) -> bool mask
    shaped like ``u``.
    """
    cw, ch = frac * width - 0.5, frac * height - 0.5
    left, right = u <= cw, u >= width - 1 - cw
    top, bottom = v <= ch, v >= height - 1 - ch
    return dict(zip(_CORNER_NAMES, (top & left, top & right, bottom & left, bottom & right)))


def _summary(map_px: np.ndarray, u: np.ndarray, v: np.ndarray, width: int, height: int, corner_frac: float):
    fin = np.isfinite(map_px)
    vals = map_px[fin]
    if vals.size == 0:
        raise InputError("ray error: the mask leaves no pixel")
    regions = corner_regions(u, v, width, height, corner_frac)
    per = {}
    allc = []
    for name, m in regions.items():
        x = map_px[m & fin]
        per[name] = float(x.max()) if x.size else float("nan")
        allc.append(x)
    allc = np.concatenate(allc)
    return (float(np.sqrt(np.mean(vals ** 2))), float(np.percentile(vals, 90)), float(vals.max()),
            float(allc.max()) if allc.size else float("nan"),
            float(np.sqrt(np.mean(allc ** 2))) if allc.size else float("nan"), per)


def ray_error_px(true: CameraIntrinsics, est: CameraIntrinsics, mask: np.ndarray | None = None, *, step: int = 1,
                 corner_frac: float = CORNER_FRAC) -> RayError:
    """Ray error of ``est`` against ``true`` over the full pixel grid, image corners included.

    For every pixel, the angle between the ray of ``true`` and the ray of ``est`` through that
    pixel (undistorted, exact inversion of the Brown model), times the mean focal length of
    ``true``: the error in pixels a point at that pixel would have when projected with one
    model and back-projected with the other. Near the image centre it equals the pixel
    distance of :func:`ray_difference_px`.

    Parameters
    ----------
    true, est : CameraIntrinsics of the same image size
    mask : optional (H, W) bool, pixels to include (e.g. the area covered by boards)
    step : evaluate every ``step``-th pixel (plus the last row and column), for speed
    corner_frac : size of the four corner regions (fraction of width and height)

    Returns
    -------
    RayError (map + RMS, p90, max, and the values in the corner regions).
    """
    if (true.width, true.height) != (est.width, est.height):
        raise InputError(f"ray_error_px: image sizes differ: {true.width}x{true.height} vs {est.width}x{est.height}")
    step = int(step)
    if step < 1:
        raise InputError(f"ray_error_px: step must be >= 1, found {step}")
    u, v = _grid_uv(true.width, true.height, step)
    uv = np.column_stack([u.ravel(), v.ravel()])
    a = np.column_stack([true.pixel_to_normalized(uv), np.ones(len(uv))])
    b = np.column_stack([est.pixel_to_normalized(uv), np.ones(len(uv))])
    ang = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))
    f = 0.5 * (true.fx + true.fy)
    m = (ang * f).reshape(u.shape)
    if mask is not None:
        mk = np.asarray(mask, bool)
        if mk.shape != (true.height, true.width):
            raise InputError(f"ray_error_px: mask shape {mk.shape} differs from the image {(true.height, true.width)}")
        m = np.where(mk[v.astype(int), u.astype(int)], m, np.nan)
    rms, p90, mx, cmax, crms, per = _summary(m, u, v, true.width, true.height, corner_frac)
    return RayError(m, step, rms, p90, mx, cmax, crms, per, f, u[0].copy(), v[:, 0].copy())


def ray_difference_px(a: CameraIntrinsics, b: CameraIntrinsics, mask: np.ndarray | None = None) -> np.ndarray:
    """Back-projection difference between two models, expressed in pixels.

    For every pixel, the ray of model ``a`` is reprojected with model ``b``'s focal lengths
    (undistorted normalised coordinates times (fx, fy) of ``b``): (H, W) float64 [px] distance
    between the two models' rays, NaN outside ``mask``. Prefer :func:`ray_error_px` (angle,
    summaries, corner regions).
    """
    ra, rb = a.ray_table(), b.ray_table()
    d = np.hypot((ra[..., 0] - rb[..., 0]) * b.fx, (ra[..., 1] - rb[..., 1]) * b.fy)
    if mask is not None:
        d = np.where(mask, d, np.nan)
    return d


def ray_jacobian(intr: CameraIntrinsics, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Derivative of the undistorted ray through pixels ``uv`` with respect to the parameters.

    Implicit differentiation of ``distort(x(theta); k) = ((u - cx) / fx, (v - cy) / fy)``.

    Parameters
    ----------
    intr : CameraIntrinsics; uv : (N, 2) [px]

    Returns
    -------
    xy : (N, 2) undistorted normalised ray ``(x, y)`` (the ray is ``(x, y, 1)``)
    J : (N, 2, 9) d(x, y) / d(fx, fy, cx, cy, k1, k2, p1, p2, k3) (order :data:`PARAMS`)
    """
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    xy = intr.pixel_to_normalized(uv)
    k1, k2, p1, p2, k3 = intr.dist_array
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    JD = np.empty((len(x), 2, 2))
    JD[:, 0, 0] = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
    JD[:, 0, 1] = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
    JD[:, 1, 0] = JD[:, 0, 1]
    JD[:, 1, 1] = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
    xd = (uv[:, 0] - intr.cx) / intr.fx
    yd = (uv[:, 1] - intr.cy) / intr.fy
    rhs = np.zeros((len(x), 2, 9))
    # d(target)/d(theta): the distorted coordinates move with fx, fy, cx, cy
    rhs[:, 0, 0] = -xd / intr.fx
    rhs[:, 1, 1] = -yd / intr.fy
    rhs[:, 0, 2] = -1.0 / intr.fx
    rhs[:, 1, 3] = -1.0 / intr.fy
    # minus d(distort)/d(k) at fixed (x, y)
    r4 = r2 * r2
    rhs[:, 0, 4], rhs[:, 1, 4] = -x * r2, -y * r2
    rhs[:, 0, 5], rhs[:, 1, 5] = -x * r4, -y * r4
    rhs[:, 0, 6], rhs[:, 1, 6] = -2 * x * y, -(r2 + 2 * y * y)
    rhs[:, 0, 7], rhs[:, 1, 7] = -(r2 + 2 * x * x), -2 * x * y
    rhs[:, 0, 8], rhs[:, 1, 8] = -x * r2 * r4, -y * r2 * r4
    return xy, np.linalg.solve(JD, rhs)


def predicted_ray_error_px(intr: CameraIntrinsics, cov: np.ndarray, *, step: int = 4,
                           corner_frac: float = CORNER_FRAC) -> RayError:
    """Predicted (1-sigma, RMS) ray error over the full image grid from the parameter covariance.

    First-order propagation: for each pixel the covariance of the unit ray direction is
    ``P G cov G^T P^T / |r|^2`` (``G`` = :func:`ray_jacobian`, ``P`` the projection onto the
    plane normal to the ray ``r = (x, y, 1)``); its trace is the expected squared angle between
    the estimated and the true ray. Reported as ``sqrt(trace) x`` the mean focal length [px].
    Where boards were, this is small; where none was (image corners) the extrapolated
    distortion polynomial can be far off, and the map says by how much. First order: where the
    error reaches pixels, the curvature of the distortion polynomial makes the true error up to
    about 25 % larger (measured by Monte Carlo on a wide test lens, ``tests/calibrate``). It
    assumes independent corner errors; correlated (systematic) corner errors are not in it.

    Parameters
    ----------
    intr : the estimated intrinsics; cov : (9, 9) covariance of :data:`PARAMS`
    step, corner_frac : see :func:`ray_error_px`

    Returns
    -------
    RayError (its fields hold the predicted values).
    """
    cov = np.asarray(cov, np.float64)
    if cov.shape != (9, 9) or not np.all(np.isfinite(cov)):
        raise InputError(f"predicted_ray_error_px: cov must be a finite (9, 9) matrix, found {cov.shape}")
    u, v = _grid_uv(intr.width, intr.height, int(step))
    uv = np.column_stack([u.ravel(), v.ravel()])
    xy, J = ray_jacobian(intr, uv)
    r = np.column_stack([xy, np.ones(len(xy))])
    nr = np.linalg.norm(r, axis=1)
    n = r / nr[:, None]
    G = np.zeros((len(xy), 3, 9))
    G[:, :2] = J
    PG = G - n[:, :, None] * np.einsum("ni,nij->nj", n, G)[:, None, :]
    var = np.einsum("nij,jk,nik->n", PG, cov, PG) / nr ** 2
    f = 0.5 * (intr.fx + intr.fy)
    m = (np.sqrt(np.maximum(var, 0.0)) * f).reshape(u.shape)
    rms, p90, mx, cmax, crms, per = _summary(m, u, v, intr.width, intr.height, corner_frac)
    return RayError(m, int(step), rms, p90, mx, cmax, crms, per, f, u[0].copy(), v[:, 0].copy())


# ----------------------------------------------------------------------------- coverage
