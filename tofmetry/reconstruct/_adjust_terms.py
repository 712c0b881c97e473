"""The joint fit's residuals and their normal equations (:func:`tofmetry.reconstruct._adjust.global_adjust`):
the views' clouds (:class:`AdjustView`) moved by the poses and the depth-error terms, nearest-point
correspondences between them, and the Gauss-Newton normal equations of the point-to-plane residuals
(along the target's normal, or along both points' normals), with the response to a depth-error field
when one is asked for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tofmetry._shared.geometry import skew, transform_points
from tofmetry.reconstruct._range_curve import range_basis

@dataclass
class AdjustView:
    """Clouds of one view for the adjustment (camera frame, metres).

    Attributes
    ----------
    source : (M, 3) points matched against the other views (e.g. the 5 mm voxel cloud)
    source_normals : (M, 3) their unit normals (correspondences must agree in orientation)
    target : (K, 3) the view's surface the others are matched to (e.g. the 2.5 mm voxel cloud)
    target_normals : (K, 3) unit normals of ``target``
    source_amp, target_amp : (M,), (K,) ``ln(A_white / A)`` of each point (the amplitude-bias
        regressor, dimensionless; 0 where unknown), or None: no amplitude-bias estimation
    source_ir, target_ir : (M,), (K,) relative log IR albedo of each point
        (:func:`~tofmetry.reconstruct._photometric.log_albedo`), or None: no albedo term
        (:mod:`tofmetry.reconstruct._adjust_albedo`)
    target_ir_gradient : (K, 3) the albedo's gradient on ``target``'s tangent planes [per m]
        (:func:`~tofmetry.reconstruct._adjust_albedo.albedo_gradients`), or None: computed by the
        joint fit (pass it to share it between several fits of the same views)
    """

    source: np.ndarray
    source_normals: np.ndarray
    target: np.ndarray
    target_normals: np.ndarray
    source_amp: np.ndarray | None = None
    target_amp: np.ndarray | None = None
    source_ir: np.ndarray | None = None
    target_ir: np.ndarray | None = None
    target_ir_gradient: np.ndarray | None = None


def apply_depth_gain(points: np.ndarray, gain: float, z_ref_m: float) -> np.ndarray:
    """Move camera-frame points along their rays: ``Z -> Z + gain (Z - z_ref)``.

    Parameters
    ----------
    points : (N, 3) [m], camera frame (Z > 0)
    gain : dimensionless; z_ref_m : [m]

    Returns
    -------
    (N, 3) [m]
    """
    z = points[:, 2:3]
    return points * (1.0 + gain * (z - z_ref_m) / z)


def image_tilt_m(xy: np.ndarray, ab: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Depth change of the image tilt ``a (x - x0) + b (y - y0)`` [m].

    Parameters
    ----------
    xy : (..., 2) normalised image coordinates (``X / Z``, ``Y / Z``, or a ray table)
    ab : (2,) [m per unit]; centre : (2,) ``(x0, y0)``, where the tilt is zero

    Returns
    -------
    (...) [m], to add to Z
    """
    return (np.asarray(xy) - centre) @ ab


