"""The model's scale on a dot mat: what the placements hold, the joint fit may not bend.

The mat places each view from its dots and the support plane, independently of the object; the
joint fit then refines the views on the object's overlaps. Its data pull the poses with the depth
calibration's residual field as well as with the surfaces' real misfit, and some pose modes change
the model's *scale* (a plaque's, a vase's, a box's faces seen from opposite sides) while the
overlaps barely see them. Measured on the family (draw 87's two worst scales): the placements
alone gave the vase +0.09 % and the plaque -0.05 %; after the fit +0.17 % and +0.37 %.

:func:`hold_scale` weighs the two on the scale mode only. The fit's change of the model's scale
from the placements, ``s`` (:func:`~tofmetry.reconstruct._scale_budget.view_scale_rows` on the
model's own points), is one estimate of the placements' scale error with the fit's uncertainty
(``sigma_fit``: its noise and the calibration's field, the scale budget's pose term); the
placements say zero with theirs (``sigma_mat``: each placement's covariance from its dots,
:func:`placement_covariance`). Their weighted mean keeps ``s sigma_mat^2 / (sigma_mat^2 +
sigma_fit^2)``; the rest is taken off along the direction the fit's data constrain least (its pose
covariance times the scale's gradient), which moves the overlaps' misfit least, and the scale's
1-sigma becomes ``(sigma_fit^-2 + sigma_mat^-2)^-1/2``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import block_diag
from scipy.spatial.transform import Rotation

from tofmetry._shared.geometry import skew
from tofmetry.reconstruct._adjust_terms import _exp_se3
from tofmetry.reconstruct._mat_locate import MatFix
from tofmetry.reconstruct._scale_budget import sampled_points, view_scale_rows


@dataclass(frozen=True)
class ScaleHold:
    """What :func:`hold_scale` did (relative scales, dimensionless: 0.001 = 0.1 %).

    Attributes
    ----------
    fit_scale : the model's scale change the joint fit's moves from the placements make
    fit_sigma : the fit's own scale 1-sigma (its noise and the calibration's residual field)
    mat_sigma : the placements' scale 1-sigma (their dots, tilt and height)
    applied : the scale change made to the fitted poses (``-fit_scale`` times the fit's weight)
    held_sigma : the scale's 1-sigma the two together leave
    note : why nothing was done, where so
    """

    fit_scale: float = float("nan")
    fit_sigma: float = float("nan")
    mat_sigma: float = float("nan")
    applied: float = 0.0
    held_sigma: float = float("nan")
    note: str = ""

    def to_dict(self) -> dict:
        pct = {k: (None if not np.isfinite(v) else round(100 * v, 4)) for k, v in
               (("fit_scale_pct", self.fit_scale), ("fit_sigma_pct", self.fit_sigma),
                ("mat_sigma_pct", self.mat_sigma), ("applied_pct", self.applied),
                ("held_sigma_pct", self.held_sigma))}
        return pct | ({"note": self.note} if self.note else {})


def left_increments(start: np.ndarray, fitted: np.ndarray) -> np.ndarray:
    """(V, 6) left increments (rotation vector [rad], translation [m], world frame) taking the
    camera-to-world poses ``start`` (V, 4, 4) to ``fitted`` (V, 4, 4): ``fitted = E start`` with
    ``E`` moving a world point ``p`` by about ``w x p + t``."""
    E = np.einsum("vij,vjk->vik", fitted, np.linalg.inv(start))
    return np.c_[Rotation.from_matrix(E[:, :3, :3]).as_rotvec(), E[:, :3, 3]]


def apply_increments(poses: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``poses`` (V, 4, 4) moved by left increments ``xi`` (V, 6) (:func:`left_increments`), as the
    joint fit moves its poses."""
    return np.array([_exp_se3(x) @ T for x, T in zip(xi, poses)])


def placement_covariance(fix: MatFix | None, tilt_sigma_deg: float, height_sigma_m: float) -> np.ndarray:
    """(6, 6) covariance of a mat placement's left increment (rotation vector [rad^2], translation
    [m^2], mat frame). About the vertical and along the sheet, the dots' (``fix.sigma_deg``, and
    ``fix.sigma_mm`` at their centroid ``fix.centre_xy``, where the turn and the shift are
    independent); the tilt, the dots' and the plane's (``fix.tilt_sigma_deg``) or ``tilt_sigma_deg``
    where not judged; the height, ``height_sigma_m``. A view the dots did not place (``fix`` None or
    not located): ``tilt_sigma_deg`` about every axis and ``height_sigma_m`` along every axis.

    A range error of the depth common to the view is left out: it moves the support plane, hence
    the dots' cuts, along the rays as it moves the view's object points, and the placement that
    follows it puts the points back (on the family's draw 87, counting it along the optical axis
    held the scales less well: p90 0.19 % against 0.15 %)."""
    placed = fix is not None and fix.located and np.isfinite(fix.sigma_deg) and np.isfinite(fix.sigma_mm)
    if placed:
        tilt = fix.tilt_sigma_deg if np.isfinite(fix.tilt_sigma_deg) else tilt_sigma_deg
        sw = np.radians([tilt, tilt, fix.sigma_deg])
        sn = np.array([fix.sigma_mm * 1e-3, fix.sigma_mm * 1e-3, height_sigma_m])
        # about the dots' centroid; a placement that gave none, about the sheet's middle, where the object stands
        # (a NaN there had made every hold of the scan "unknown": draws 95-102, 6 rocker arms seen by a low ring)
        c = np.r_[fix.centre_xy, 0.0] if np.all(np.isfinite(fix.centre_xy)) else np.zeros(3)
    else:
        sw, sn, c = np.radians([tilt_sigma_deg] * 3), np.full(3, height_sigma_m), np.zeros(3)
    A = np.block([[np.eye(3), np.zeros((3, 3))], [skew(c), np.eye(3)]])  # a turn about c: t = c x w + shift
    return A @ np.diag(np.r_[sw, sn] ** 2) @ A.T


def hold_scale(rows: np.ndarray | None, start: np.ndarray, fitted: np.ndarray, covariances: np.ndarray,
               fit_sigma: float, fit_cov: np.ndarray | None) -> tuple[np.ndarray, ScaleHold]:
    """The fitted poses with the scale mode weighed against the placements' (module docstring).

    Parameters
    ----------
    rows : (V, 6) the model's relative scale per unit left increment of each view
        (:func:`~tofmetry.reconstruct._scale_budget.view_scale_rows`), or None (scale and offset
        not separable on this shape: nothing is done)
    start : (V, 4, 4) the mat's placements, camera to mat [m]; fitted : (V, 4, 4) the joint fit's poses
    covariances : (V, 6, 6) each placement's covariance (:func:`placement_covariance`)
    fit_sigma : the fit's scale 1-sigma (the scale budget's pose term)
    fit_cov : (6 (V - 1), 6 (V - 1)) the fit's pose covariance (view 0 held), or None: the
        placements' covariances are the metric of the change

    Returns
    -------
    (poses (V, 4, 4), :class:`ScaleHold`)
    """
    if rows is None:
        return fitted, ScaleHold(note="scale and offset are not separable on this shape")
    s = float(np.sum(rows * left_increments(start, fitted)))
    mat_var = float(np.einsum("vi,vij,vj->", rows, covariances, rows))
    if not (np.isfinite(fit_sigma) and fit_sigma > 0 and np.isfinite(mat_var) and mat_var > 0):
        return fitted, ScaleHold(s, fit_sigma, float(np.sqrt(max(mat_var, 0.0))),
                                 note="the fit's or the placements' scale uncertainty is unknown")
    w_fit = fit_sigma ** 2 / (fit_sigma ** 2 + mat_var)  # the share of s the placements take back
    delta = -s * w_fit
    a = rows[1:].ravel()
    C = fit_cov if fit_cov is not None and fit_cov.shape == (len(a), len(a)) and np.all(np.isfinite(fit_cov)) \
        else block_diag(*covariances[1:])
    g = C @ a
    if not float(a @ g) > 0:  # no move of the views 1.. changes the scale: view 0 alone sees the object
        return fitted, ScaleHold(s, fit_sigma, float(np.sqrt(mat_var)), note="no view but the first moves the scale")
    xi = np.zeros_like(rows)
    xi[1:] = (delta / float(a @ g) * g).reshape(-1, 6)
    held = float(1.0 / np.sqrt(1.0 / fit_sigma ** 2 + 1.0 / mat_var))
    return apply_increments(fitted, xi), ScaleHold(s, fit_sigma, float(np.sqrt(mat_var)), delta, held)


def held_poses(points_cam: list[np.ndarray], normals_cam: list[np.ndarray], start: np.ndarray, fitted: np.ndarray,
               fixes: list[MatFix | None], fit_sigma: float, fit_cov: np.ndarray | None, tilt_sigma_deg: float,
               height_sigma_m: float, max_points: int = 20_000) -> tuple[np.ndarray, ScaleHold]:
    """:func:`hold_scale` on the model's own points.

    Parameters
    ----------
    points_cam, normals_cam : per view (N_v, 3) the object's points [m] and unit outward normals, camera frame
    start, fitted : (V, 4, 4) the placements and the joint fit's poses, camera to mat [m]
    fixes : per view its :class:`MatFix` (None: placed through its neighbours)
    fit_sigma, fit_cov : as :func:`hold_scale`
    tilt_sigma_deg, height_sigma_m : :func:`placement_covariance`'s fallbacks
    max_points : points drawn (seeded) over all views
    """
    if sum(len(p) for p in points_cam) < 10:
        return fitted, ScaleHold(note="no object points")
    rows, covs = _rows_and_covariances(points_cam, normals_cam, fitted, fixes, tilt_sigma_deg, height_sigma_m,
                                       max_points)
    return hold_scale(rows, start, fitted, covs, fit_sigma, fit_cov)


def placed_scale(points_cam: list[np.ndarray], normals_cam: list[np.ndarray], placed: np.ndarray,
                 fixes: list[MatFix | None], tilt_sigma_deg: float, height_sigma_m: float,
                 max_points: int = 20_000) -> ScaleHold:
    """The model's scale 1-sigma the mat's placements leave where they stand as the poses, unrefined
    by the joint fit (``mat_sigma``; :func:`placement_covariance` through each view's scale row).

    Where the joint fit refines the placements, :func:`hold_scale` counts them in the held sigma;
    where it was not kept (the calibration's residual could move it beyond the gate, or it slid
    views beyond it), the placements' own pose errors scale the model and the depth chain's
    prediction has no term for them. On the 22 reliable runs of family draws 106-112 whose placements
    stood unrefined the models' scale error followed the placements' (correlation +0.81, read from
    the stored rows by ``bench/robustness/placement_scale``); rerun with this term in quadrature
    (session 56, ``bench/results/object_family_dev106_112_unrefined_placed_sigma_rows.jsonl``),
    |error| / sigma p90 went 1.77 -> 1.53 (1.645 exact), 21 of 22 within 2 sigmas either way. The
    term is added on 17 of them; on the 5 heads (igea) scale and offset are not separable on the
    views' own points, and it is not.

    Parameters
    ----------
    points_cam, normals_cam : per view (N_v, 3) the object's points [m] and unit outward normals, camera frame
    placed : (V, 4, 4) the placements, camera to mat [m]
    fixes, tilt_sigma_deg, height_sigma_m, max_points : as :func:`held_poses`

    Returns
    -------
    :class:`ScaleHold` with ``mat_sigma`` set (NaN with a ``note`` where scale and offset are not
    separable on this shape or there are no object points), nothing applied
    """
    if sum(len(p) for p in points_cam) < 10:
        return ScaleHold(note="no object points")
    rows, covs = _rows_and_covariances(points_cam, normals_cam, placed, fixes, tilt_sigma_deg, height_sigma_m,
                                       max_points)
    if rows is None:
        return ScaleHold(note="scale and offset are not separable on this shape")
    var = float(np.einsum("vi,vij,vj->", rows, covs, rows))
    return ScaleHold(mat_sigma=float(np.sqrt(var)) if np.isfinite(var) and var >= 0 else float("nan"),
                     note="the placements stand unrefined: their own scale uncertainty")


def _rows_and_covariances(points_cam, normals_cam, poses, fixes, tilt_sigma_deg, height_sigma_m, max_points):
    """(V, 6) scale rows (:func:`~tofmetry.reconstruct._scale_budget.view_scale_rows`, None where not
    separable) of the views' points carried by ``poses`` (V, 4, 4), and (V, 6, 6) the placements'
    covariances (:func:`placement_covariance`)."""
    _, view, _, _, P, N = sampled_points(points_cam, normals_cam, poses, max_points)
    covs = np.array([placement_covariance(f, tilt_sigma_deg, height_sigma_m) for f in fixes])
    return view_scale_rows(P, N, view, len(poses)), covs


def budget_held(budget, hold: ScaleHold | None):
    """The scale budget ``budget`` (``(offset_sigma_m, gain_sigma) -> dict``,
    :func:`~tofmetry.reconstruct._adjust_stage.scale_budget_of`) with its poses' term replaced by
    what the mat and the fit hold together (``hold.held_sigma``) where :func:`hold_scale` weighed them."""
    if hold is None or not np.isfinite(hold.held_sigma):
        return budget

    def held(offset_sigma_m: float, gain_sigma: float) -> dict:
        b = budget(offset_sigma_m, gain_sigma)
        if "sigma_poses_held" in b:
            b["poses"] = b["poses"] | {"sigma_fit": b["poses"]["sigma"], "sigma": hold.held_sigma,
                                       "held_by": "the dot mat's placements"}
            b["sigma"] = float(np.hypot(b["sigma_poses_held"], hold.held_sigma))
        return b
    return held
