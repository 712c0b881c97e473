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
"""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import SCALE_OFFSET_MAX_CORRELATION, similarity_offset_jacobian


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
    p = np.asarray(points_w, np.float64)
    n = np.asarray(normals_w, np.float64)
    d = np.asarray(moves_w, np.float64)
    if len(p) < 10:
        return float("nan"), float("nan"), float("nan")
    qc = p - p.mean(0)
    L = float(np.sqrt(np.mean(np.sum(qc ** 2, 1)))) or 1.0
    J = similarity_offset_jacobian(qc, n, L)
    b = np.einsum("ij,ij->i", n, d)
    H = J.T @ J
    if not np.linalg.cond(H) < 1e12:  # a plane: the scale moves nothing along its normal
        return float("nan"), float("nan"), float("nan")
    Hi = np.linalg.inv(H)
    x = Hi @ (J.T @ b)
    corr = float(Hi[6, 7] / np.sqrt(max(Hi[6, 6] * Hi[7, 7], 1e-300)))
    if not np.isfinite(corr) or abs(corr) > SCALE_OFFSET_MAX_CORRELATION:
        return float("nan"), float("nan"), corr
    return float(x[6]), float(x[7]), corr


def scale_budget(points_cam: list[np.ndarray], normals_cam: list[np.ndarray], poses: np.ndarray, z_ref_m: float,
                 log_ratio: list[np.ndarray] | None, offset_sigma_m: float, gain_sigma: float,
                 k_sigma_m: float | None, max_points: int = 20_000) -> dict:
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

    Returns
    -------
    dict: per term (``offset``, ``gain``, ``amplitude``) the response (relative scale per m, per
    unit of gain, per m per ln unit) and its ``sigma`` (relative scale), and ``sigma`` (total, in
    quadrature; NaN when scale and offset are not separable on this shape), ``correlation``,
    ``n_points``.
    """
    sizes = [len(p) for p in points_cam]
    total = int(sum(sizes))
    if total == 0:
        return {"sigma": float("nan"), "n_points": 0, "note": "no object points"}
    rng = np.random.default_rng(0)
    take = np.sort(rng.choice(total, min(total, max_points), replace=False))
    view = np.repeat(np.arange(len(sizes)), sizes)[take]
    P = np.concatenate(points_cam)[take]
    N = np.concatenate(normals_cam)[take]
    R, t = poses[view, :3, :3], poses[view, :3, 3]
    Pw = np.einsum("nij,nj->ni", R, P) + t
    Nw = np.einsum("nij,nj->ni", R, N)
    z = P[:, 2]
    ray = P / z[:, None]  # move per metre of depth along the ray (camera frame)

    def response(delta: np.ndarray) -> tuple[float, float]:
        s, _, c = scale_response(Pw, Nw, np.einsum("nij,nj->ni", R, ray * delta[:, None]))
        return s, c

    out: dict = {"n_points": int(len(P))}
    terms = [("offset", np.ones(len(P)), offset_sigma_m), ("gain", z - z_ref_m, gain_sigma)]
    if log_ratio is not None and k_sigma_m is not None:
        terms.append(("amplitude", np.concatenate(log_ratio)[take], k_sigma_m))
    var, corr = 0.0, float("nan")
    for name, delta, sigma in terms:
        r, corr = response(np.asarray(delta, np.float64))
        sd = abs(r) * float(sigma)
        out[name] = {"response": r, "sigma": sd, "input_sigma": float(sigma)}
        var += sd ** 2
    out["sigma"] = float(np.sqrt(var))
    out["correlation"] = corr
    if log_ratio is None or k_sigma_m is None:
        out["note"] = "amplitude bias not counted (no amplitude reference)"
    return out
