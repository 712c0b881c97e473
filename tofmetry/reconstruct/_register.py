"""Pairwise registration of prepared views: FPFH + RANSAC coarse, robust point-to-plane ICP fine.

Hypotheses are tested for visibility (free space): a pose under which one camera would have
seen through the other's object surface is rejected; this is what separates a nearly symmetric
object's turned-over match from the true one (both fit the surfaces alike). Distinct hypotheses
that pass every gate are kept as ``alternatives`` for the multi-view selection of the pose graph.

Reliability weighting (study §6.3): only points seen at an incidence angle below
``max_incidence_deg`` take part (a 0/1 weight: grazing points are the noisiest and carry the
mixed-pixel bias), and the Tukey kernel down-weights the remaining outliers. The range is
limited by the working range of the preprocessing.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.ndimage import minimum_filter
from scipy.spatial import cKDTree

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._photometric import ir_yaw_sweep, log_albedo
from tofmetry.reconstruct._o3d import (
    global_register,
    icp,
    information_matrix,
    voxel_down,
    voxel_down_values,
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
    near_depth_m : (H, W) float32 nearest observed depth in each pixel's 3x3 neighbourhood [m]
        (inf where nothing valid was observed): the free space seen by this camera
    intr : CameraIntrinsics of the depth image (projection for the free-space test)
    obj_normals : (K, 3) unit normals of ``obj_points`` (toward the camera)
    obj_ir, icp_ir : relative log IR albedo of ``obj_points`` / ``icp_points``
        (:func:`~tofmetry.reconstruct._photometric.log_albedo`), or None without IR
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
    near_depth_m: np.ndarray | None = None
    intr: object = None
    obj_normals: np.ndarray | None = None
    obj_ir: np.ndarray | None = None
    icp_ir: np.ndarray | None = None
    _tree: cKDTree | None = field(default=None, repr=False)

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.icp_points)
        return self._tree


def make_reg_view(view: ViewData, seg: Segmentation, cfg: RegistrationConfig, intr=None,
                  white_map: np.ndarray | None = None) -> RegView:
    """Select reliable object (+ ring) points and downsample them for registration (``intr``: the
    depth intrinsics, enables the free-space test of hypotheses and, with the view's IR, the
    photometric yaw search; ``white_map``: the amplitude reference, refines the albedo estimate)."""
    reliable = view.cos_incidence >= np.cos(np.radians(cfg.max_incidence_deg))
    # coarse hypotheses and their scoring use the main cluster only (parts merged across a gap are
    # the least reliable and make a nearly symmetric object more ambiguous); the fine ICP uses the
    # whole object, whose ends constrain the slide along a prism-like middle part
    core = seg.core_mask if seg.core_mask is not None else seg.object_mask
    ring = seg.ring_mask & reliable if cfg.use_ground else np.zeros_like(reliable)
    fine = view.cos_incidence >= np.cos(np.radians(cfg.fine_max_incidence_deg))
    sel = (seg.object_mask & reliable & fine) | (ring & fine)
    alb = log_albedo(view, intr, white_map) if cfg.ir_yaw and view.ir is not None and intr is not None else None
    p, n, p_ir = voxel_down_values(view.points[sel], view.normals[sel], None if alb is None else alb[sel],
                                   cfg.icp_voxel_mm * 1e-3)
    om = seg.object_mask & reliable
    po, pon, po_ir = voxel_down_values(view.points[om], view.normals[om], None if alb is None else alb[om],
                                       cfg.icp_voxel_mm * 1e-3)
    pf, nf = voxel_down(view.points[core], view.normals[core], cfg.feature_voxel_mm * 1e-3)
    csel = (core & reliable) | ring
    pc, nc = voxel_down(view.points[csel], view.normals[csel], cfg.coarse_voxel_mm * 1e-3)
    pm, nm = voxel_down(view.points[sel], view.normals[sel], cfg.mid_voxel_mm * 1e-3)
    near = None
    if intr is not None:
        d = np.where(view.depth_mm > 0, view.depth_mm * 1e-3, np.inf).astype(np.float32)
        near = minimum_filter(d, size=3, mode="nearest")
    return RegView(view.name, p, n, po, pf, nf, pc, nc, seg.plane, pm, nm, near, intr, pon, po_ir, p_ir)


def free_space_violation(src: RegView, tgt: RegView, T: np.ndarray, tol_m: float) -> float:
    """Share of the source object points that, mapped by ``T`` into the target camera, lie more than
    ``tol_m`` in front of everything the target camera observed around that pixel (3x3): space the
    target saw through. A correct pose leaves only noise there; a near-symmetric false match puts
    surface where the other camera saw the background (visibility consistency). 0 when the target
    has no depth image; points outside its image or over invalid pixels are not counted."""
    if tgt.near_depth_m is None or tgt.intr is None:
        return 0.0
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    p = p[p[:, 2] > 1e-3]
    if len(p) == 0:
        return 0.0
    uv = np.rint(tgt.intr.project(p)).astype(np.int64)
    H, W = tgt.near_depth_m.shape
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    d = np.full(len(p), np.inf)
    d[ok] = tgt.near_depth_m[uv[ok, 1], uv[ok, 0]]
    known = np.isfinite(d)
    if not known.any():
        return 0.0
    return float(np.sum(p[known, 2] < d[known] - tol_m) / known.sum())


def visibility_violation(src: RegView, tgt: RegView, T: np.ndarray, tol_m: float) -> float:
    """:func:`free_space_violation` both ways (source into target, target into source): the larger."""
    return max(free_space_violation(src, tgt, T, tol_m), free_space_violation(tgt, src, np.linalg.inv(T), tol_m))


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


def shifted_yaw_candidates(src: RegView, tgt: RegView, step_deg: float = 30.0, frac: float = 0.5) -> list[np.ndarray]:
    """:func:`yaw_candidates` shifted in the support plane by ``frac`` x the target object's in-plane RMS
    radius in the 8 directions of a 3 x 3 grid. The yaw seeds put the two object centroids on top of
    each other, but each view sees another part of the object: on an elongated object seen from
    views 60 degrees apart the centroids differ by ~0.1 m and the quick ICP slides away from the
    right yaw (measured); the shifted seeds start within reach of it."""
    n = tgt.plane[:3]
    rel = tgt.obj_points - tgt.obj_points.mean(0)
    rel -= np.outer(rel @ n, n)
    d = frac * float(np.sqrt(np.mean(np.sum(rel ** 2, 1))))
    x = np.cross(n, [1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.cross(n, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    out = []
    for T0 in yaw_candidates(src, tgt, step_deg):
        for a in (-1, 0, 1):
            for b in (-1, 0, 1):
                if a or b:
                    S = np.eye(4)
                    S[:3, 3] = d * (a * x + b * y)
                    out.append(S @ T0)
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
    method : "fpfh+icp", "plane-yaw+icp" or "init+icp"
    accepted : passed the fitness / RMSE gates and the free-space test
    alternatives : other distinct hypotheses that pass the gates (PairResult each), best first
    conditioning : :func:`registration_conditioning` of the transform
    see_through : :func:`visibility_violation` of the transform (share of points seen through)
    ir_yaw : the photometric yaw search of a yaw-free edge (:func:`~tofmetry.reconstruct._photometric.ir_yaw_sweep`:
        correlation of the best yaw, its margin over the next, whether it decided) or None
    """

    source: int
    target: int
    transform: np.ndarray
    fitness: float
    inlier_rmse_mm: float
    information: np.ndarray
    method: str
    accepted: bool
    alternatives: list = field(default_factory=list)
    conditioning: dict | None = None
    see_through: float = 0.0
    ir_yaw: dict | None = None

    def to_dict(self, names: list[str]) -> dict:
        d = {"source": names[self.source], "target": names[self.target], "fitness": round(self.fitness, 4),
             "inlier_rmse_mm": round(self.inlier_rmse_mm, 3), "method": self.method, "accepted": self.accepted,
             "see_through": round(self.see_through, 4),
             "alternatives": [{"fitness": round(a.fitness, 4), "inlier_rmse_mm": round(a.inlier_rmse_mm, 3),
                               "method": a.method} for a in self.alternatives]}
        if self.conditioning is not None:
            d["conditioning"] = self.conditioning
        if self.ir_yaw is not None:
            d["ir_yaw"] = self.ir_yaw
        return d

    def with_hypothesis(self, alt: PairResult) -> PairResult:
        """This edge with ``alt`` (one of :attr:`alternatives`) as its transform; the old one becomes an alternative."""
        rest = [a for a in self.alternatives if a is not alt]
        old = PairResult(self.source, self.target, self.transform, self.fitness, self.inlier_rmse_mm, self.information,
                         self.method, self.accepted, conditioning=self.conditioning, see_through=self.see_through,
                         ir_yaw=self.ir_yaw)
        return PairResult(self.source, self.target, alt.transform, alt.fitness, alt.inlier_rmse_mm, alt.information,
                          alt.method, alt.accepted, [old] + rest, alt.conditioning, alt.see_through, alt.ir_yaw)


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


