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


def move_onto_points(vertices: np.ndarray, normals: np.ndarray, points: np.ndarray, radius: float, band: float,
                     min_points: int = 5, max_points: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Each surface vertex moved along its normal onto the points that lie about it.

    The points within ``radius`` of the vertex's normal line and ``band`` of the vertex along it (a
    cylinder) are the surface's own samples there; the vertex moves by their median signed offset
    along its normal. A fused surface whose zero level sits where the samples do not (a TSDF's
    truncation band reaching past a rim, :mod:`tofmetry.reconstruct._model_build`) is put back
    on them; the median keeps a second surface that enters the band, or an outlier, from pulling
    it. On a convex edge the cylinder takes samples of the faces below the edge as well, so the
    edge moves inward by about ``radius^2 / (4 R)`` where its radius of curvature ``R`` is small:
    ``radius`` should be a sample spacing or two.

    Parameters
    ----------
    vertices : (V, 3) float [m]; normals : (V, 3) unit normals of the vertices
    points : (N, 3) float [m], the same frame
    radius, band : the cylinder's radius and half length [m] (> 0)
    min_points : fewer samples in the cylinder: the vertex stays
    max_points : the nearest this many points are searched (a denser cloud: the median of the nearest)

    Returns
    -------
    (V, 3) float64 the moved vertices (a new array); (V,) float64 each vertex's move along its
    normal [m], NaN where it stayed
    """
    v = np.asarray(vertices, np.float64)
    nr = np.asarray(normals, np.float64)
    p = np.asarray(points, np.float64)
    for name, a in (("vertices", v), ("normals", nr), ("points", p)):
        if a.ndim != 2 or a.shape[1] != 3:
            raise InputError(f"move_onto_points: {name} must be (N, 3), found {a.shape}")
    if nr.shape != v.shape:
        raise InputError(f"move_onto_points: normals must be (V, 3) like the vertices {v.shape}, found {nr.shape}")
    if not (radius > 0 and band > 0):
        raise InputError(f"move_onto_points: radius and band must be > 0 [m], found {radius} and {band}")
    if len(v) == 0 or len(p) == 0:
        return v.copy(), np.full(len(v), np.nan)
    dist, idx = cKDTree(p).query(v, int(max_points), distance_upper_bound=float(np.hypot(radius, band)), workers=-1)
    found = np.isfinite(dist)
    d = p[np.where(found, idx, 0)] - v[:, None, :]
    along = np.einsum("vkj,vj->vk", d, nr)
    inside = found & (np.einsum("vkj,vkj->vk", d, d) - along ** 2 < radius ** 2) & (np.abs(along) < band)
    cnt = inside.sum(1)
    srt = np.sort(np.where(inside, along, np.inf), axis=1)  # the samples first, in order
    rows = np.arange(len(v))
    med = 0.5 * (srt[rows, np.maximum(cnt - 1, 0) // 2] + srt[rows, cnt // 2])
    move = np.where(cnt >= int(min_points), med, np.nan)
    return v + np.nan_to_num(move)[:, None] * nr, move
