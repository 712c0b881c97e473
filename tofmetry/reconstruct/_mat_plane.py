"""The mat's plane from its printed dots alone: where the sheet lies, measured without the depth.

A view places itself on the dot mat (:mod:`~tofmetry.reconstruct._mat_locate`) by cutting its dots'
rays with the support plane the depth shows. That plane carries the depth's own range error: a
millimetre of offset at the mat moves it a millimetre, and nothing in the depth can tell. The dots
can: their layout is printed at a known size, so the plane that makes their centres (the cuts of
their pixels' rays, :func:`dot_centres`) match the layout is the sheet's, up to the lens calibration
(a focal length off by ``f`` puts it ``f`` too far, as a depth gain would). This is a perspective-n-point
fit on dots, with the dots' own pixels as the measurements:

* parameters: the plane's tilt (two angles about the depth plane's frame), its distance (log scale)
  and the sheet's in-plane turn and shift;
* residuals: each matched dot's centre, cut on the plane, minus its printed centre [mm];
* its 1-sigma from the Gauss-Newton covariance scaled by the residuals, and :data:`DISTANCE_FLOOR` of
  the distance for what the residuals do not show.

One view's plane is as good as its dots: on a Kinect v2 simulated at 0.6-1.0 m, 40-55 dots put a
sheet 0.57 m below the camera within 0.1 % (0.6 mm); 7-13 dots within 0.4-1 %. Several views of one
mat average that down. The depth plane's distance carries the calibration's offset (-0.8 to -1.0 mm
in the same views), the same in every view.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from tofmetry._shared.dot_mat import DotMat
from tofmetry.reconstruct._mat_dots import dot_moments, plane_frame, seen_dots
from tofmetry.reconstruct._mat_locate import MatFix, contrast, guided_match


#: relative 1-sigma added to a dot plane's distance: the pixels a dot's rim cuts bias its centre,
#: alike for neighbouring dots, which the residuals do not show (measured on rendered views with perfect
#: depth: 0.17-0.21 % off, 4x the fit's own sigma; on pixel-exact synthetic dots up to 0.2 % at 70 deg
#: incidence)
DISTANCE_FLOOR = 1e-3


@dataclass
class DotPlane:
    """A view's mat plane from its dots (:func:`plane_from_dots`).

    Attributes
    ----------
    plane : (4,) unit normal toward the camera and offset, ``n . p + d = 0`` [m], camera frame
    inverse_depth : (3,) ``(a, b, c)`` with ``1 / Z = a x + b y + c`` on the plane [1/m]
    inverse_depth_cov : (3, 3) their covariance [1/m^2]
    n_dots : matched dots that entered the fit; rms_mm : their residual RMS [mm]
    tilt : (2,) the plane's turn from the depth's support plane about the x and y axes of that
        plane's :func:`~tofmetry.reconstruct._mat_dots.plane_frame` [rad]; tilt_cov : (2, 2) its
        covariance from the fit [rad^2]
    """

    plane: np.ndarray
    inverse_depth: np.ndarray
    inverse_depth_cov: np.ndarray
    n_dots: int
    rms_mm: float
    tilt: np.ndarray = field(default_factory=lambda: np.zeros(2))
    tilt_cov: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))

    def to_dict(self) -> dict:
        """The camera's distance from the sheet [mm], its 1-sigma, the dots and their residual RMS."""
        d = abs(float(self.plane[3]))
        rel = float(np.sqrt(self.inverse_depth_cov[2, 2])) / max(abs(float(self.inverse_depth[2])), 1e-12)
        return {"distance_mm": round(1e3 * d, 3), "distance_sigma_mm": round(1e3 * d * rel, 3),
                "n_dots": self.n_dots, "rms_mm": round(self.rms_mm, 3)}


def dot_centres(dot_rays: list[np.ndarray], plane: np.ndarray) -> np.ndarray:
    """The centres (K, 2) of dots on ``plane`` (4,), from each dot's pixels' rays (M, 3), in
    :func:`~tofmetry.reconstruct._mat_dots.plane_frame`'s x, y [m], as
    :func:`~tofmetry.reconstruct._mat_dots.seen_dots` computes them
    (:func:`~tofmetry.reconstruct._mat_dots.dot_moments`)."""
    n, G = np.asarray(plane[:3], np.float64), plane_frame(plane)
    return np.array([dot_moments(r, n, float(plane[3]), G)[0] for r in dot_rays]).reshape(-1, 2)


def tilted_normal(n0: np.ndarray, a: float, b: float) -> np.ndarray:
    """``n0`` turned by ``a`` and ``b`` [rad] about the x and y axes of its plane frame."""
    G = plane_frame(np.r_[n0, 1.0])[:3, :3]
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    Rl = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]]) @ np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    return G.T @ Rl @ G @ n0