def expected_visible(src: RegView, tgt: RegView, T: np.ndarray, max_incidence_deg: float = 65.0) -> np.ndarray:
    """Mask of the source object points the target camera could see under ``T``: in front of it,
    inside its image and facing it at an incidence below ``max_incidence_deg`` (self-occlusion is
    not tested). Without normals or intrinsics: the points inside the target's bounding box."""
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    if src.obj_normals is None or tgt.intr is None:
        lo, hi = tgt.icp_points.min(0), tgt.icp_points.max(0)
        return np.all((p >= lo) & (p <= hi), axis=1)
    n = src.obj_normals @ T[:3, :3].T
    z = p[:, 2]
    ok = z > 1e-3
    cos_inc = -np.einsum("ij,ij->i", n, p) / np.maximum(np.linalg.norm(p, axis=1), 1e-12)
    ok &= cos_inc > np.cos(np.radians(max_incidence_deg))
    uv = tgt.intr.project(np.where(ok[:, None], p, [0.0, 0.0, 1.0]))
    H, W = tgt.intr.shape
    ok &= (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
    return ok


def object_fitness(src: RegView, tgt: RegView, T: np.ndarray, radius_m: float) -> tuple[float, float]:
    """Share of the source object points the target camera could see (:func:`expected_visible`)
    that lie within ``radius_m`` of the target cloud, and the RMS distance of all matches [m].

    Normalising by what the target could see (not by all source points) keeps the fitness of a
    correct pose high where the views overlap only in part: a thin slab seen from its front by one
    view and from its edge by the next shares only the points both cameras face."""
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    d, _ = tgt.tree.query(p, distance_upper_bound=radius_m, workers=-1)
    ok = np.isfinite(d)
    if not ok.any():
        return 0.0, np.inf
    vis = expected_visible(src, tgt, T)
    return float((ok & vis).sum() / max(vis.sum(), 1)), float(np.sqrt(np.mean(d[ok] ** 2)))


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
    tol = cfg.see_through_tol_mm * 1e-3

    def key(c):  # hypotheses the other camera sees through rank last, then by fitness, then RMSE
        return (c[4] > cfg.max_see_through, -c[0], c[1])

    def vis(T):
        return visibility_violation(src, tgt, T, tol)

    cands = []
    if init is not None:
        T = _refine_mid(src, tgt, init, cfg)
        E = np.linalg.inv(init) @ T
        jump_deg = rotation_angle_deg(E)
        if global_search or (jump_deg <= cfg.max_loop_jump_deg and np.linalg.norm(E[:3, 3]) * 1e3 <= cfg.max_loop_jump_mm):
            T = _refine_fine(src, tgt, T, cfg)
            cands.append((*object_fitness(src, tgt, T, r_final), T, "init+icp", vis(T)))
    if global_search and (not cands or not _passes(cands[0][0], cands[0][1], cfg) or not plane_consistent(src, tgt, cands[0][2])
                          or cands[0][4] > cfg.max_see_through):
        def fpfh():
            return [(global_register(src.feat_points, src.feat_normals, tgt.feat_points, tgt.feat_normals,
                                     cfg.feature_voxel_mm * 1e-3, seed=cfg.seed + s).transform, "fpfh+icp")
                    for s in range(cfg.ransac_seeds)]

        def good(c):
            return _passes(c[0], c[1], cfg) and c[4] <= cfg.max_see_through and plane_consistent(src, tgt, c[2])

        if src.plane is not None and tgt.plane is not None:
            _search(src, tgt, cfg, [(T, "plane-yaw+icp") for T in yaw_candidates(src, tgt, cfg.yaw_step_deg)], cands, key, vis)
            # fallbacks when no yaw seed converged to an acceptable pose: shifted yaw seeds, then FPFH + RANSAC
            if not any(good(c) for c in cands):
                _search(src, tgt, cfg, [(T, "shifted-yaw+icp") for T in shifted_yaw_candidates(src, tgt, cfg.yaw_step_deg)],
                        cands, key, vis)
            if not any(good(c) for c in cands):
                _search(src, tgt, cfg, fpfh(), cands, key, vis)
        else:
            _search(src, tgt, cfg, fpfh(), cands, key, vis)
    if not cands:
        return PairResult(i, j, np.eye(4), 0.0, np.inf, np.zeros((6, 6)), "none", False)
    ranked = sorted(cands, key=lambda c: (not plane_consistent(src, tgt, c[2]), *key(c)))
    out = []
    for fit, rmse, T, method, v in ranked:
        ok = _passes(fit, rmse, cfg) and v <= cfg.max_see_through
        if out and not (ok and plane_consistent(src, tgt, T)):
            continue
        info = information_matrix(src.icp_points, tgt.icp_points, r_final, T)
        out.append(PairResult(i, j, T, fit, rmse * 1e3, info, method, ok,
                              conditioning=registration_conditioning(src, tgt, T, r_final), see_through=v))
    best = out[0]
    yr = (best.conditioning or {}).get("yaw_ratio")
    if cfg.ir_yaw and yr is not None and yr < cfg.yaw_free_ratio and src.obj_ir is not None and tgt.icp_ir is not None:
        # the geometry leaves the yaw free: let the painted pattern (IR amplitude) choose it
        sw = ir_yaw_sweep(src, tgt, best.transform, r_final)
        if sw["decided"]:
            T = _refine_fine(src, tgt, sw.pop("transform"), cfg)
            fit, rmse = object_fitness(src, tgt, T, r_final)
            v = vis(T)
            ok = _passes(fit, rmse, cfg) and v <= cfg.max_see_through
            best = PairResult(i, j, T, fit, rmse * 1e3, information_matrix(src.icp_points, tgt.icp_points, r_final, T),
                              best.method + "+ir-yaw", ok, conditioning=registration_conditioning(src, tgt, T, r_final),
                              see_through=v, ir_yaw=sw)
            return replace(best, alternatives=[a for a in out if not _same_pose(a.transform, T)])
        sw.pop("transform", None)
        best = replace(best, ir_yaw=sw)
    return replace(best, alternatives=out[1:])


def _search(src: RegView, tgt: RegView, cfg: RegistrationConfig, coarse: list, cands: list, key, vis) -> None:
    """Coarse hypotheses ``coarse`` [(T, how)] -> quick ICP -> distinct -> mid ICP -> fine ICP; appends
    (fitness, rmse, T, how, see_through) of the winner and of every other distinct hypothesis that
    passes the gates to ``cands``."""
    r_final = cfg.icp_radii_mm[-1] * 1e-3
    # quick ICP of every coarse candidate on the feature-voxel clouds, keep the best few
    quick = []
    for T0, how in coarse:
        T = T0
        for r in (2.5 * cfg.coarse_voxel_mm, 1.25 * cfg.coarse_voxel_mm):
            T = icp(src.coarse_points, tgt.coarse_points, tgt.coarse_normals, T, r * 1e-3, kernel=cfg.kernel,
                    max_iter=12).transform
        if plane_consistent(src, tgt, T, 5.0, 15.0):
            quick.append((*_coarse_fitness(src, tgt, T, 1.25 * cfg.coarse_voxel_mm * 1e-3), T, how, vis(T)))
    quick.sort(key=key)
    distinct: list = []  # several yaw seeds converge to the same pose: refine distinct ones only
    for c in quick:
        if all(not _same_pose(c[2], d[2]) for d in distinct):
            distinct.append(c)
    # coarse-to-fine: the distinct hypotheses are refined on the mid-voxel clouds and ranked;
    # the winner, and every other distinct one that passes the gates, get the last ICP stage
    mids = []
    for c in distinct[:cfg.refine_candidates]:
        T = _refine_mid(src, tgt, c[2], cfg)
        if plane_consistent(src, tgt, T):
            mids.append((*object_fitness(src, tgt, T, r_final), T, c[3], vis(T)))
    mids.sort(key=key)
    for k, (fit0, rm0, T, how, v0) in enumerate(mids):
        # alternatives are kept for the multi-view (loop consistency) selection
        if k > 0 and not (_passes(fit0, rm0, cfg) and v0 <= cfg.max_see_through
                          and all(not _same_pose(T, c[2]) for c in cands)):
            continue
        T = _refine_fine(src, tgt, T, cfg)
        if plane_consistent(src, tgt, T) and all(not _same_pose(T, c[2]) for c in cands):
            cands.append((*object_fitness(src, tgt, T, r_final), T, how, vis(T)))


def registration_conditioning(src: RegView, tgt: RegView, T: np.ndarray, radius_m: float,
                              normal_radius_m: float = 0.01) -> dict:
    """How well the overlap constrains the pose (point-to-plane, Gelfand et al. 2003).

    ``H = sum J^T J / N`` with rows ``J = [((p - c) x n) / L, n]`` over the target points matched by
    the source object points within ``radius_m`` (``c`` their centroid, ``L`` their RMS distance
    from it: rotations scaled to a displacement at the object's size). The normals ``n`` are
    re-estimated by PCA over ``normal_radius_m`` (10 mm): the per-pixel image normals are noisy
    enough to fill a null direction (measured: yaw ratio 0.17 with them against 0.01 with PCA
    normals on a surface of revolution).

    ``yaw_ratio``: the stiffness of the rotation about the support-plane normal through ``c``,
    the other five parameters left free (``1 / (u' H^-1 u)``), over the smaller stiffness of the
    two horizontal rotations. A surface of revolution standing on the plane leaves that yaw free:
    measured 0.01-0.06 on a vase where the overlap misses its handle, 0.28 where it holds it,
    0.9-2.7 on a bunny and a head. None without a support plane.

    Returns
    -------
    dict: ratio (smallest / largest eigenvalue), weak_rotation (share of the weakest direction in
    the rotation part), weak_axis (3,) rotation axis of the weakest direction (target frame),
    yaw_ratio (float or None), n_matched
    """
    from tofmetry.reconstruct._o3d import estimate_normals

    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    d, idx = tgt.tree.query(p, distance_upper_bound=radius_m, workers=-1)
    ok = np.isfinite(d)
    if ok.sum() < 30:
        return {"ratio": 0.0, "weak_rotation": 1.0, "weak_axis": [0.0, 0.0, 0.0], "yaw_ratio": None,
                "n_matched": int(ok.sum())}
    q = tgt.icp_points[np.unique(idx[ok])]
    n = estimate_normals(q, normal_radius_m, 60, toward=np.zeros(3))
    c = q.mean(0)
    L = float(np.sqrt(np.mean(np.sum((q - c) ** 2, 1))))
    J = np.c_[np.cross(q - c, n) / L, n]
    H = J.T @ J / len(J)
    w, V = np.linalg.eigh(H)
    v = V[:, 0]
    rot = float(np.sum(v[:3] ** 2))
    yaw = None
    if tgt.plane is not None:
        try:
            Hi = np.linalg.inv(H)
            up = tgt.plane[:3] / np.linalg.norm(tgt.plane[:3])
            a1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
            a1 /= np.linalg.norm(a1)
            a2 = np.cross(up, a1)

            def k(axis):
                e = np.r_[axis, 0.0, 0.0, 0.0]
                return 1.0 / float(e @ Hi @ e)

            yaw = round(k(up) / max(min(k(a1), k(a2)), 1e-300), 4)
        except np.linalg.LinAlgError:
            yaw = 0.0
    return {"ratio": float(w[0] / max(w[-1], 1e-300)), "weak_rotation": round(rot, 3),
            "weak_axis": [round(float(x), 3) for x in v[:3] / max(np.linalg.norm(v[:3]), 1e-12)],
            "yaw_ratio": yaw, "n_matched": int(ok.sum())}


def _same_pose(A: np.ndarray, B: np.ndarray, deg: float = 3.0, mm: float = 10.0) -> bool:
    E = np.linalg.inv(A) @ B
    return bool(rotation_angle_deg(E) <= deg and np.linalg.norm(E[:3, 3]) * 1e3 <= mm)


def rejection_reason(p: PairResult, cfg: RegistrationConfig) -> str:
    """Why a pair was not accepted (or "accepted"), in words, with the figures and the gates."""
    if p.accepted:
        return "accepted"
    if p.method == "none":
        return "no hypothesis converged (no overlap)"
    why = []
    if p.fitness < cfg.min_fitness:
        why.append(f"overlap {p.fitness:.2f} < {cfg.min_fitness:g}")
    if p.inlier_rmse_mm > cfg.max_rmse_mm:
        why.append(f"RMSE {p.inlier_rmse_mm:.1f} mm > {cfg.max_rmse_mm:g} mm")
    if p.see_through > cfg.max_see_through:
        why.append(f"the other camera sees through {p.see_through:.0%} of the matched object (> {cfg.max_see_through:.0%})")
    if "dropped" in p.method:
        why.append("dropped: contradicts the loops of the other views")
    return "rejected: " + ("; ".join(why) or "support planes disagree")


def _passes(fit: float, rmse_m: float, cfg: RegistrationConfig) -> bool:
    return fit >= cfg.min_fitness and rmse_m * 1e3 <= cfg.max_rmse_mm
