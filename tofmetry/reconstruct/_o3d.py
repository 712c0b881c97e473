"""Thin Open3D helpers shared by registration and evaluation (arrays in, arrays out).

Open3D objects never leave this package's private modules: public functions take and
return numpy arrays in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofmetry.errors import EstimationError


def quiet() -> None:
    """Silence Open3D's console warnings (we report quality ourselves)."""
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)


def to_pcd(points: np.ndarray, normals: np.ndarray | None = None):
    """(N, 3) [m] (+ normals) -> ``o3d.geometry.PointCloud``."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, np.float64)))
    if normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, np.float64))
    return pcd


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 3) unit normals of a triangle mesh's vertices [m, int] (Open3D's ``compute_vertex_normals``:
    the sum of the adjacent triangles' normals; zero where a vertex has no triangle of any area)."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.ascontiguousarray(vertices, np.float64)),
                                     o3d.utility.Vector3iVector(np.ascontiguousarray(triangles, np.int32)))
    mesh.compute_vertex_normals()
    return np.asarray(mesh.vertex_normals).copy()


def estimate_normals(points: np.ndarray, radius_m: float, max_nn: int = 30,
                     toward: np.ndarray | None = None) -> np.ndarray:
    """PCA normals (N, 3), oriented toward ``toward`` (a point, e.g. the camera centre) if given."""
    import open3d as o3d

    pcd = to_pcd(points)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=max_nn))
    n = np.asarray(pcd.normals).copy()
    if toward is not None:
        flip = np.einsum("ij,ij->i", n, np.asarray(toward)[None, :] - points) < 0
        n[flip] *= -1
    return n


def voxel_down(points: np.ndarray, normals: np.ndarray | None, voxel_m: float):
    """Voxel-grid downsampling (centroids); returns (points, normals or None)."""
    pcd = to_pcd(points, normals).voxel_down_sample(voxel_m)
    p = np.asarray(pcd.points).copy()
    n = np.asarray(pcd.normals).copy() if normals is not None else None
    if n is not None:
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return p, n


def voxel_down_values(points: np.ndarray, normals: np.ndarray, values: np.ndarray | None, voxel_m: float):
    """:func:`voxel_down` that also averages per-point values: (N,) or (N, C) with C <= 3 (carried
    as Open3D colours, which are averaged unclipped); returns them with the same trailing shape
    (None: returns None)."""
    pcd = to_pcd(points, normals)
    if values is not None:
        v = np.asarray(values, np.float64)
        v2 = v.reshape(len(v), -1)
        if v2.shape[1] > 3:
            raise ValueError(f"voxel_down_values: at most 3 values per point, found {v2.shape[1]}")
        pad = np.zeros((len(v2), 3))
        pad[:, :v2.shape[1]] = v2
        pcd.colors = __import__("open3d").utility.Vector3dVector(pad)
    pcd = pcd.voxel_down_sample(voxel_m)
    p = np.asarray(pcd.points).copy()
    n = np.asarray(pcd.normals).copy()
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    vals = None
    if values is not None:
        vals = np.asarray(pcd.colors)[:, :v2.shape[1]].copy().reshape(len(p), *v.shape[1:])
    return p, n, vals


@dataclass
class Match:
    """Outcome of a registration step: 4x4 transform source->target and quality."""

    transform: np.ndarray
    fitness: float
    inlier_rmse_m: float
    n_correspondences: int


def global_register(src_pts, src_nrm, tgt_pts, tgt_nrm, voxel_m: float, seed: int = 0,
                    max_iter: int = 100_000, confidence: float = 0.999) -> Match:
    """FPFH features + RANSAC (mutual filter, edge-length and distance checkers).

    Parameters
    ----------
    src_pts, tgt_pts : (N, 3) [m] already downsampled at ``voxel_m``; *_nrm their normals
    voxel_m : feature scale; FPFH radius = 5 voxels, RANSAC inlier distance = 1.5 voxels
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    quiet()
    o3d.utility.random.seed(seed)
    src, tgt = to_pcd(src_pts, src_nrm), to_pcd(tgt_pts, tgt_nrm)
    feat = o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel_m, max_nn=100)
    fs = reg.compute_fpfh_feature(src, feat)
    ft = reg.compute_fpfh_feature(tgt, feat)
    dist = 1.5 * voxel_m
    res = reg.registration_ransac_based_on_feature_matching(
        src, tgt, fs, ft, True, dist, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(dist)],
        reg.RANSACConvergenceCriteria(max_iter, confidence))
    return Match(np.asarray(res.transformation).copy(), float(res.fitness), float(res.inlier_rmse),
                 len(res.correspondence_set))


