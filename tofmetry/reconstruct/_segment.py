"""Object segmentation in one view: support plane (RANSAC), what stands on it, near-axis cluster."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tofmetry._shared.geometry import fit_plane_svd
from tofmetry.errors import EstimationError
from tofmetry.reconstruct._config import SegmentConfig
from tofmetry.reconstruct._o3d import quiet, to_pcd
from tofmetry.reconstruct._support import support_region


@dataclass
class Segmentation:
    """Masks over a view's points and the support plane.

    Attributes
    ----------
    object_mask : (N,) bool, points of the object
    ring_mask : (N,) bool, support-plane points around the object footprint
    core_mask : (N,) bool, the main cluster only (nearest the optical axis), used for registration
    plane : (4,) float64 (a, b, c, d), unit normal toward the camera, height = n . p + d [m]
        (None when segmentation was skipped)
    plane_inlier_share : float, share of the view's points on the support plane
    """

    object_mask: np.ndarray
    ring_mask: np.ndarray
    core_mask: np.ndarray | None
    plane: np.ndarray | None
    plane_inlier_share: float


def ransac_plane(points: np.ndarray, threshold_m: float, iterations: int = 1000, seed: int = 0,
                 score_points: int = 5000) -> tuple[np.ndarray, int]:
    """The plane through 3 sampled points that holds the most points within ``threshold_m``.

    Deterministic for a given ``seed`` (NumPy's generator; the scores are exact counts, ties go to
    the first sample). Open3D's ``segment_plane`` is not: its multi-threaded RANSAC gave planes
    0.01 mm apart in separate processes on the same points with the same seed (measured on a
    family scan: 2 views of 10 segmented differently, and the run's loop closure moved from 2.13 to
    1.64 deg, across the verdict's limit).

    The candidates are scored on ``score_points`` points drawn once (the share of a dominant plane
    is estimated to about +-0.5 % from 5000): 0.03 s instead of 0.6 s on the 80 000 points of a
    view's 5 mm voxels, the cost of Open3D's early-terminating search.

    Parameters
    ----------
    points : (N, 3) [m]; threshold_m : inlier distance [m]; iterations : samples drawn
    score_points : points the candidates are scored on (all when fewer)

    Returns
    -------
    plane : (4,) unit normal and offset (``n . p + d = 0``) [m]; inliers : their count
    """
    p = np.asarray(points, np.float64)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(p), size=(iterations, 3))
    a, b, c = p[idx[:, 0]], p[idx[:, 1]], p[idx[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-12
    n, a = n[ok] / norm[ok, None], a[ok]
    d = -np.einsum("ij,ij->i", n, a)
    q = p[rng.choice(len(p), score_points, replace=False)] if len(p) > score_points else p
    best, best_count = 0, -1
    for s in range(0, len(n), 64):  # (M, 64) distances at a time
        counts = (np.abs(q @ n[s:s + 64].T + d[s:s + 64]) < threshold_m).sum(axis=0)
        j = int(np.argmax(counts))
        if counts[j] > best_count:
            best, best_count = s + j, int(counts[j])
    if best_count < 0:
        raise EstimationError("support plane: the points are collinear or too few (no plane through 3 of them)")
    plane = np.r_[n[best], d[best]]
    return plane, int(np.sum(np.abs(p @ plane[:3] + plane[3]) < threshold_m))


def fit_support_plane(points: np.ndarray, threshold_m: float, seed: int = 0) -> tuple[np.ndarray, float]:
    """Dominant plane by RANSAC (:func:`ransac_plane` on 5 mm voxels), refined by least squares.

    Returns
    -------
    plane : (4,) unit normal oriented toward the origin (camera), offset [m]
    inlier_share : float
    """
    quiet()
    down = np.asarray(to_pcd(points).voxel_down_sample(0.005).points)
    plane, _ = ransac_plane(down, threshold_m, 1000, seed)
    # least-squares refinement on all points within the threshold, repeated: the plane through the
    # middle of the noisy slab, whatever the tilt of the sample RANSAC kept
    for _ in range(3):
        sel = points[np.abs(points @ plane[:3] + plane[3]) < threshold_m]
        if len(sel) < 3:
            break
        plane = fit_plane_svd(sel, orient=plane[:3])
    if plane[3] < 0:  # camera (origin) on the positive side: height(origin) = d > 0
        plane = -plane
    share = float(np.mean(np.abs(points @ plane[:3] + plane[3]) < threshold_m))
    return plane, share


def segment_object(points: np.ndarray, config: SegmentConfig | None = None, seed: int = 0,
                   height_tolerance_m: np.ndarray | None = None, normals: np.ndarray | None = None,
                   grid: tuple[np.ndarray, tuple[int, int]] | None = None) -> Segmentation:
    """Segment the object standing on the support plane.

    Parameters
    ----------
    points : (N, 3) float64 [m], camera frame
    height_tolerance_m : optional (N,) float [m], added per point to ``min_height_mm``: how far a
        point's depth may be off beyond the plane fit's own tolerance (depth the calibration only
        extrapolates to: the support plane there can read millimetres off, and a band of it would
        otherwise stand "on" the plane and join the object)
    normals, grid : optional (N, 3) unit normals toward the camera and (flat pixel index (N,), image
        shape): with both (and ``config.support_band_mm`` > 0), what continues the support plane
        smoothly and level on the image grid is support, not object, however far the measured
        table bends from the fitted plane (:func:`~tofmetry.reconstruct._support.support_region`)

    Raises
    ------
    EstimationError when nothing stands on the plane.
    """
    cfg = config or SegmentConfig()
    n = len(points)
    if cfg.keep_all:
        return Segmentation(np.ones(n, bool), np.zeros(n, bool), None, None, 0.0)
    plane, share = fit_support_plane(points, cfg.plane_threshold_mm * 1e-3, seed)
    h = points @ plane[:3] + plane[3]
    floor = cfg.min_height_mm * 1e-3 + (0.0 if height_tolerance_m is None else np.asarray(height_tolerance_m))
    cand = (h > floor) & (h < cfg.max_height_mm * 1e-3)
    if normals is not None and grid is not None and cfg.support_band_mm > 0:
        cand &= ~support_region(points, normals, grid[0], grid[1], plane, cfg.plane_threshold_mm * 1e-3,
                                cfg.support_band_mm * 1e-3, cfg.support_tilt_deg)
    if cand.sum() < 50:
        raise EstimationError(f"segmentation: only {int(cand.sum())} points stand on the support plane "
                              f"(plane holds {share:.0%} of the view); use --keep-all to skip segmentation")
    ci = np.flatnonzero(cand)
    cp = points[ci]
    # cluster on 4 mm voxels: label each voxel centroid, then propagate to the points
    import open3d as o3d

    down = to_pcd(cp).voxel_down_sample(0.004)
    dp = np.asarray(down.points)
    labels = np.asarray(down.cluster_dbscan(cfg.cluster_eps_mm * 1e-3, 8, False))
    if labels.max() < 0:
        raise EstimationError("segmentation: no compact cluster stands on the support plane")
    best, best_score = -1, -np.inf
    for lab in range(labels.max() + 1):
        m = labels == lab
        c = dp[m].mean(0)
        ang = np.degrees(np.arccos(np.clip(c[2] / np.linalg.norm(c), -1, 1)))
        score = m.sum() * (1.0 if ang < 20 else 0.1)  # favour clusters near the optical axis
        if score > best_score:
            best, best_score = lab, score
    # parts of one object can be separated in a view (occlusion, removed mixed pixels at depth
    # jumps): merge every cluster within merge_gap of the object grown so far
    members = {best}
    grown = True
    while grown:
        grown = False
        tree = cKDTree(dp[np.isin(labels, list(members))])
        for lab in range(labels.max() + 1):
            if lab in members or (labels == lab).sum() < 10:
                continue
            dmin, _ = tree.query(dp[labels == lab], distance_upper_bound=cfg.merge_gap_mm * 1e-3)
            if np.isfinite(dmin).any():
                members.add(lab)
                grown = True
    core_only = dp[labels == best]
    core = dp[np.isin(labels, list(members))]
    d, _ = cKDTree(core).query(cp, distance_upper_bound=cfg.cluster_eps_mm * 1e-3, workers=-1)
    obj_local = np.isfinite(d)
    # footprint limit: in-plane distance from the core centroid
    nrm = plane[:3]
    c0 = core.mean(0)
    rel = cp - c0
    inplane = rel - np.outer(rel @ nrm, nrm)
    obj_local &= np.linalg.norm(inplane, axis=1) < cfg.max_footprint_mm * 1e-3
    obj = np.zeros(n, bool)
    obj[ci[obj_local]] = True
    dc, _ = cKDTree(core_only).query(cp, distance_upper_bound=cfg.cluster_eps_mm * 1e-3, workers=-1)
    core_mask = np.zeros(n, bool)
    core_mask[ci[np.isfinite(dc) & obj_local]] = True
    _ = o3d
    # ground ring around the footprint (in-plane distance to the object's projected points)
    ring = np.zeros(n, bool)
    if cfg.ring_mm > 0:
        on_plane = np.flatnonzero(np.abs(h) <= cfg.plane_threshold_mm * 1e-3)
        foot = points[obj] - np.outer(h[obj], nrm)
        foot_down = np.asarray(to_pcd(foot).voxel_down_sample(0.01).points)
        gp = points[on_plane]
        dd, _ = cKDTree(foot_down).query(gp, distance_upper_bound=cfg.ring_mm * 1e-3, workers=-1)
        ring[on_plane[np.isfinite(dd)]] = True
    return Segmentation(obj, ring, core_mask, plane, share)
