"""The IR albedo as a term of the joint fit, where the geometry leaves a rotation free.

Why: on a surface of revolution (a vase, a dome, a bottle) the points do not determine the
rotation about its axis. The pairwise registrations of such a scan take that rotation from a
painted or printed pattern in the IR amplitude (:mod:`tofmetry.reconstruct._photometric`), but the
joint fit (:func:`tofmetry.reconstruct._adjust.global_adjust`) saw only the geometry: it moved every
view along the free direction by whatever the noise and the calibration residual asked, and a
restart of it ended elsewhere (measured on held-out family draws 18-21: 4 of the 5 painted vases
moved 0.67-1.47 deg from the pose graph and ended 0.79-1.40 deg off; the fifth flipped, 75 deg).
With the term, those four ended 0.46-0.86 deg off (``bench/results/object_family_dev_albedo_rows.jsonl``).

The term: each correspondence of the joint fit (source point ``p`` of view ``i``, its nearest
target point ``q`` of view ``j``) compares the relative log albedo of both
(:func:`~tofmetry.reconstruct._photometric.log_albedo`), the target's linearised on its tangent
plane: ``r = a_p - a_q - grad_q . (p - q)`` (Park, Zhou & Koltun 2017, the colored point-cloud
registration, here over all views at once). ``grad_q`` is the albedo gradient of the target cloud
in its tangent plane, fitted once per view to its nearest neighbours (:func:`albedo_gradients`).
Only where the pattern changes (the edges of the paint) does ``r`` respond to a pose.

Which directions: the albedo of a real object seen by a ToF camera is estimated with smooth,
view-dependent errors (the incidence and range model of :func:`log_albedo`, the amplitude bias of
dark paint), and over all six degrees of freedom they pull poses where the geometry needs no help
(measured on a held-out fandisk and igea, painted: the model's scale error went from 0.8 and -0.7 %
to 1.9 and 2.4 %). So the term acts only on the direction the geometry leaves free: each view's
rotation about the vertical (the support plane's normal) through the object's centre.

Or, more generally (``albedo_weak_ratio`` of the joint fit, :func:`weak_bases`): along the directions of
each view's pose where the albedo tells more than the geometry. The view's block of the geometric normal
matrix, rotations taken about the object's centre and scaled to its radius, gives its eigen-directions;
the albedo acts along those where its own information is at least ``ratio`` times the geometry's. On a
vase that is the turn about the vase's own axis (not the vertical through the points' centre); on a bar,
its slide or roll where the pattern sees it; on a feature-rich object, nothing.

Weighting: the albedo residuals enter at their own robust scale (``1.4826 MAD``) beside the
geometric residuals at theirs (both as unit-variance residuals, Huber at 1.345 scales), so that
neither is tuned: where the pattern is faint or absent its scale is large against its response and
the term carries nothing. A constant difference between two views' albedo (their medians are
removed per view, but the overlap of two views need not share it) is a nuisance, removed per pair
of views before the residuals are formed. The term acts on the poses only; the depth-error terms
(gain, range curve, amplitude bias, tilt) move points along their rays, which changes the albedo
residual only through the gradient along the ray, and the gradient lies in the tangent plane.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tofmetry._shared.geometry import skew

#: neighbours of a target point its albedo gradient is fitted to
GRADIENT_NEIGHBOURS = 12


def albedo_gradients(points: np.ndarray, normals: np.ndarray, values: np.ndarray,
                     k: int = GRADIENT_NEIGHBOURS) -> np.ndarray:
    """Gradient of a value over a surface, in each point's tangent plane (least squares on neighbours).

    Parameters
    ----------
    points : (K, 3) [m], one view's cloud (any frame)
    normals : (K, 3) unit normals in the same frame
    values : (K,) the value at each point (e.g. relative log albedo, dimensionless)
    k : neighbours per point (itself included)

    Returns
    -------
    (K, 3) gradient [value per m], orthogonal to each normal; 0 where the fit is degenerate
    """
    p = np.asarray(points, np.float64)
    n = np.asarray(normals, np.float64)
    v = np.asarray(values, np.float64)
    if len(p) < 3:
        return np.zeros_like(p)
    k = min(k, len(p))
    _, idx = cKDTree(p).query(p, k=k, workers=-1)
    d = p[idx] - p[:, None, :]  # (K, k, 3)
    d -= np.einsum("kmd,kd->km", d, n)[:, :, None] * n[:, None, :]  # onto the tangent plane
    dv = v[idx] - v[:, None]
    A = np.einsum("kmd,kme->kde", d, d)
    scale = np.einsum("kdd->k", A) / 3.0
    # damped: the normal direction has no data (A is rank 2 on a surface); the damping keeps the
    # solution in the tangent plane and is far below the tangent eigenvalues
    A = A + (1e-6 * scale + 1e-18)[:, None, None] * np.eye(3)
    g = np.linalg.solve(A, np.einsum("kmd,km->kd", d, dv)[..., None])[..., 0]
    g -= np.einsum("kd,kd->k", g, n)[:, None] * n
    g[~np.isfinite(g).all(1)] = 0.0
    return g


def weak_bases(H: np.ndarray, V: int, centre: np.ndarray, radius_m: float, ratio: float,
               H_albedo: np.ndarray) -> list:
    """Per view, the directions of its pose where the albedo tells more than the geometry.

    Parameters
    ----------
    H : (n, n) the geometric normal matrix of the joint fit (poses first, 6 per view 1..V-1, left
        increments: rotation w [rad], translation t [m], world frame)
    V : number of views
    centre : (3,) the object's centre [m] (world frame): rotations are taken about it
    radius_m : the object's radius [m]: a rotation counts by the displacement it gives there
    ratio : a direction (eigenvector of the view's geometric block, rotation about ``centre`` scaled
        to ``radius_m``) is weak when the albedo's information along it is at least this many times
        the geometry's
    H_albedo : (n, n) the albedo term's normal matrix on all six degrees of freedom, at the same scale

    Returns
    -------
    list of V: None for view 0 (fixed) and where no direction is weak, else ``(G, Q)``: (6, k) maps
    of the weak coordinates ``a`` to the increment (``xi = G a``) and of the increment to them
    (``a = Q^T xi``)
    """
    cx = skew(np.asarray(centre, np.float64))
    MS = np.block([[np.eye(3) / radius_m, np.zeros((3, 3))], [cx / radius_m, np.eye(3)]])
    MS_inv_T = np.linalg.inv(MS).T
    out: list = [None]
    for v in range(1, V):
        blk = slice(6 * (v - 1), 6 * v)
        lam, E = np.linalg.eigh(MS.T @ H[blk, blk] @ MS)
        alb = np.einsum("dk,de,ek->k", E, MS.T @ H_albedo[blk, blk] @ MS, E)
        weak = alb >= ratio * np.maximum(lam, 0.0)
        out.append((MS @ E[:, weak], MS_inv_T @ E[:, weak]) if weak.any() else None)
    return out


def albedo_terms(P: np.ndarray, sources: list, targets: list, corr, npar: int,
                 geometric_variance: float, axis: tuple[np.ndarray, np.ndarray] | None = None,
                 weak: tuple | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """Gauss-Newton terms of the albedo residuals (module docstring) for the joint fit's correspondences.

    Parameters
    ----------
    P : (V, 4, 4) current camera-to-world poses (view 0 fixed: not an unknown)
    sources : per view, None or ``(points (M, 3) [m], albedo (M,))`` of its source cloud (camera frame)
    targets : per view, None or ``(points (K, 3) [m], albedo (K,), gradient (K, 3) [per m])`` (camera frame)
    corr : the joint fit's correspondences ``(i, j, source indices, target indices)``
    npar : number of unknowns of the joint fit (poses first, ``6 (V - 1)``)
    geometric_variance : the geometric residuals' variance [m^2] the data term's normal equations
        carry: the albedo terms are scaled to it (unit-variance residuals both)
    axis : ``(up (3,), centre (3,))`` world frame: the albedo then acts on each view's rotation
        about the vertical through the object's centre only (module docstring); None: on all six
        degrees of freedom (or along ``weak``'s directions)
    weak : ``(H (npar, npar) geometric normal matrix, centre (3,) [m], radius [m], ratio)``: the albedo
        acts on each view only along the directions :func:`weak_bases` finds from those and from its own
        normal matrix on all six degrees of freedom; None: not used

    Returns
    -------
    H : (npar, npar) addition to the normal matrix; b : (npar,) addition to the gradient
    info : dict: ``n`` (residuals), ``scale`` (their robust standard deviation, log albedo units),
    ``n_pairs``; with ``weak``, ``weak_directions`` (how many per view)
    """
    H = np.zeros((npar, npar))
    b = np.zeros(npar)
    blocks = []
    for i, j, si, qi in corr:
        if sources[i] is None or targets[j] is None:
            continue
        sp, sa = sources[i]
        tp, ta, tg = targets[j]
        Ri, ti, Rj, tj = P[i][:3, :3], P[i][:3, 3], P[j][:3, :3], P[j][:3, 3]
        p = sp[si] @ Ri.T + ti
        q = tp[qi] @ Rj.T + tj
        g = tg[qi] @ Rj.T
        e = sa[si] - ta[qi] - np.einsum("md,md->m", g, p - q)
        e = e - np.median(e)  # the pair's albedo offset (module docstring)
        blocks.append((i, j, p, q, g, e))
    if not blocks:
        return H, b, {"n": 0, "scale": float("nan"), "n_pairs": 0}
    all_e = np.concatenate([x[5] for x in blocks])
    scale = 1.4826 * float(np.median(np.abs(all_e)))
    if not scale > 0:
        return H, b, {"n": int(len(all_e)), "scale": scale, "n_pairs": len(blocks)}
    lam = geometric_variance / scale ** 2
    u = None
    if axis is not None:  # a left increment turning about the vertical through the centre: w = up, t = -up x c
        up = np.asarray(axis[0], np.float64) / np.linalg.norm(axis[0])
        u = np.r_[up, -np.cross(up, np.asarray(axis[1], np.float64))]
    huber = 1.345 * scale
    rows = []
    for i, j, p, q, g, e in blocks:
        w = np.where(np.abs(e) <= huber, 1.0, huber / np.maximum(np.abs(e), 1e-15))
        # left increments (rotation w, translation t) of both views, as the geometric term
        J = np.empty((len(e), 12))
        J[:, 0:3] = -np.cross(p, g)
        J[:, 3:6] = -g
        J[:, 6:9] = np.cross(q, g) - np.cross(g, p - q)
        J[:, 9:12] = g
        cols = np.r_[np.arange(6 * (i - 1), 6 * i) if i > 0 else np.full(6, -1),
                     np.arange(6 * (j - 1), 6 * j) if j > 0 else np.full(6, -1)]
        rows.append((i, j, J, w, e, cols))

    def normal(project=None) -> tuple[np.ndarray, np.ndarray]:
        """The rows' normal equations, each row's Jacobian mapped by ``project(i, j, J)`` first."""
        H = np.zeros((npar, npar))
        b = np.zeros(npar)
        for i, j, J, w, e, cols in rows:
            if project is not None:
                J = project(i, j, J)
            keep = cols >= 0
            c = cols[keep]
            Jw = J * w[:, None]
            H[np.ix_(c, c)] += lam * (Jw.T @ J)[np.ix_(keep, keep)]
            b[c] += lam * (Jw.T @ e)[keep]
        return H, b

    info = {"n": int(len(all_e)), "scale": round(scale, 4), "n_pairs": len(blocks)}
    if u is not None:
        H, b = normal(lambda i, j, J: np.hstack([(J[:, 0:6] @ u)[:, None] * u, (J[:, 6:12] @ u)[:, None] * u]))
    elif weak is not None:  # only along each view's weak directions
        bases = weak_bases(weak[0], len(P), weak[1], weak[2], weak[3], normal()[0])
        H, b = normal(lambda i, j, J: np.hstack([np.zeros((len(J), 6)) if bases[v] is None else
                                                 J[:, s:s + 6] @ bases[v][0] @ bases[v][1].T
                                                 for v, s in ((i, 0), (j, 6))]))
        info["weak_directions"] = [0 if B is None else B[0].shape[1] for B in bases]
    else:
        H, b = normal()
    return H, b, info