def _exp_se3(xi: np.ndarray) -> np.ndarray:
    """4x4 from a 6-vector (rotation vector, translation) - left update."""
    w, t = xi[:3], xi[3:]
    th = np.linalg.norm(w)
    K = skew(w)
    if th < 1e-12:
        R = np.eye(3) + K
    else:
        R = np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th ** 2 * K @ K
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _world(views: list[AdjustView], P: np.ndarray, g: float, z_ref_m: float, which: str, curve=None,
           amp: float | None = None, tilt: tuple | None = None):
    """World points, normals, d(point)/d(gain) and d(point)/d(depth-error coefficients) ((M, 3, E):
    the range curve's, then the amplitude bias's, then the image tilt's) of every view's ``source``
    or ``target`` cloud; ``curve`` = (coefficients [m], half span [m]) or None; ``amp`` = ``dk`` [m]
    or None (off); ``tilt`` = ((a, b) [m per unit of ``x / z``, ``y / z``], (x0, y0) its zero in
    the image) or None (off)."""
    pts, nrm, dg, dc = [], [], [], []
    for v, T in zip(views, P):
        R, t = T[:3, :3], T[:3, 3]
        c, n = (v.source, v.source_normals) if which == "source" else (v.target, v.target_normals)
        z = c[:, 2:3]
        p = apply_depth_gain(c, g, z_ref_m)
        cols = []  # Z displacement per unit of each coefficient [m / m]
        if curve is not None and len(curve[0]):
            B = range_basis(c[:, 2], z_ref_m, curve[1], len(curve[0]) + 1)  # (M, D)
            p = p + c * (B @ curve[0])[:, None] / z
            cols.append(B)
        if amp is not None:
            L = v.source_amp if which == "source" else v.target_amp
            p = p - c * (amp * L)[:, None] / z
            cols.append(-L[:, None])
        if tilt is not None:  # Z -> Z + a (x - x0) + b (y - y0) (x = X / Z, y = Y / Z: the position in the image)
            p = p + c * image_tilt_m(c[:, :2] / z, *tilt)[:, None] / z
            cols.append(c[:, :2] / z - tilt[1])
        B = np.hstack(cols) if cols else np.zeros((len(c), 0))
        dc.append(np.einsum("mk,md->mkd", (c / z) @ R.T, B))
        pts.append(p @ R.T + t)
        nrm.append(n @ R.T)
        dg.append((c * ((z - z_ref_m) / z)) @ R.T)
    return pts, nrm, dg, dc


def world_sources(views: list[AdjustView], poses: np.ndarray) -> np.ndarray:
    """(M, 3) every view's ``source`` points [m] placed by ``poses`` (V, 4, 4), all views together."""
    return np.concatenate([transform_points(v.source, T) for v, T in zip(views, poses)])


def _correspondences(views, P, g, z_ref_m, r, cos_max, pairs=None, curve=None,
                     amp=None, tilt=None) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """(i, j, source indices of view i, target indices of view j): nearest target point within ``r``
    with normals agreeing within ``arccos(cos_max)``; only ``pairs`` when given."""
    src, srcn, _, _ = _world(views, P, g, z_ref_m, "source", curve, amp, tilt)
    tgt, tgtn, _, _ = _world(views, P, g, z_ref_m, "target", curve, amp, tilt)
    trees = [cKDTree(t) for t in tgt]
    out = []
    V = len(views)
    for i in range(V):
        for j in range(V):
            if i == j or (pairs is not None and (i, j) not in pairs):
                continue
            d, idx = trees[j].query(src[i], distance_upper_bound=r, workers=-1)
            ok = np.flatnonzero(np.isfinite(d))
            if len(ok) == 0:
                continue
            qi = idx[ok]
            agree = np.einsum("ij,ij->i", tgtn[j][qi], srcn[i][ok]) >= cos_max
            if agree.sum() >= 10:
                out.append((i, j, ok[agree], qi[agree]))
    return out