def icp(src_pts, tgt_pts, tgt_nrm, init: np.ndarray, max_dist_m: float, kernel: str = "tukey",
        kernel_k_m: float | None = None, max_iter: int = 50, src_nrm=None) -> Match:
    """Point-to-plane ICP with a robust kernel ("tukey", "huber" or "none").

    ``kernel_k_m`` defaults to ``max_dist_m / 3``.
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    k = kernel_k_m if kernel_k_m is not None else max_dist_m / 3
    loss = {"tukey": lambda: reg.TukeyLoss(k), "huber": lambda: reg.HuberLoss(k), "none": lambda: reg.L2Loss()}[kernel]()
    res = reg.registration_icp(
        to_pcd(src_pts, src_nrm), to_pcd(tgt_pts, tgt_nrm), max_dist_m, np.asarray(init, np.float64),
        reg.TransformationEstimationPointToPlane(loss),
        reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=max_iter))
    return Match(np.asarray(res.transformation).copy(), float(res.fitness), float(res.inlier_rmse),
                 len(res.correspondence_set))


def information_matrix(src_pts, tgt_pts, max_dist_m: float, transform: np.ndarray,
                       tgt_nrm: np.ndarray | None = None) -> np.ndarray:
    """6x6 information matrix of a pairwise alignment (Open3D convention: rotation then
    translation, perturbation of the source points mapped into the target frame).

    Parameters
    ----------
    src_pts, tgt_pts : (N, 3), (M, 3) [m] source and target points (each in its camera frame)
    max_dist_m : correspondence radius [m] (nearest target point of each mapped source point)
    transform : (4, 4) source -> target
    tgt_nrm : (M, 3) unit target normals, or None

    Returns
    -------
    (6, 6) float64. With ``tgt_nrm``: the point-to-plane Gauss-Newton matrix ``sum J J^T`` with
    ``J = (p x n, n)`` per correspondence (unit noise along the normal): it is what the ICP measured,
    so a direction the matched surfaces do not constrain (sliding along a prism-like object, the
    yaw of a surface of revolution) carries little information and a pose graph spreads loop errors
    there. Without normals: Open3D's point-to-point matrix (it counts three constraints per match
    and so overstates such directions).
    """
    if tgt_nrm is None:
        import open3d as o3d

        return np.asarray(o3d.pipelines.registration.get_information_matrix_from_point_clouds(
            to_pcd(src_pts), to_pcd(tgt_pts), max_dist_m, np.asarray(transform, np.float64))).copy()
    from scipy.spatial import cKDTree

    T = np.asarray(transform, np.float64)
    p = np.asarray(src_pts, np.float64) @ T[:3, :3].T + T[:3, 3]
    d, k = cKDTree(tgt_pts).query(p, distance_upper_bound=max_dist_m, workers=-1)
    ok = np.isfinite(d)
    n = np.asarray(tgt_nrm, np.float64)[k[ok]]
    J = np.hstack([np.cross(p[ok], n), n])
    return J.T @ J


def colored_icp(src_pts, src_vals, tgt_pts, tgt_nrm, tgt_vals, init: np.ndarray, max_dist_m: float,
                lambda_geometric: float = 0.968, kernel_k_m: float | None = None, max_iter: int = 30,
                src_nrm=None) -> Match:
    """Point-to-plane ICP with a photometric term (Park et al. 2017, Open3D ``registration_colored_icp``).

    ``src_vals`` (N,), ``tgt_vals`` (M,): a per-point intensity in [0, 1] (e.g. the relative IR
    albedo); the target's intensity gradient on its tangent plane pulls the source along directions
    the geometry leaves free. ``lambda_geometric`` weighs the geometric term against it (1: ICP).
    """
    import open3d as o3d

    reg = o3d.pipelines.registration

    def pcd(p, n, v):
        c = to_pcd(p, n)
        c.colors = o3d.utility.Vector3dVector(np.repeat(np.asarray(v, np.float64).reshape(-1, 1), 3, axis=1))
        return c

    k = kernel_k_m if kernel_k_m is not None else max_dist_m / 3
    try:
        res = reg.registration_colored_icp(
            pcd(src_pts, src_nrm, src_vals), pcd(tgt_pts, tgt_nrm, tgt_vals), max_dist_m, np.asarray(init, np.float64),
            reg.TransformationEstimationForColoredICP(lambda_geometric, reg.HuberLoss(k)),
            reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=max_iter))
    except RuntimeError as exc:  # Open3D raises when an iteration finds no correspondence within max_dist_m
        if "correspondence" not in str(exc).lower():
            raise
        raise EstimationError(f"coloured ICP: no source point came within {max_dist_m * 1e3:.1f} mm of the "
                              "target") from exc
    return Match(np.asarray(res.transformation).copy(), float(res.fitness), float(res.inlier_rmse),
                 len(res.correspondence_set))
