"""Distances between a model (cloud or mesh) and a reference (mesh or cloud).

All inputs and outputs in metres. Signed cloud-to-mesh distances use Open3D's
``RaycastingScene.compute_closest_points`` and the sign of ``(p - closest) . face_normal``
(outside = positive), which, unlike ``compute_signed_distance``, does not require a
watertight reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tofmetry.errors import InputError


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit face normals (M, 3) and face areas (M,) [m^2] (right-handed winding)."""
    v = vertices[faces]
    cr = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area2 = np.linalg.norm(cr, axis=1)
    n = cr / np.maximum(area2, 1e-30)[:, None]
    return n, 0.5 * area2


def sample_mesh(vertices: np.ndarray, faces: np.ndarray, spacing_m: float, seed: int = 0,
                max_points: int = 400_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area-uniform random samples on a triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) float [m]; faces : (M, 3) int
    spacing_m : float, mean spacing of the samples (count = area / spacing^2)

    Returns
    -------
    points (K, 3) [m], normals (K, 3) unit face normals, face_index (K,) int64
    """
    n, area = face_normals(vertices, faces)
    total = float(area.sum())
    if total <= 0:
        raise InputError("mesh has zero surface area")
    k = int(np.clip(total / spacing_m**2, 1000, max_points))
    rng = np.random.default_rng(seed)
    fi = rng.choice(len(faces), size=k, p=area / total)
    r1 = np.sqrt(rng.random(k))
    r2 = rng.random(k)
    v = vertices[faces[fi]]
    pts = (1 - r1)[:, None] * v[:, 0] + (r1 * (1 - r2))[:, None] * v[:, 1] + (r1 * r2)[:, None] * v[:, 2]
    return pts, n[fi], fi


@dataclass
class ClosestPoints:
    """Closest reference points of query points.

    Attributes
    ----------
    distance : (N,) float64 [m] signed (positive outside / on the normal side)
    closest : (N, 3) float64 [m] closest points on the reference
    normal : (N, 3) float64 reference normal at the closest point
    """

    distance: np.ndarray
    closest: np.ndarray
    normal: np.ndarray


def distances_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> ClosestPoints:
    """Signed point-to-mesh distances.

    Parameters
    ----------
    points : (N, 3) float [m] query points
    vertices : (V, 3) float [m]; faces : (M, 3) int — the reference mesh

    Returns
    -------
    ClosestPoints
    """
    import open3d as o3d

    pts = np.asarray(points, dtype=np.float64)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
    # sorting by a coarse spatial key keeps the BVH traversal coherent (library pitfalls note)
    key = np.floor(pts / 0.02).astype(np.int64)
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
    q = o3d.core.Tensor(np.ascontiguousarray(pts[order], np.float32))
    ans = scene.compute_closest_points(q)
    fid = ans["primitive_ids"].numpy().astype(np.int64)
    closest = np.empty_like(pts)
    closest[order] = ans["points"].numpy().astype(np.float64)
    fn, _ = face_normals(np.asarray(vertices, np.float64), np.asarray(faces))
    normal = np.empty_like(pts)
    normal[order] = fn[fid]
    diff = pts - closest
    dist = np.linalg.norm(diff, axis=1)
    sign = np.where(np.einsum("ij,ij->i", diff, normal) >= 0, 1.0, -1.0)
    return ClosestPoints(distance=sign * dist, closest=closest, normal=normal)


def distances_to_cloud(points: np.ndarray, ref_points: np.ndarray, ref_normals: np.ndarray | None = None) -> ClosestPoints:
    """Cloud-to-cloud distances: nearest neighbour, signed (point-to-plane) when normals exist.

    With normals the distance is the point-to-plane distance to the nearest reference
    point (less sensitive to the reference density); without, the plain Euclidean
    nearest-neighbour distance (unsigned, >= 0).
    """
    tree = cKDTree(ref_points)
    d, i = tree.query(points, workers=-1)
    closest = ref_points[i]
    if ref_normals is None:
        return ClosestPoints(distance=d, closest=closest, normal=np.zeros_like(closest))
    nrm = ref_normals[i]
    sd = np.einsum("ij,ij->i", points - closest, nrm)
    return ClosestPoints(distance=sd, closest=closest, normal=nrm)


def sharp_edge_samples(vertices: np.ndarray, faces: np.ndarray, angle_deg: float = 45.0,
                       spacing_m: float = 0.0005) -> np.ndarray:
    """Points sampled along the sharp and boundary edges of a mesh.

    An edge is *sharp* when the dihedral angle between its two faces' normals exceeds
    ``angle_deg``, and a *boundary* edge when it has only one face.

    Returns
    -------
    (K, 3) float64 [m] (possibly empty)
    """
    fn, _ = face_normals(vertices, faces)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    fidx = np.tile(np.arange(len(faces)), 3)
    es = np.sort(e, axis=1)
    key = es[:, 0] * (len(vertices) + 1) + es[:, 1]
    order = np.argsort(key, kind="stable")
    key_s = key[order]
    _, start, counts = np.unique(key_s, return_index=True, return_counts=True)
    cos_lim = np.cos(np.radians(angle_deg))
    keep_edges = []
    for c_val, mask_sel in ((1, counts == 1), (2, counts == 2)):
        st = start[mask_sel]
        if c_val == 1:
            keep_edges.append(es[order[st]])
        else:
            f1 = fidx[order[st]]
            f2 = fidx[order[st + 1]]
            sharp = np.einsum("ij,ij->i", fn[f1], fn[f2]) < cos_lim
            keep_edges.append(es[order[st[sharp]]])
    # non-manifold edges (> 2 faces) are treated as sharp
    keep_edges.append(es[order[start[counts > 2]]])
    edges = np.concatenate(keep_edges) if keep_edges else np.zeros((0, 2), np.int64)
    if len(edges) == 0:
        return np.zeros((0, 3))
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    length = np.linalg.norm(b - a, axis=1)
    nseg = np.maximum(1, np.ceil(length / spacing_m).astype(np.int64))
    rep = np.repeat(np.arange(len(edges)), nseg + 1)
    # parameter t in [0, 1] along each edge, nseg + 1 samples per edge
    start = np.repeat(np.cumsum(nseg + 1) - (nseg + 1), nseg + 1)
    t = (np.arange(len(rep)) - start) / np.repeat(nseg, nseg + 1)
    return a[rep] + t[:, None] * (b - a)[rep]
