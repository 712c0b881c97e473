"""Point clouds projected on their local planes: the depth noise taken out of a surface.

Why: the global adjustment pairs each point with the nearest point of another view's cloud, and
with noise on both clouds its optimum leaves the truth. Started at the true poses with the sensor's
noise as the only error (``bench/robustness/drift.py``), a plaque's views ended 3.1 mm / 0.52 deg
from the truth and a box's 1.5 mm / 0.06 deg; with the *target* clouds projected on their local
planes (12 neighbours), 1.1 mm / 0.20 deg and 1.0 mm / 0.05 deg. Projecting the query points too
helped the box no more (0.8 mm) and made the plaque worse (4.3 mm).

What it costs: a plane through the neighbours of a point on a convex surface lies inside it by
about half the patch's sagitta, so the projection shrinks a convex surface by ``~k s^2 / (4 pi R)``
(``s``: sampling spacing, ``R``: radius of curvature; 0.2 mm for k = 12, s = 3.5 mm, R = 50 mm;
:func:`project_to_local_planes`). A quadric fit instead of a plane has no such shrink, but on
the family's plaques it removed less of the bias (from their true poses with every sensor error:
0.19 and 0.55 deg with quadrics of 20 neighbours, 0.17 and 0.21 deg with planes, 0.39 and 0.72 deg
with the raw clouds), so the plane stays; the shrink is part of what it changes.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tofmetry.errors import InputError


def project_to_local_planes(points: np.ndarray, k: int = 12, normals: np.ndarray | None = None,
                            max_normal_deg: float | None = None) -> np.ndarray:
    """Each point moved along its local normal onto the plane fitted to its ``k`` nearest neighbours.

    The plane is the least-squares one through the neighbours (their centroid and the smallest
    principal direction); the point moves only along that normal, so the sampling of the surface
    along it is kept. Noise along the normal drops by about ``sqrt(k)`` where the sampling is
    denser than the noise; a convex surface of radius ``R`` sampled at spacing ``s`` moves inward
    by about ``k s^2 / (4 pi R)`` (half the sagitta of the neighbourhood).

    Parameters
    ----------
    points : (N, 3) float [m], any frame
    k : neighbours per plane (>= 3; the point itself included)
    normals, max_normal_deg : (N, 3) unit normals of ``points`` and an angle [deg]: only the neighbours
        whose normal lies within this angle of the point's own enter its plane (the point always
        does), so that a point near an edge is projected on its own face and not on a plane that
        cuts the edge; a point left with fewer than 3 such neighbours is kept as it is

    Returns
    -------
    (N, 3) float64 [m], a new array; the input itself is returned unchanged when N <= k.
    """
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"project_to_local_planes: points must be (N, 3), found {p.shape}")
    if int(k) < 3:
        raise InputError(f"project_to_local_planes: k must be >= 3 (a plane needs 3 points), found {k}")
    if len(p) <= k:
        return p
    _, idx = cKDTree(p).query(p, int(k), workers=-1)
    nb = p[idx]
    few = None
    if normals is None or max_normal_deg is None:
        m = nb.mean(1)
        q = nb - m[:, None]
    else:
        nr = np.asarray(normals, np.float64)
        if nr.shape != p.shape:
            raise InputError(f"project_to_local_planes: normals must be (N, 3) like the points {p.shape}, "
                             f"found {nr.shape}")
        w = (np.einsum("nkj,nj->nk", nr[idx], nr) >= np.cos(np.radians(max_normal_deg))).astype(np.float64)
        w[:, 0] = 1.0  # the point itself
        cnt = w.sum(1)
        m = np.einsum("nk,nki->ni", w, nb) / cnt[:, None]
        q = (nb - m[:, None]) * np.sqrt(w)[:, :, None]
        few = cnt < 3
    _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", q, q))
    n = vec[:, :, 0]  # smallest principal direction: the local normal
    out = p - n * np.einsum("ij,ij->i", p - m, n)[:, None]
    if few is not None:
        out[few] = p[few]
    return out
