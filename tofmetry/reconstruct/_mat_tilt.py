"""A placement's tilt from the mat's dots where they measure it better than the depth does.

A view placed on the dot mat (:func:`~tofmetry.reconstruct._mat_locate.fix_from_matches`) takes its
tilt from the support plane the depth shows. A depth error that changes across the image tilts that
plane: the calibration's per-pixel residual, and most of all a tilt of the depth the calibration left
uncalibrated (its boards contradicted it). Measured on family draw 78, a rocker arm on a sensor with
a 14.7 mm per unit tilt left uncalibrated (0.86 deg at 1 m): every placement 0.26 deg off in the ring
views, 0.73 deg off in the steep ones, each claiming +-0.03 deg in the plane; the joint fit could not
refine them (the same residual moved it beyond the gate), so the run came out 0.79 deg wrong and
reliable. The dots' own plane (:func:`~tofmetry.reconstruct._mat_plane.plane_from_dots`, a
perspective-n-point fit on their printed layout) does not see the depth: in the same views it lay
0.02-0.28 deg from the true sheet.

The two are combined by their covariances (:func:`combined_tilt`): the depth plane's, from the
calibration's residual field (:class:`~tofmetry.reconstruct._adjust_field.DepthFieldPrior`) fitted
over the view's support (:func:`depth_plane_tilt_cov`); the dots', from their fit plus
:data:`DOT_TILT_FLOOR_DEG`. A calibration that calibrated its tilt keeps the depth's plane; one that
did not hands the tilt to the dots. The view is then placed again on the combined plane
(:func:`retilted_fix`), turned about the dots it sees, and carries the combined tilt's 1-sigma.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tofmetry._shared.dot_mat import DotMat
from tofmetry.reconstruct._adjust_field import DepthFieldPrior
from tofmetry.reconstruct._mat_dots import plane_frame
from tofmetry.reconstruct._mat_locate import MatFix, fix_from_matches, guided_match
from tofmetry.reconstruct._mat_plane import DotPlane, dot_centres, tilted_normal
from tofmetry.reconstruct._preprocess import correct_views

#: 1-sigma added to each axis of a dot plane's tilt: what its fit does not show (the dots' rims, the
#: lens calibration). Measured on family draw 78's rocker arm (20 views of 9-49 dots): 0.02-0.28 deg
#: from the true sheet where the fit said 0.03-0.11 deg (three views beyond 2 of its sigmas)
DOT_TILT_FLOOR_DEG = 0.1
#: the support's points used for the depth plane's tilt covariance (evenly subsampled)
MAX_POINTS = 2000
#: support points within this of the plane are searched for the mat's pattern [m]
GROUND_BAND_M = 0.015


def largest_sigma(cov: np.ndarray) -> float:
    """The 1-sigma along the larger axis of a (2, 2) covariance (its unit's square root)."""
    return float(np.sqrt(max(np.linalg.eigvalsh(cov)[-1], 0.0)))


def support_mask(view, seg, plane_threshold_m: float) -> np.ndarray:
    """(N,) the view's points on its support plane and off the object: within ``plane_threshold_m``
    of it, or :data:`GROUND_BAND_M` (the dark toner reads farther than the paper, an amplitude-dependent
    range error: a wide band)."""
    h = view.points @ np.asarray(seg.plane[:3]) + float(seg.plane[3])
    return (np.abs(h) < max(plane_threshold_m, GROUND_BAND_M)) & ~seg.object_mask


def plane_tilt_response(plane: np.ndarray, support_points: np.ndarray, error_terms) -> np.ndarray:
    """(2, T) turn of the support plane refitted over its points [rad per unit of each term] when the
    depth takes the error terms ``error_terms(points) -> (M, T)`` [m per unit]: a depth error
    ``delta`` moves a pixel's point along its ray ``r = (x / z, y / z, 1)`` by ``delta r``, its height
    over the plane by ``delta (n . r)``; the plane refitted over the support turns by the slope of
    those heights, about the x and y axes of :func:`plane_frame` (the :attr:`DotPlane.tilt`
    convention). ``plane``: (4,) unit normal toward the camera [m]; ``support_points``: (M, 3) [m]."""
    P = np.asarray(support_points, np.float64)
    P = P[np.linspace(0, len(P) - 1, min(len(P), MAX_POINTS)).astype(np.int64)]
    n = np.asarray(plane[:3], np.float64)
    G = plane_frame(plane)
    uv = P @ G[:2, :3].T + G[:2, 3]
    dh = np.asarray(error_terms(P), np.float64) * (P / P[:, 2:3] @ n)[:, None]
    A = np.c_[np.ones(len(uv)), uv - uv.mean(0)]
    slope = np.linalg.lstsq(A, dh, rcond=None)[0][1:]  # (2, T): dh/du, dh/dv
    # a height slope (beta, gamma) turns the normal to (-beta, -gamma, 1): a = gamma, b = -beta
    return np.stack([slope[1], -slope[0]])


def depth_plane_tilt_cov(plane: np.ndarray, support_points: np.ndarray, field: DepthFieldPrior) -> np.ndarray:
    """(2, 2) covariance [rad^2] of the support plane's tilt that the depth field ``field`` leaves.

    Linear in the field's coefficients (:func:`plane_tilt_response` of its basis), so their
    covariance (:meth:`DepthFieldPrior.coefficient_sigmas`, its gain term left out: a gain about
    the camera scales the plane and does not turn it) propagates exactly.

    Parameters
    ----------
    plane : (4,) the support plane, unit normal toward the camera, ``n . p + d = 0`` [m], camera frame
    support_points : (M, 3) the support's points, camera frame [m] (at least 3 not on a line)
    field : the calibration's residual field

    Returns
    -------
    (2, 2) covariance of the turn about the x and y axes of :func:`plane_frame` (the
    :attr:`DotPlane.tilt` convention) [rad^2]
    """
    sig = field.coefficient_sigmas()
    if field.gain_sigma > 0:
        sig = sig[:-1]
    S = plane_tilt_response(plane, support_points, lambda P: field.basis(P)[:, :len(sig)])
    return (S * sig ** 2) @ S.T


def combined_tilt(dot: DotPlane, depth_cov: np.ndarray,
                  floor_deg: float = DOT_TILT_FLOOR_DEG) -> tuple[np.ndarray, np.ndarray]:
    """The tilt from the depth's plane (zero, covariance ``depth_cov``) and the dots' (``dot.tilt``,
    its fit's covariance plus ``floor_deg`` per axis), weighed by their covariances: (tilt (2,)
    [rad], its covariance (2, 2) [rad^2]) in :attr:`DotPlane.tilt`'s convention."""
    Sp = np.asarray(dot.tilt_cov, np.float64) + np.radians(floor_deg) ** 2 * np.eye(2)
    Sd = np.asarray(depth_cov, np.float64)
    K = Sd @ np.linalg.inv(Sd + Sp)
    return K @ np.asarray(dot.tilt, np.float64), Sd - K @ Sd


def retilted_fix(fix: MatFix, plane: np.ndarray, dot_rays: list[np.ndarray], radii: np.ndarray, tilt: np.ndarray,
                 tilt_cov: np.ndarray, mat: DotMat) -> tuple[MatFix, np.ndarray]:
    """``fix`` placed again on the support ``plane`` turned by ``tilt`` (:func:`combined_tilt`) about
    the dots it sees, and carrying the tilt's 1-sigma (``tilt_sigma_deg``, its larger axis).

    Parameters
    ----------
    fix : the view's placement on ``plane``; plane : (4,) the depth's support plane [m], camera frame
    dot_rays : per dot seen, (M, 3) its pixels' rays, or (M, 4) with their weights
        (:func:`~tofmetry.reconstruct._mat_dots.dot_moments`); radii : (K,) their radii on ``plane`` [m]
    tilt, tilt_cov : the turn [rad] and its covariance [rad^2] (:attr:`DotPlane.tilt` convention)
    mat : the mat's layout

    Returns
    -------
    (MatFix, the turned plane (4,)); ``fix`` with the tilt's sigma alone when its dots no longer match
    as many of the layout
    """
    sigma = float(np.degrees(largest_sigma(tilt_cov)))
    n0 = np.asarray(plane[:3], np.float64)
    cut = np.concatenate([r[:, :3] * (-float(plane[3]) / (r[:, :3] @ n0))[:, None] for r in dot_rays])
    n1 = tilted_normal(n0, float(tilt[0]), float(tilt[1]))
    turned = np.r_[n1, -float(n1 @ cut.mean(0))]
    c = dot_centres(dot_rays, turned)
    S = fix.camera_to_mat @ np.linalg.inv(plane_frame(turned))
    R, t, matched = guided_match(c, np.asarray(radii), S[:2, :2], S[:2, 3], mat)
    if (matched >= 0).sum() < fix.n_matched:
        return replace(fix, tilt_sigma_deg=sigma), plane
    out = fix_from_matches(c, R, t, matched, mat, turned, fix.how)
    return replace(out, tilt_sigma_deg=sigma, tilt_deg=float(np.degrees(np.linalg.norm(tilt)))), turned


@dataclass
class MatDepthTilt:
    """The depth's tilt across the image measured on the mat (:func:`depth_tilt_from_dots`).

    Attributes
    ----------
    measured_mm : (2,) the tilt the views' depth shows against their dot planes, ``dZ = t . (x / z,
        y / z)`` [mm per unit]; measured_cov : (2, 2) its covariance [mm^2]
    prior_sigma_mm : 1-sigma of the tilt the calibration may have left [mm per unit]
    applied_mm : (2,) the measurement weighed against that prior, taken off every view's depth;
        applied_cov : (2, 2) its covariance [mm^2]
    n_views : views with a dot plane; chi2_per_dof : their agreement about it (1: as their sigmas say)
    """

    measured_mm: np.ndarray
    measured_cov: np.ndarray
    prior_sigma_mm: float
    applied_mm: np.ndarray
    applied_cov: np.ndarray
    n_views: int
    chi2_per_dof: float

    @property
    def sigma_mm(self) -> float:
        """The larger axis' 1-sigma of what is left after the tilt applied [mm per unit]."""
        return largest_sigma(self.applied_cov)

    def to_dict(self) -> dict:
        r = lambda a: [round(float(x), 3) for x in np.ravel(a)]
        return {"measured_mm": r(self.measured_mm), "measured_sigma_mm": r(np.sqrt(np.diag(self.measured_cov))),
                "prior_sigma_mm": round(self.prior_sigma_mm, 3), "applied_mm": r(self.applied_mm),
                "applied_sigma_mm": r(np.sqrt(np.diag(self.applied_cov))), "n_views": self.n_views,
                "chi2_per_dof": round(self.chi2_per_dof, 3),
                "unit": "mm per unit of x / z: dZ = t . (x / z, y / z), taken off every view's depth"}


def depth_tilt_from_dots(samples: list[tuple[np.ndarray, np.ndarray, DotPlane]], prior_sigma_mm: float,
                         field: DepthFieldPrior | None = None, floor_deg: float = DOT_TILT_FLOOR_DEG,
                         min_views: int = 3) -> MatDepthTilt | None:
    """The depth's tilt across the image from views whose dots gave their mat's plane.

    A depth error linear in the image position, ``dZ = t . (x / z, y / z)``, is the same in every
    view and turns every view's support plane by ``S_v t`` (``S_v``: the plane refitted over that
    view's support, :func:`plane_tilt_response`); the dots' planes
    (:func:`~tofmetry.reconstruct._mat_plane.plane_from_dots`) do not see it, so each dot plane's turn
    from its support plane (:attr:`DotPlane.tilt`) measures ``-S_v t``, within its fit's covariance,
    ``floor_deg`` and the turn the rest of the calibration's residual field gives the support plane
    (``field`` without its tilt, :func:`depth_plane_tilt_cov`). The views are combined by least
    squares (the covariance widened by their disagreement) and the result weighed against
    ``prior_sigma_mm``, the tilt the calibration may have left: a calibrated tilt is hardly moved, an
    uncalibrated one is taken from the mat.

    Measured on family draw 78 before this form (a per-pixel fit of the support against the dot
    plane, linear in the depth as a nuisance): 12 views at 20 deg elevation read -9.4 +- 1.9 mm per
    unit about x where the sensor had 0.0, as the range error along an oblique support follows y.
    The planes' turns do not carry a range error (a gain about the camera turns no plane; the
    calibration's offset, 0.3 mm, turns them by ~0.01 deg): (2.1, -2.2) +- (1.6, 2.5) against (1.2, 0.0).

    Parameters
    ----------
    samples : per view with a dot plane, (its support plane (4,) [m]; its support's points (M, 3) [m],
        camera frame; its DotPlane, fitted from that support plane)
    prior_sigma_mm : 1-sigma of the tilt the calibration may have left [mm per unit]
    field : the calibration's residual field (its tilt term left out here), or None
    floor_deg : each dot plane's tilt floor (:data:`DOT_TILT_FLOOR_DEG`)
    min_views : fewer views: None

    Returns
    -------
    MatDepthTilt, or None
    """
    if len(samples) < min_views:
        return None
    rest = None if field is None else replace(field, tilt_sigma_m=0.0, gain_sigma=0.0)
    H, b, terms = np.zeros((2, 2)), np.zeros(2), []
    for plane, P, dp in samples:
        S = plane_tilt_response(plane, P, lambda Q: Q[:, :2] / Q[:, 2:3])  # [rad per m of t]
        C = np.asarray(dp.tilt_cov, np.float64) + np.radians(floor_deg) ** 2 * np.eye(2)
        if rest is not None:
            C = C + depth_plane_tilt_cov(plane, P, rest)
        W = np.linalg.inv(C)
        H += S.T @ W @ S
        b -= S.T @ W @ np.asarray(dp.tilt, np.float64)
        terms.append((S, W, np.asarray(dp.tilt, np.float64)))
    cov = np.linalg.inv(H)
    t = cov @ b
    chi2 = float(sum((d + S @ t) @ W @ (d + S @ t) for S, W, d in terms))
    dof = 2 * len(terms) - 2
    ct = cov * max(1.0, chi2 / dof) * 1e6
    t = t * 1e3
    P0 = prior_sigma_mm ** 2 * np.eye(2)
    K = P0 @ np.linalg.inv(P0 + ct)
    return MatDepthTilt(t, ct, float(prior_sigma_mm), K @ t, P0 - K @ P0, len(terms), chi2 / dof)


def without_depth_tilt(points: np.ndarray, depth_mm: np.ndarray, rays: np.ndarray,
                       tilt_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A view's points (N, 3) [m] and depth (H, W) [mm, 0: none] with ``dZ = t . (x / z, y / z)``
    taken off (``tilt_mm`` (2,) [mm per unit]; ``rays`` (H, W, 2) each pixel's ``x / z, y / z``):
    each point moves along its ray."""
    t = np.asarray(tilt_mm, np.float64)
    dz = 1e-3 * (points[:, :2] / points[:, 2:3]) @ t
    new = depth_mm.astype(np.float64, copy=True)
    valid = new > 0
    new[valid] -= rays[valid] @ t
    return points * (1.0 - dz / points[:, 2])[:, None], new


def take_off_depth_tilt(views, segs, intr, dot_planes: list, prior_sigma_mm: float, plane_threshold_m: float,
                        field: DepthFieldPrior | None = None) -> MatDepthTilt | None:
    """The depth's tilt (:func:`depth_tilt_from_dots`) measured on the views whose dots gave their
    plane (``dot_planes``: per view a DotPlane or None, fitted from the view's support plane) and
    taken off every view in place: points and depth (:func:`without_depth_tilt`), each support plane
    refitted on the points that lay on it. None (nothing changed) with fewer than three such views.

    Parameters
    ----------
    views, segs : the prepared views and their segmentations (support planes)
    intr : the depth images' intrinsics; prior_sigma_mm : the tilt the calibration may have left [mm per unit]
    plane_threshold_m : the support plane's inlier distance [m]
    field : the calibration's residual field (:func:`depth_tilt_from_dots`), or None
    """
    samples = [(s.plane, v.points[support_mask(v, s, plane_threshold_m)], dp)
               for v, s, dp in zip(views, segs, dot_planes) if dp is not None and s.plane is not None]
    mt = depth_tilt_from_dots(samples, prior_sigma_mm, field)
    if mt is None:
        return None
    rays = intr.ray_table(True)
    correct_views(views, segs, plane_threshold_m, lambda v: without_depth_tilt(v.points, v.depth_mm, rays, mt.applied_mm))
    return mt