def plane_from_dots(dot_rays: list[np.ndarray], printed_xy: np.ndarray, plane0: np.ndarray, R: np.ndarray,
                    t: np.ndarray) -> DotPlane | None:
    """The plane that makes the dots' centres match their printed layout (module docstring).

    Parameters
    ----------
    dot_rays : per matched dot, (M, 3) its pixels' rays ``(x, y, 1)``, or (M, 4) with their weights
        (:func:`~tofmetry.reconstruct._mat_dots.dot_moments`)
    printed_xy : (K, 2) their printed centres on the sheet [m]
    plane0 : (4,) the start, the depth's support plane (unit normal toward the camera) [m]
    R, t : (2, 2), (2,) the in-plane motion ``sheet = R c + t`` of the centres cut on ``plane0``

    Returns
    -------
    DotPlane, or None with fewer than 6 dots (6 parameters)
    """
    K = len(dot_rays)
    if K < 6:
        return None
    n0 = np.asarray(plane0[:3], np.float64) / np.linalg.norm(plane0[:3])
    d0 = float(plane0[3]) / np.linalg.norm(plane0[:3])
    C = np.asarray(printed_xy, np.float64)

    def plane_of(p):
        return np.r_[tilted_normal(n0, p[0], p[1]), d0 * np.exp(p[2])]

    def resid(p):
        c = dot_centres(dot_rays, plane_of(p))
        th = p[3]
        Rt = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        return ((c @ Rt.T + p[4:6]) - C).ravel() * 1e3

    p0 = np.r_[0.0, 0.0, 0.0, np.arctan2(R[1, 0], R[0, 0]), t]
    sol = least_squares(resid, p0, x_scale=np.full(6, 1e-3), method="lm")
    dof = max(2 * K - 6, 1)
    s2 = float(np.sum(sol.fun ** 2)) / dof
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * s2
    except np.linalg.LinAlgError:
        return None
    pl = plane_of(sol.x)

    def inv_depth(p):
        q = plane_of(p)
        return -q[:3] / q[3]

    # (a, b, c) and their covariance through the numerical Jacobian of the plane's three parameters
    J = np.zeros((3, 3))
    for k in range(3):
        dp = np.zeros(6)
        dp[k] = 1e-6
        J[:, k] = (inv_depth(sol.x + dp) - inv_depth(sol.x - dp)) / 2e-6
    abc = inv_depth(sol.x)
    cov_abc = J @ cov[:3, :3] @ J.T + DISTANCE_FLOOR ** 2 * np.outer(abc, abc)
    return DotPlane(pl, abc, cov_abc, K, float(np.sqrt(np.mean(sol.fun ** 2))), sol.x[:2].copy(), cov[:2, :2].copy())


def matched_dots(alb: np.ndarray, rays: np.ndarray, plane: np.ndarray, fix: MatFix, mat: DotMat,
                 min_dots: int = 8) -> tuple | None:
    """The dots one placed view sees (``alb``, ``rays``, ``plane`` as
    :func:`~tofmetry.reconstruct._mat_dots.seen_dots`), matched to the layout near where its
    placement ``fix`` puts them: (per dot its pixels' rays and weights (M, 4), radii (K,) [m], R (2, 2), t (2,),
    matched (K,), -1: none), or None when fewer than ``min_dots`` are seen or match."""
    if not fix.located:
        return None
    c, r, blobs = seen_dots(alb, rays, plane, contrast(mat), with_rays=True)
    if len(c) < min_dots:
        return None
    S = fix.camera_to_mat @ np.linalg.inv(plane_frame(plane))
    R, t, matched = guided_match(c, r, S[:2, :2], S[:2, 3], mat)
    if (matched >= 0).sum() < min_dots:
        return None
    return blobs, r, R, t, matched


def view_dot_plane(alb: np.ndarray, rays: np.ndarray, plane: np.ndarray, fix: MatFix, mat: DotMat,
                   min_dots: int = 8, seen: tuple | None = None) -> DotPlane | None:
    """One placed view's :class:`DotPlane`: its :func:`matched_dots` (or ``seen``, what that returned),
    then :func:`plane_from_dots`; None when fewer than ``min_dots`` match."""
    seen = matched_dots(alb, rays, plane, fix, mat, min_dots) if seen is None else seen
    if seen is None:
        return None
    blobs, _, R, t, matched = seen
    m = matched >= 0
    return plane_from_dots([b for b, k in zip(blobs, m) if k], mat.dots()[0][matched[m]], plane, R, t)
