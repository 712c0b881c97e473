"""Pairwise registration of prepared views: FPFH + RANSAC coarse, robust point-to-plane ICP fine.

Reliability weighting (study §6.3): only points seen at an incidence angle below
``max_incidence_deg`` take part (a 0/1 weight: grazing points are the noisiest and carry the
mixed-pixel bias), and the Tukey kernel down-weights the remaining outliers. The range is
limited by the working range of the preprocessing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._o3d import (
    global_register,
    icp,
    information_matrix,
    voxel_down,
)
from tofmetry.reconstruct._preprocess import ViewData
from tofmetry.reconstruct._segment import Segmentation


@dataclass
class RegView:
    """Registration clouds of one view (camera frame, metres).

    Attributes
    ----------
    icp_points, icp_normals : (M, 3) object (+ ground ring) at the ICP voxel
    obj_points : (K, 3) object only at the ICP voxel (fitness is measured on these)
    coarse_points, coarse_normals : main cluster (+ ring) at the coarse voxel (quick ICP of hypotheses)
    mid_points, mid_normals : the ICP selection at the mid voxel (all ICP stages but the last run on these)
    feat_points, feat_normals : (F, 3) object at the feature voxel (FPFH)
    """

    name: str
    icp_points: np.ndarray
    icp_normals: np.ndarray
    obj_points: np.ndarray
    feat_points: np.ndarray
    feat_normals: np.ndarray
    coarse_points: np.ndarray | None = None
    coarse_normals: np.ndarray | None = None
    plane: np.ndarray | None = None
    mid_points: np.ndarray | None = None
    mid_normals: np.ndarray | None = None
    _tree: cKDTree | None = field(default=None, repr=False)

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.icp_points)
        return self._tree


def make_reg_view(view: ViewData, seg: Segmentation, cfg: RegistrationConfig) -> RegView:
    """Select reliable object (+ ring) points and downsample them for registration."""
    reliable = view.cos_incidence >= np.cos(np.radians(cfg.max_incidence_deg))
    # coarse hypotheses and their scoring use the main cluster only (parts merged across a gap are
    # the least reliable and make a nearly symmetric object more ambiguous); the fine ICP uses the
    # whole object, whose ends constrain the slide along a prism-like middle part
    core = seg.core_mask if seg.core_mask is not None else seg.object_mask
    ring = seg.ring_mask & reliable if cfg.use_ground else np.zeros_like(reliable)
    fine = view.cos_incidence >= np.cos(np.radians(cfg.fine_max_incidence_deg))
    sel = (seg.object_mask & reliable & fine) | (ring & fine)
    p, n = voxel_down(view.points[sel], view.normals[sel], cfg.icp_voxel_mm * 1e-3)
    po, _ = voxel_down(view.points[seg.object_mask & reliable], None, cfg.icp_voxel_mm * 1e-3)
    pf, nf = voxel_down(view.points[core], view.normals[core], cfg.feature_voxel_mm * 1e-3)
    csel = (core & reliable) | ring
    pc, nc = voxel_down(view.points[csel], view.normals[csel], cfg.coarse_voxel_mm * 1e-3)
    pm, nm = voxel_down(view.points[sel], view.normals[sel], cfg.mid_voxel_mm * 1e-3)
    return RegView(view.name, p, n, po, pf, nf, pc, nc, seg.plane, pm, nm)


def _plane_frame(plane: np.ndarray, obj: np.ndarray) -> np.ndarray:
    """4x4 frame: origin = object centroid projected on the plane, z = plane normal (up)."""
    n = plane[:3]
    c = obj.mean(0)
    o = c - (n @ c + plane[3]) * n
    x = np.array([1.0, 0, 0]) - n[0] * n
    x /= np.linalg.norm(x)
    F = np.eye(4)
    F[:3, 0], F[:3, 1], F[:3, 2], F[:3, 3] = x, np.cross(n, x), n, o
    return F


def plane_consistent(src: RegView, tgt: RegView, T: np.ndarray, max_deg: float = 3.0, max_mm: float = 8.0) -> bool:
    """Does ``T`` map the source support plane onto the target one (normal and offset)?"""
    if src.plane is None or tgt.plane is None:
        return True
    n_s = T[:3, :3] @ src.plane[:3]
    ang = np.degrees(np.arccos(np.clip(n_s @ tgt.plane[:3], -1, 1)))
    # a source-plane point mapped into the target must lie on the target plane
    p0 = -src.plane[3] * src.plane[:3]
    h = tgt.plane[:3] @ (T[:3, :3] @ p0 + T[:3, 3]) + tgt.plane[3]
    return bool(ang <= max_deg and abs(h) * 1e3 <= max_mm)


def yaw_candidates(src: RegView, tgt: RegView, step_deg: float = 30.0) -> list[np.ndarray]:
    """Transforms that put the source support plane on the target one, at yaw steps about its normal."""
    Fs = _plane_frame(src.plane, src.obj_points)
    Ft = _plane_frame(tgt.plane, tgt.obj_points)
    out = []
    for a in np.radians(np.arange(0.0, 360.0, step_deg)):
        Rz = np.eye(4)
        Rz[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        out.append(Ft @ Rz @ np.linalg.inv(Fs))
    return out


@dataclass
class PairResult:
    """Registration of view ``source`` onto view ``target``.

    Attributes
    ----------
    transform : (4, 4) maps source-camera points into the target camera frame
    fitness : share of the source object points with a target point within the final ICP radius
    inlier_rmse_mm : RMS distance of those matches [mm]
    information : (6, 6) Open3D information matrix
    method : "fpfh+icp" or "init+icp"
    accepted : passed the fitness / RMSE gates
    """

    source: int
    target: int
    transform: np.ndarray
    fitness: float
    inlier_rmse_mm: float
    information: np.ndarray
    method: str
    accepted: bool

    def to_dict(self, names: list[str]) -> dict:
        return {"source": names[self.source], "target": names[self.target], "fitness": round(self.fitness, 4),
                "inlier_rmse_mm": round(self.inlier_rmse_mm, 3), "method": self.method, "accepted": self.accepted}


def _refine_mid(src: RegView, tgt: RegView, init: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """All ICP stages but the last, on the mid-voxel clouds (cheap; within ~1 mm of the fine result)."""
    T = init
    sp, tp, tn = ((src.mid_points, tgt.mid_points, tgt.mid_normals) if src.mid_points is not None
                  else (src.icp_points, tgt.icp_points, tgt.icp_normals))
    for r in cfg.icp_radii_mm[:-1]:
        T = icp(sp, tp, tn, T, r * 1e-3, kernel=cfg.kernel, max_iter=cfg.icp_max_iter).transform
    return T


def _refine_fine(src: RegView, tgt: RegView, init: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """The last (narrowest) ICP stage on the full ICP clouds."""
    return icp(src.icp_points, tgt.icp_points, tgt.icp_normals, init, cfg.icp_radii_mm[-1] * 1e-3, kernel=cfg.kernel,
               max_iter=cfg.fine_max_iter).transform


def _refine(src: RegView, tgt: RegView, init: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    return _refine_fine(src, tgt, _refine_mid(src, tgt, init, cfg), cfg)


def object_fitness(src: RegView, tgt: RegView, T: np.ndarray, radius_m: float) -> tuple[float, float]:
    """Share of the source object points within ``radius_m`` of the target cloud, and their RMS [m]."""
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    d, _ = tgt.tree.query(p, distance_upper_bound=radius_m, workers=-1)
    ok = np.isfinite(d)
    if not ok.any():
        return 0.0, np.inf
    # target overlap is partial: normalise by the source points that fall inside the target's bounding box
    lo, hi = tgt.icp_points.min(0) - radius_m, tgt.icp_points.max(0) + radius_m
    inside = np.all((p >= lo) & (p <= hi), axis=1)
    return float(ok.sum() / max(inside.sum(), 1)), float(np.sqrt(np.mean(d[ok] ** 2)))


def _coarse_fitness(src: RegView, tgt: RegView, T: np.ndarray, radius_m: float) -> tuple[float, float]:
    """Share of the source coarse points within ``radius_m`` of the target coarse points, and their RMS [m]."""
    p = src.coarse_points @ T[:3, :3].T + T[:3, 3]
    d, _ = cKDTree(tgt.coarse_points).query(p, distance_upper_bound=radius_m, workers=-1)
    ok = np.isfinite(d)
    return (float(ok.mean()), float(np.sqrt(np.mean(d[ok] ** 2)))) if ok.any() else (0.0, np.inf)


def register_pair(src: RegView, tgt: RegView, i: int, j: int, cfg: RegistrationConfig,
                  init: np.ndarray | None = None, global_search: bool = True) -> PairResult:
    """Register view ``i`` (source) onto view ``j`` (target).

    With ``init`` the ICP starts there first; FPFH + RANSAC (``cfg.ransac_seeds`` restarts)
    is used when there is no ``init`` or when the initialised ICP fails the gates. The
    candidate with the best (fitness, -RMSE) wins.
    """
    r_final = cfg.icp_radii_mm[-1] * 1e-3
    cands = []
    if init is not None:
        T = _refine_mid(src, tgt, init, cfg)
        E = np.linalg.inv(init) @ T
        jump_deg = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
        if global_search or (jump_deg <= cfg.max_loop_jump_deg and np.linalg.norm(E[:3, 3]) * 1e3 <= cfg.max_loop_jump_mm):
            T = _refine_fine(src, tgt, T, cfg)
            cands.append((*object_fitness(src, tgt, T, r_final), T, "init+icp"))
    if global_search and (not cands or not _passes(cands[0][0], cands[0][1], cfg) or not plane_consistent(src, tgt, cands[0][2])):
        coarse = []
        use_plane = src.plane is not None and tgt.plane is not None
        for s in range(0 if use_plane else cfg.ransac_seeds):
            g = global_register(src.feat_points, src.feat_normals, tgt.feat_points, tgt.feat_normals,
                                cfg.feature_voxel_mm * 1e-3, seed=cfg.seed + s)
            coarse.append((g.transform, "fpfh+icp"))
        if use_plane:
            coarse += [(T, "plane-yaw+icp") for T in yaw_candidates(src, tgt, cfg.yaw_step_deg)]
        # quick ICP of every coarse candidate on the feature-voxel clouds, keep the best few
        quick = []
        for T0, how in coarse:
            T = T0
            for r in (2.5 * cfg.coarse_voxel_mm, 1.25 * cfg.coarse_voxel_mm):
                T = icp(src.coarse_points, tgt.coarse_points, tgt.coarse_normals, T, r * 1e-3, kernel=cfg.kernel,
                        max_iter=12).transform
            if plane_consistent(src, tgt, T, 5.0, 15.0):
                quick.append((*_coarse_fitness(src, tgt, T, 1.25 * cfg.coarse_voxel_mm * 1e-3), T, how))
        quick.sort(key=lambda c: (-c[0], c[1]))
        distinct: list = []  # several yaw seeds converge to the same pose: refine distinct ones only
        for c in quick:
            if all(not _same_pose(c[2], d[2]) for d in distinct):
                distinct.append(c)
        # coarse-to-fine: the distinct hypotheses are refined on the mid-voxel clouds and ranked;
        # only the winner gets the last ICP stage on the full clouds
        mids = []
        for fit0, rm0, T0, how in distinct[:cfg.refine_candidates]:
            T = _refine_mid(src, tgt, T0, cfg)
            if plane_consistent(src, tgt, T):
                mids.append((*object_fitness(src, tgt, T, r_final), T, how))
        if mids:
            _, _, T, how = max(mids, key=lambda c: (c[0], -c[1]))
            T = _refine_fine(src, tgt, T, cfg)
            if plane_consistent(src, tgt, T):
                cands.append((*object_fitness(src, tgt, T, r_final), T, how))
    if not cands:
        return PairResult(i, j, np.eye(4), 0.0, np.inf, np.zeros((6, 6)), "none", False)
    fit, rmse, T, method = max(cands, key=lambda c: (c[0] if plane_consistent(src, tgt, c[2]) else -1, -c[1]))
    info = information_matrix(src.icp_points, tgt.icp_points, r_final, T)
    return PairResult(i, j, T, fit, rmse * 1e3, info, method, _passes(fit, rmse, cfg))


def _same_pose(A: np.ndarray, B: np.ndarray, deg: float = 3.0, mm: float = 10.0) -> bool:
    E = np.linalg.inv(A) @ B
    ang = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return bool(ang <= deg and np.linalg.norm(E[:3, 3]) * 1e3 <= mm)


def _passes(fit: float, rmse_m: float, cfg: RegistrationConfig) -> bool:
    return fit >= cfg.min_fitness and rmse_m * 1e3 <= cfg.max_rmse_mm
