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
from tofmetry.reconstruct._o3d import global_register, icp, information_matrix, voxel_down
from tofmetry.reconstruct._preprocess import ViewData
from tofmetry.reconstruct._segment import Segmentation


@dataclass
class RegView:
    """Registration clouds of one view (camera frame, metres).

    Attributes
    ----------
    icp_points, icp_normals : (M, 3) object (+ ground ring) at the ICP voxel
    obj_points : (K, 3) object only at the ICP voxel (fitness is measured on these)
    feat_points, feat_normals : (F, 3) object at the feature voxel (FPFH)
    """

    name: str
    icp_points: np.ndarray
    icp_normals: np.ndarray
    obj_points: np.ndarray
    feat_points: np.ndarray
    feat_normals: np.ndarray
    _tree: cKDTree | None = field(default=None, repr=False)

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.icp_points)
        return self._tree


def make_reg_view(view: ViewData, seg: Segmentation, cfg: RegistrationConfig) -> RegView:
    """Select reliable object (+ ring) points and downsample them for registration."""
    reliable = view.cos_incidence >= np.cos(np.radians(cfg.max_incidence_deg))
    obj = seg.object_mask & reliable
    sel = obj | (seg.ring_mask & reliable) if cfg.use_ground else obj
    p, n = voxel_down(view.points[sel], view.normals[sel], cfg.icp_voxel_mm * 1e-3)
    po, _ = voxel_down(view.points[obj], None, cfg.icp_voxel_mm * 1e-3)
    pf, nf = voxel_down(view.points[seg.object_mask], view.normals[seg.object_mask], cfg.feature_voxel_mm * 1e-3)
    return RegView(view.name, p, n, po, pf, nf)


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


def _refine(src: RegView, tgt: RegView, init: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    T = init
    for r in cfg.icp_radii_mm:
        T = icp(src.icp_points, tgt.icp_points, tgt.icp_normals, T, r * 1e-3, kernel=cfg.kernel).transform
    return T


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


def register_pair(src: RegView, tgt: RegView, i: int, j: int, cfg: RegistrationConfig,
                  init: np.ndarray | None = None) -> PairResult:
    """Register view ``i`` (source) onto view ``j`` (target).

    With ``init`` the ICP starts there first; FPFH + RANSAC (``cfg.ransac_seeds`` restarts)
    is used when there is no ``init`` or when the initialised ICP fails the gates. The
    candidate with the best (fitness, -RMSE) wins.
    """
    r_final = cfg.icp_radii_mm[-1] * 1e-3
    cands = []
    if init is not None:
        T = _refine(src, tgt, init, cfg)
        cands.append((*object_fitness(src, tgt, T, r_final), T, "init+icp"))
    if not cands or not _passes(cands[0][0], cands[0][1], cfg):
        for s in range(cfg.ransac_seeds):
            g = global_register(src.feat_points, src.feat_normals, tgt.feat_points, tgt.feat_normals,
                                cfg.feature_voxel_mm * 1e-3, seed=cfg.seed + s)
            T = _refine(src, tgt, g.transform, cfg)
            cands.append((*object_fitness(src, tgt, T, r_final), T, "fpfh+icp"))
    fit, rmse, T, method = max(cands, key=lambda c: (round(c[0], 2), -c[1]))
    info = information_matrix(src.icp_points, tgt.icp_points, r_final, T)
    return PairResult(i, j, T, fit, rmse * 1e3, info, method, _passes(fit, rmse, cfg))


def _passes(fit: float, rmse_m: float, cfg: RegistrationConfig) -> bool:
    return fit >= cfg.min_fitness and rmse_m * 1e3 <= cfg.max_rmse_mm
