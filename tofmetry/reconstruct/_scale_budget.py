"""How much each depth error the chain leaves behind changes the model's scale, on the model's own geometry.

A depth error moves every point along its ray: ``Z -> Z + delta``, so a camera-frame point ``p``
moves by ``p delta / Z``. What that does to the model's *scale* depends on where the surface faces
the cameras: on a surface seen head-on the move is along the normal (the model grows or shrinks),
at the silhouette it slides along the surface (nothing changes). A closed-form rule ("a range
offset ``e`` scales the lateral size by ``e / z``, a gain ``g`` by ``g / 2``") ignores this and
the depth errors that change from point to point, such as the amplitude bias.

:func:`scale_response` measures it instead: the per-point moves of a depth-error pattern are
mapped to the world with the adjusted poses and fitted, point to plane, by a rigid motion, a
scale about the centroid and an offset along the normals (the model that
:func:`tofmetry.evaluate.scale_from_reference` fits against a reference). Its scale is the
model's scale change per unit of the pattern. :func:`scale_budget` does this for the three
errors the chain leaves (all first order, poses held):

* the calibration's range offset between its stations, ``delta = e`` (its predicted central error);
* a depth gain over the object's depth, ``delta = g (Z - z_ref)`` (the self-calibrated gain's
  standard error, or what the calibration can leave between stations);
* the amplitude bias, ``delta = dk ln(A_white / A)``, with ``dk`` the uncertainty of the
  coefficient ``k`` (the study's 6.7 mm per ln unit came from one sensor).

Each term's scale standard deviation is ``|response| * sigma``; they are added in quadrature.

The poses are not held in the end: the joint fit places them with an uncertainty of its own (the
data's noise, :attr:`~tofmetry.reconstruct._adjust_result.AdjustResult.pose_covariance`) and the
calibration's residual field moves them (``dx = -H^-1 F c``, :mod:`~tofmetry.reconstruct._adjust_field`).
Moving one view's points moves the model's scale as well, most where halves of the model are tied
by edges only: on a box seen by two half-rings (the family's draw 48, 819151717) the joint fit slid
one half 1.6 mm along the length, noise alone doing as much, and the model came out -1.05 % small
against a predicted +-0.24 % with the poses held. :func:`pose_scale_response` maps each view's
increment to the scale; :class:`PoseUncertainty` carries what moves them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from tofmetry._shared.geometry import SCALE_OFFSET_MAX_CORRELATION, similarity_offset_jacobian


@dataclass(frozen=True)
class PoseUncertainty:
    """What moves the joint fit's poses, for the scale they carry (:func:`scale_budget`).

    Attributes
    ----------
    noise_cov : (6 (V - 1), 6 (V - 1)) covariance of the poses' left increments from the data's
        noise (rotation vector [rad^2], translation [m^2], view 0 fixed), or None
    field_response : (6 (V - 1), T) the same increments per unit coefficient of each term of the
        calibration's residual field [rad, m per coefficient unit], or None
    field_sigma : (T,) standard deviation of each coefficient, or None
    field_basis : camera-frame points (M, 3) [m] -> (M, T) value of each term there, or None
    """

    noise_cov: np.ndarray | None
    field_response: np.ndarray | None = None
    field_sigma: np.ndarray | None = None
    field_basis: Callable[[np.ndarray], np.ndarray] | None = None


def _scale_rows(points_w: np.ndarray, normals_w: np.ndarray,
                weights: np.ndarray | None = None) -> tuple[np.ndarray | None, float]:
    """The fit of :func:`scale_response` as a linear map: ``(rows, correlation)`` with ``rows`` (2, N)
    such that a displacement field ``d`` has scale ``rows[0] @ (n . d)`` and normal offset
    ``rows[1] @ (n . d)`` [m]; ``rows`` is None where the fit is singular or scale and offset are not
    separable (``|correlation| > SCALE_OFFSET_MAX_CORRELATION``).

    ``weights`` (N,): each point's weight in the fit (its centroid, size and normal equations), e.g.
    the surface area it stands for; None: each point counted once (what the scale budget and the
    mat's scale hold do)."""
    p = np.asarray(points_w, np.float64)
    n = np.asarray(normals_w, np.float64)
    if len(p) < 10:
        return None, float("nan")
    if weights is None:
        qc = p - p.mean(0)
        L = float(np.sqrt(np.mean(np.sum(qc ** 2, 1)))) or 1.0
    else:
        w = np.asarray(weights, np.float64)[:, None]
        qc = p - (p * w).sum(0) / w.sum()
        L = float(np.sqrt((w[:, 0] * (qc ** 2).sum(1)).sum() / w.sum())) or 1.0
    J = similarity_offset_jacobian(qc, n, L)
    JW = J if weights is None else J * w
    H = JW.T @ J
    if not np.linalg.cond(H) < 1e12:  # a plane: the scale moves nothing along its normal
        return None, float("nan")
    Hi = np.linalg.inv(H)
    corr = float(Hi[6, 7] / np.sqrt(max(Hi[6, 6] * Hi[7, 7], 1e-300)))
    if not np.isfinite(corr) or abs(corr) > SCALE_OFFSET_MAX_CORRELATION:
        return None, corr
    return (Hi @ JW.T)[6:8], corr


def scale_response(points_w: np.ndarray, normals_w: np.ndarray, moves_w: np.ndarray) -> tuple[float, float, float]:
    """Scale change of a surface under a small displacement field, rigid motion and normal offset removed.

    Parameters
    ----------
    points_w : (N, 3) float [m] surface points (world frame)
    normals_w : (N, 3) float unit normals, all outward (or all inward)
    moves_w : (N, 3) float [m] displacement of each point

    Returns
    -------
    (scale, offset_m, correlation): the fitted relative scale change (+0.001 = 0.1 % larger), the
    offset along the normals [m] and the correlation of the two estimates. ``scale`` is NaN when
    the two are not separable on this shape (``|correlation| > SCALE_OFFSET_MAX_CORRELATION``) or
    the fit is singular.
    """
    rows, corr = _scale_rows(points_w, normals_w)
    if rows is None:
        return float("nan"), float("nan"), corr
    x = rows @ np.einsum("ij,ij->i", np.asarray(normals_w, np.float64), np.asarray(moves_w, np.float64))
    return float(x[0]), float(x[1]), corr


def pose_scale_response(points_w: np.ndarray, normals_w: np.ndarray, view: np.ndarray, n_views: int) -> np.ndarray | None:
    """Scale change of the model per unit move of each view's pose, the points held in their views.

    A left increment of view ``v``'s camera-to-world pose, rotation vector ``w`` [rad] and
    translation ``t`` [m] in the world frame (the global adjustment's unknowns, view 0 fixed), moves
    that view's points by ``w x p + t``; :func:`scale_response` is linear in the moves.

    Parameters
    ----------
    points_w : (N, 3) float [m] surface points (world frame of the increments)
    normals_w : (N, 3) float unit normals, all outward
    view : (N,) int index of the view each point comes from, 0 .. ``n_views`` - 1

    Returns
    -------
    (6 (n_views - 1),) relative scale per rad and per m of each increment, or None where scale and
    offset are not separable on this shape
    """
    a = view_scale_rows(points_w, normals_w, view, n_views)
    return None if a is None else a[1:].ravel()


def view_scale_rows(points_w: np.ndarray, normals_w: np.ndarray, view: np.ndarray, n_views: int) -> np.ndarray | None:
    """:func:`pose_scale_response` for every view, view 0 included: (n_views, 6) relative scale per
    rad of the rotation vector and per m of the translation of each view's left increment (a common
    increment of all views is a rigid motion: the rows sum to a zero scale for it). None where scale
    and offset are not separable on this shape."""
    rows, _ = _scale_rows(points_w, normals_w)
    return None if rows is None else _view_rows(points_w, normals_w, rows[0], view, n_views)


def _view_rows(points_w, normals_w, scale_row: np.ndarray, view, n_views: int) -> np.ndarray:
    """:func:`view_scale_rows` from the scale fit's row (:func:`_scale_rows`)."""
    p, n = np.asarray(points_w, np.float64), np.asarray(normals_w, np.float64)
    a = np.zeros((n_views, 6))
    np.add.at(a, np.asarray(view), np.c_[np.cross(p, n), n] * scale_row[:, None])
    return a


def sampled_points(points_cam: list[np.ndarray], normals_cam: list[np.ndarray], poses: np.ndarray,
                   max_points: int) -> tuple[np.ndarray, ...]:
    """At most ``max_points`` of the views' points drawn (seeded, the same draw every call), in
    their cameras and in the world: ``(take, view, P, N, Pw, Nw)`` with ``take`` (M,) their indices
    into the views' concatenated points, ``view`` (M,) the view of each, ``P``, ``N`` (M, 3) camera
    frame and ``Pw``, ``Nw`` (M, 3) carried by ``poses`` (V, 4, 4) camera to world [m];
    ``points_cam``, ``normals_cam`` as :func:`scale_budget` (at least one point in all)."""
    sizes = [len(p) for p in points_cam]
    total = int(sum(sizes))
    take = np.sort(np.random.default_rng(0).choice(total, min(total, max_points), replace=False))
    view = np.repeat(np.arange(len(sizes)), sizes)[take]
    P = np.concatenate(points_cam)[take]
    N = np.concatenate(normals_cam)[take]
    R, t = poses[view, :3, :3], poses[view, :3, 3]
    return take, view, P, N, np.einsum("nij,nj->ni", R, P) + t, np.einsum("nij,nj->ni", R, N)


def scale_budget(points_cam: list[np.ndarray], normals_cam: list[np.ndarray], poses: np.ndarray, z_ref_m: float,
                 log_ratio: list[np.ndarray] | None, offset_sigma_m: float, gain_sigma: float,
                 k_sigma_m: float | None, max_points: int = 20_000, poses_free: PoseUncertainty | None = None) -> dict:
    """Scale standard deviation of a fused model from the depth errors left by the chain (module docstring).

    Parameters
    ----------
    points_cam : per view (N_v, 3) float [m] object points in the view's camera frame (x right, y
        down, z forward; depth Z = z)
    normals_cam : per view (N_v, 3) unit normals, camera frame, toward the camera (outward)
    poses : (V, 4, 4) camera-to-world poses of the views
    z_ref_m : depth about which the gain acts [m]
    log_ratio : per view (N_v,) ``ln(A_white / A)`` of each point, or None (no amplitude reference:
        the amplitude term is not counted)
    offset_sigma_m : standard deviation of a range offset common to all views [m]
    gain_sigma : standard deviation of the depth gain (dimensionless)
    k_sigma_m : standard deviation of the amplitude-bias coefficient [m per ln unit], or None
    max_points : points drawn (seeded) over all views for the fits
    poses_free : what moves the poses (:class:`PoseUncertainty`), or None: the poses held

    Returns
    -------
    dict: per term (``offset``, ``gain``, ``amplitude``) the response (relative scale per m, per
    unit of gain, per m per ln unit) and its ``sigma`` (relative scale), and ``sigma`` (total, in
    quadrature; NaN when scale and offset are not separable on this shape), ``correlation``,
    ``n_points``; with ``poses_free``, ``poses`` (:func:`_pose_term`) is in the total too and
    ``sigma_poses_held`` is the total without it.
    """
    if sum(len(p) for p in points_cam) == 0:
        return {"sigma": float("nan"), "n_points": 0, "note": "no object points"}
    take, view, P, N, Pw, Nw = sampled_points(points_cam, normals_cam, poses, max_points)
    z = P[:, 2]
    # a depth error delta moves a point along its ray by P delta / z: along the normal by (N . P / z) delta
    along = np.einsum("ij,ij->i", N, P) / z
    rows, corr = _scale_rows(Pw, Nw)  # the scale fit, once for every term (linear in the moves)

    def response(delta: np.ndarray) -> tuple[float, float]:
        return (float("nan") if rows is None else float(rows[0] @ (along * delta))), corr

    out: dict = {"n_points": int(len(P))}
    terms = [("offset", np.ones(len(P)), offset_sigma_m), ("gain", z - z_ref_m, gain_sigma)]
    if log_ratio is not None and k_sigma_m is not None:
        terms.append(("amplitude", np.concatenate(log_ratio)[take], k_sigma_m))
    var = 0.0
    for name, delta, sigma in terms:
        r, _ = response(np.asarray(delta, np.float64))
        sd = abs(r) * float(sigma)
        out[name] = {"response": r, "sigma": sd, "input_sigma": float(sigma)}
        var += sd ** 2
    out["sigma"] = float(np.sqrt(var))
    out["correlation"] = corr
    if poses_free is not None:  # the poses' own uncertainty, independent of the terms above but for
        # the field's direct moves, whose correlation with the moves of the poses it causes is left out
        out["poses"] = _pose_term(None if rows is None else _view_rows(Pw, Nw, rows[0], view, len(poses))[1:].ravel(), P,
                                  poses_free, response)
        if np.isfinite(out["poses"]["sigma"]):
            out["sigma_poses_held"] = out["sigma"]
            out["sigma"] = float(np.hypot(out["sigma"], out["poses"]["sigma"]))
    if log_ratio is None or k_sigma_m is None:
        out["note"] = "amplitude bias not counted (no amplitude reference)"
    return out


def _pose_term(a: np.ndarray | None, P: np.ndarray, free: PoseUncertainty, response) -> dict:
    """The scale the poses carry: their noise (``noise``) and how the calibration's residual field
    moves them (``field``), each a relative standard deviation; ``field_total`` adds the field's
    direct moves of the points along their rays, term by term (the poses free, not held). ``a``:
    :func:`pose_scale_response` (None: not separable); ``P``: the camera-frame points; ``response``:
    a depth-error pattern's scale, poses held."""
    if a is None:
        return {"sigma": float("nan"), "note": "scale and offset not separable on this shape"}
    out: dict = {}
    C = free.noise_cov
    if C is not None and C.shape == (len(a), len(a)) and np.all(np.isfinite(C)):
        out["noise"] = float(np.sqrt(max(a @ C @ a, 0.0)))
    F, sd = free.field_response, free.field_sigma
    if F is not None and sd is not None and F.shape == (len(a), len(sd)):
        moved = a @ F
        out["field"] = float(np.sqrt(np.sum((sd * moved) ** 2)))
        if free.field_basis is not None:
            B = free.field_basis(P)
            direct = np.array([response(B[:, t])[0] for t in range(B.shape[1])])
            out["field_total"] = float(np.sqrt(np.sum((sd * (moved + direct)) ** 2)))
    out["sigma"] = float(np.hypot(out.get("noise", 0.0), out.get("field", 0.0)))
    return out
