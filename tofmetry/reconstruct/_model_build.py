"""The model from the placed views: the object's depths, TSDF fusion, and the crop to the object.

Functions of the views (:class:`~tofmetry.reconstruct._preprocess.ViewData`), their segmentations
and camera-to-world poses; :class:`~tofmetry.reconstruct.ReconstructionPipeline` (and the rig
reconstruction) call them after the registration.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tofmetry.errors import EstimationError
from tofmetry.pointcloud import move_onto_points
from tofmetry.reconstruct._config import TRUNCATION_RULE, ReconstructionConfig
from tofmetry.reconstruct._fusion import TSDFFusion, crop_mesh, incidence_weight, poisson_mesh
from tofmetry.reconstruct._o3d import vertex_normals
from tofmetry.reconstruct._world import transform_plane


def object_depths_m(views, segs) -> np.ndarray:
    """(N,) depths Z [m] of the segmented object points of all views."""
    return np.concatenate([v.points[s.object_mask, 2] for v, s in zip(views, segs)])


def object_depth_span_mm(views, segs) -> tuple[float, float] | None:
    """5th-95th percentile of the segmented object points' depths Z over all views [mm]; None
    without object points."""
    z = object_depths_m(views, segs) * 1e3
    return tuple(float(x) for x in np.percentile(z, (5, 95))) if len(z) else None


def median_object_depth_m(views, segs) -> float:
    """Median depth Z [m] of the segmented object points over all views (1 m when there are none)."""
    z = object_depths_m(views, segs)
    return float(np.median(z)) if len(z) else 1.0


def fuse_views(views, segs, poses: np.ndarray, intr, cfg: ReconstructionConfig, progress) -> tuple:
    """TSDF fusion of the views' depth (the object and its ground ring only, unless
    ``cfg.segment.keep_all``) at the poses ``poses`` (V, 4, 4) camera to world [m].

    Returns
    -------
    V, F, N : mesh vertices [m], triangles, normals; P, PN : cloud [m] and normals; info : dict
    (voxel and truncation [mm] and their rule)
    """
    fc = cfg.fusion
    z_med = median_object_depth_m(views, segs) * 1e3
    voxel = fc.voxel_for(z_med, intr.fx)
    trunc = fc.trunc_for(z_med, voxel)
    tsdf = fusion_volume(intr, voxel, trunc, cfg)
    with progress("TSDF fusion", len(views)) as adv:
        for v, s, T in zip(views, segs, poses):
            tsdf.integrate(fusion_depth(v, s, cfg), T, weight=fusion_weight(v, cfg))
            adv()
    V, F, N, P, PN = tsdf.extract(1.0)  # surface seen by a single view is kept (undersides, flanks)
    info = {"voxel_mm": voxel, "trunc_mm": trunc, "median_object_depth_mm": z_med, "min_views": 1,
            "crop_margin_mm": fc.crop_margin_for(z_med, intr.fx), "rule": "voxel = 0.6 * z / f; " + TRUNCATION_RULE}
    if fc.refine_radius_voxels is not None:
        V, N, P, moved = onto_the_views(V, F, N, P, PN, views, segs, poses, cfg, voxel * fc.refine_radius_voxels * 1e-3,
                                        trunc * fc.refine_band_trunc * 1e-3)
        info["refined"] = moved
    return V, F, N, P, PN, info


def onto_the_views(V, F, N, P, PN, views, segs, poses: np.ndarray, cfg: ReconstructionConfig, radius_m: float,
                   band_m: float) -> tuple:
    """The fused mesh's vertices ``V`` (and cloud ``P``, normals ``PN``) moved onto the points the
    views fused (:func:`~tofmetry.pointcloud.move_onto_points` along the fusion's normals ``N``,
    cylinders of ``radius_m`` and half length ``band_m``), the mesh's normals computed again on the
    triangles ``F`` (``N`` where a vertex has no triangle of any area): (V, N, P, dict of the moves). Why:
    :class:`~tofmetry.reconstruct._config.FusionConfig`."""
    pts = np.concatenate([v.points[_fused_mask(s, cfg)] @ T[:3, :3].T + T[:3, 3] for v, s, T in zip(views, segs, poses)])
    both, mv = move_onto_points(np.r_[V, P], np.r_[N, PN], pts, radius_m, band_m)  # one search for mesh and cloud
    V, P, mv = both[:len(V)], both[len(V):], mv[:len(V)]
    moved = mv[np.isfinite(mv)] * 1e3
    info = {"radius_mm": round(radius_m * 1e3, 3), "band_mm": round(band_m * 1e3, 3),
            "share_moved": round(float(len(moved)) / max(len(V), 1), 4),
            "move_mm_p50": round(float(np.median(moved)), 4) if len(moved) else None,
            "move_abs_mm_p90": round(float(np.percentile(np.abs(moved), 90)), 4) if len(moved) else None}
    N_new = vertex_normals(V, F)
    return V, np.where(np.any(N_new != 0, axis=1)[:, None], N_new, N), P, info


def fusion_depth(v, seg, cfg: ReconstructionConfig) -> np.ndarray:
    """The depth (H, W) [mm] of view ``v`` that fusion integrates: the object and its ground ring only
    (everything with ``cfg.segment.keep_all``)."""
    d = v.depth_mm
    if cfg.segment.keep_all:
        return d
    m = np.zeros(d.size, bool)
    m[v.index[_fused_mask(seg, cfg)]] = True
    return np.where(m.reshape(d.shape), d, 0.0)


def fusion_volume(intr, voxel_mm: float, trunc_mm: float, cfg: ReconstructionConfig) -> TSDFFusion:
    """The empty TSDF volume (voxel and truncation [mm]) with ``cfg.fusion``'s band cut and depth
    reading, for depth maps of intrinsics ``intr`` (the first sensor's in a rig)."""
    fc = cfg.fusion
    return TSDFFusion(intr, voxel_mm, trunc_mm, depth_max_mm=cfg.preprocess.max_mm, block_resolution=fc.block_resolution,
                      behind_per_edge=fc.behind_per_edge, edge_jump_mm=fc.edge_jump_mm,
                      behind_min_voxels=fc.behind_min_voxels, interpolate=fc.interpolate_depth, kink_mm=fc.kink_mm)


def fusion_weight(v, cfg: ReconstructionConfig) -> np.ndarray | None:
    """Each pixel's weight (H, W) in the fusion's mean: ``cos(incidence) ** cfg.fusion.incidence_weight_power``
    where view ``v`` has a point, 1 elsewhere (:func:`~tofmetry.reconstruct._fusion.incidence_weight`);
    None when the power is 0."""
    power = cfg.fusion.incidence_weight_power
    if power == 0:
        return None
    w = np.ones(v.depth_mm.size)
    w[v.index] = incidence_weight(v.cos_incidence, power)
    return w.reshape(v.depth_mm.shape)


def _fused_mask(seg, cfg: ReconstructionConfig):
    """Which of a view's points fusion takes: the object and its ground ring (all with ``keep_all``)."""
    return slice(None) if cfg.segment.keep_all else seg.object_mask | seg.ring_mask


def crop_mask(pts: np.ndarray, world_obj: np.ndarray, plane_w: np.ndarray | None, cfg: ReconstructionConfig,
              margin_mm: float | None = None, normals: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: ``pts`` (N, 3) [m] near the segmented object points ``world_obj`` (M, 3) [m] and above
    the support plane ``plane_w`` (4,) (None: no plane).

    Near: within ``cfg.fusion.crop_margin_mm`` of a point, or, with ``normals`` (N, 3) unit, within
    ``margin_mm`` [mm] of one that lies within ``crop_margin_mm`` of the tangent plane there: the
    views' points are farther apart than the floor on a surface seen obliquely from afar (the
    fusion's ``crop_margin_mm``, :meth:`FusionConfig.crop_margin_for`), but a surface the fusion put
    off the points along its normal stays cropped. The wider margin holds only higher above the
    plane than ``cfg.segment.min_height_mm`` plus itself: below, the fused ground ring meets the
    object and the TSDF blends the two (measured: a rocker arm's model kept a blend 5-6 mm above the
    ground, 6-8 mm off the object)."""
    if cfg.segment.keep_all:
        return np.ones(len(pts), bool)
    floor = cfg.fusion.crop_margin_mm * 1e-3
    tree = cKDTree(world_obj)
    d, _ = tree.query(pts, distance_upper_bound=floor, workers=-1)
    keep = np.isfinite(d)
    height = None if plane_w is None else pts @ plane_w[:3] + plane_w[3]
    wide = ~keep
    if height is not None and margin_mm is not None:
        wide &= height > (cfg.segment.min_height_mm + margin_mm) * 1e-3
    if normals is not None and margin_mm is not None and margin_mm * 1e-3 > floor and wide.any():
        far = np.flatnonzero(wide)
        dd, ii = tree.query(pts[far], k=8, distance_upper_bound=margin_mm * 1e-3, workers=-1)
        found = np.isfinite(dd)
        q = world_obj[np.where(found, ii, 0)] - pts[far][:, None, :]
        along = np.abs(np.einsum("nkj,nj->nk", q, normals[far]))
        keep[far] = np.any(found & (along <= floor), axis=1)
    if height is not None:
        keep &= height > 0.5 * cfg.segment.min_height_mm * 1e-3
    return keep


def crop_model(V, F, N, P, PN, world_obj: np.ndarray, plane_w: np.ndarray | None, cfg: ReconstructionConfig,
               margin_mm: float | None = None) -> tuple:
    """The fused mesh (V, F, N) and cloud (P, PN) cropped to the object (:func:`crop_mask`, within
    ``margin_mm``: the fusion's ``crop_margin_mm`` where it gives one), and the Poisson mesh of the
    cropped cloud (cropped as well; None when switched off)."""
    V, F, used = crop_mesh(V, F, crop_mask(V, world_obj, plane_w, cfg, margin_mm, N))
    N = N[used]
    keep_p = crop_mask(P, world_obj, plane_w, cfg, margin_mm, PN)
    P, PN = P[keep_p], PN[keep_p]
    if len(F) == 0 or len(P) == 0:
        raise EstimationError("fusion produced an empty model after cropping to the object")
    poisson = None
    if cfg.fusion.poisson:
        pv, pf = poisson_mesh(P, PN, cfg.fusion.poisson_depth, cfg.fusion.poisson_trim_quantile)
        pv, pf, _ = crop_mesh(pv, pf, crop_mask(pv, world_obj, plane_w, cfg))
        poisson = (pv, pf)
    return V, F, N, P, PN, poisson


def world_plane(plane_cam: np.ndarray | None, pose: np.ndarray) -> np.ndarray | None:
    """The support plane (4,) of a view's camera frame in the world frame, given that view's
    camera-to-world ``pose`` (4, 4); None without a plane."""
    return None if plane_cam is None else transform_plane(plane_cam, pose)