def _normal_equations(views, P, g, z_ref_m, corr, huber_m, estimate_gain, curve=None, amp=None, tilt=None,
                      field=None, symmetric: bool = True):
    """Gauss-Newton normal equations of all correspondences (view 0 fixed; unknowns: poses, then
    the ``D`` range-curve coefficients when ``curve`` is given, then ``dk`` when ``amp`` is given,
    then the image tilt's two when ``tilt`` is given, last the gain).

    Residual: ``n . (p - q)`` with ``n`` the target's normal, or with ``symmetric`` the normalised
    sum of both points' normals (held fixed in the linearisation). ``field``: a callable mapping camera-frame points (M, 3) to (M, T) depth
    displacements [m per unit coefficient] (:class:`~tofmetry.reconstruct._adjust_field.DepthFieldPrior`
    ``.basis``); then ``J^T W B`` (P, T), the gradient's response to each term, is returned last."""
    V = len(views)
    D = (0 if curve is None else len(curve[0])) + (amp is not None) + (0 if tilt is None else 2)
    npar = 6 * (V - 1) + D + 1
    src, srcn, dsrc, csrc = _world(views, P, g, z_ref_m, "source", curve, amp, tilt)
    tgt, tgtn, dtgt, ctgt = _world(views, P, g, z_ref_m, "target", curve, amp, tilt)
    H = np.zeros((npar, npar))
    b = np.zeros(npar)
    sw = swr2 = 0.0
    counts = np.zeros((V, V), np.int64)
    pair_rms = np.full((V, V), np.nan)
    F = None
    for i, j, si, qi in corr:
        p, q = src[i][si], tgt[j][qi]
        # the target's normal (its cloud projected on its local planes: the smoother of the two), or
        # the symmetric form (Rusinkiewicz 2019), whose source normals come from the raw, sparser
        # cloud: see global_adjust's symmetric_normals
        n = tgtn[j][qi] + srcn[i][si] if symmetric else tgtn[j][qi]
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        e = np.einsum("ij,ij->i", n, p - q)
        counts[i, j] = len(e)
        pair_rms[i, j] = float(np.sqrt(np.mean(e ** 2))) * 1e3
        w = np.where(np.abs(e) <= huber_m, 1.0, huber_m / np.maximum(np.abs(e), 1e-15))
        # local Jacobian columns: [rot_i (3), trans_i (3), rot_j (3), trans_j (3), gain]
        J = np.empty((len(e), 13 + D))
        J[:, 0:3] = np.cross(p, n)
        J[:, 3:6] = n
        J[:, 6:9] = -np.cross(q, n)
        J[:, 9:12] = -n
        J[:, 12] = np.einsum("ij,ij->i", n, dsrc[i][si] - dtgt[j][qi]) if estimate_gain else 0.0
        if D:
            J[:, 13:] = np.einsum("mk,mkd->md", n, csrc[i][si] - ctgt[j][qi])
        Jw = J * w[:, None]
        cols = np.r_[np.arange(6 * (i - 1), 6 * i) if i > 0 else np.full(6, -1),
                     np.arange(6 * (j - 1), 6 * j) if j > 0 else np.full(6, -1), npar - 1,
                     np.arange(6 * (V - 1), 6 * (V - 1) + D)]
        keep = cols >= 0
        c = cols[keep]
        H[np.ix_(c, c)] += (Jw.T @ J)[np.ix_(keep, keep)]
        b[c] += (Jw.T @ e)[keep]
        sw += w.sum()
        swr2 += (w * e ** 2).sum()
        if field is not None:  # residual change per unit term: both points move along their rays
            cs, ct = views[i].source[si], views[j].target[qi]
            ray_s = np.einsum("ij,ij->i", n, (cs / cs[:, 2:3]) @ P[i][:3, :3].T)
            ray_t = np.einsum("ij,ij->i", n, (ct / ct[:, 2:3]) @ P[j][:3, :3].T)
            Eb = ray_s[:, None] * field(cs) - ray_t[:, None] * field(ct)
            F = np.zeros((npar, Eb.shape[1])) if F is None else F
            F[c] += (Jw.T @ Eb)[keep]
    if field is not None:
        return H, b, swr2 / max(sw, 1e-12), counts, pair_rms, sw, F
    return H, b, swr2 / max(sw, 1e-12), counts, pair_rms, sw


def _correlation_with_gain(H: np.ndarray, index: int) -> tuple[float, float]:
    """Correlation of unknown ``index`` with the gain (last) from the data-only normal matrix, and
    the gain's regression on it, ``C[g, i] / C[i, i]``: how far the gain estimate moves per unit
    of error in that unknown when it is held at a wrong value."""
    try:
        C = np.linalg.inv(H + np.eye(len(H)) * 1e-12 * np.trace(H) / len(H))
    except np.linalg.LinAlgError:
        return float("nan"), float("nan")
    return (float(C[index, -1] / np.sqrt(max(C[index, index] * C[-1, -1], 1e-300))),
            float(C[index, -1] / max(C[index, index], 1e-300)))
