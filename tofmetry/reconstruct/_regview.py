"""The registration's view of a prepared view (:class:`RegView`) and how a pose between two views is
scored: overlap (:func:`object_fitness`, normalised by what the target camera could see), free
space (:func:`free_space_violation`: a wrong pose makes one camera see through the other's
surface) and conditioning (:func:`registration_conditioning`: is the rotation about the vertical
determined by the overlap?).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import minimum_filter
from scipy.spatial import cKDTree

from tofmetry.reconstruct._amplitude import amplitude_log_ratio
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._o3d import estimate_normals, voxel_down, voxel_down_values
from tofmetry.reconstruct._photometric import log_albedo
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
    mid_ir : relative log IR albedo of ``mid_points``, or None without IR
    icp_amp, mid_amp : ``ln(A_white / A)`` of ``icp_points`` / ``mid_points`` (the amplitude-bias
        regressor, :func:`~tofmetry.reconstruct._amplitude.amplitude_log_ratio`), or None without
        IR and an amplitude reference
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
    icp_amp: np.ndarray | None = None
    mid_amp: np.ndarray | None = None
    mid_ir: np.ndarray | None = None
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
    amp = None
    if white_map is not None and view.ir is not None and intr is not None:
        amp = amplitude_log_ratio(view.depth_mm, view.ir, white_map, intr).ravel()[view.index]
    vals = np.stack([np.zeros(len(view.points)) if alb is None else alb, amp], axis=1) if amp is not None else alb
    p, n, p_vals = voxel_down_values(view.points[sel], view.normals[sel], None if vals is None else vals[sel],
                                     cfg.icp_voxel_mm * 1e-3)
    p_ir, p_amp = (p_vals[:, 0] if alb is not None else None, p_vals[:, 1]) if amp is not None else (p_vals, None)
    om = seg.object_mask & reliable
    po, pon, po_ir = voxel_down_values(view.points[om], view.normals[om], None if alb is None else alb[om],
                                       cfg.icp_voxel_mm * 1e-3)
    pf, nf = voxel_down(view.points[core], view.normals[core], cfg.feature_voxel_mm * 1e-3)
    csel = (core & reliable) | ring
    pc, nc = voxel_down(view.points[csel], view.normals[csel], cfg.coarse_voxel_mm * 1e-3)
    pm, nm, pm_vals = voxel_down_values(view.points[sel], view.normals[sel], None if vals is None else vals[sel],
                                        cfg.mid_voxel_mm * 1e-3)
    pm_ir, pm_amp = (pm_vals[:, 0] if alb is not None else None, pm_vals[:, 1]) if amp is not None else (pm_vals, None)
    near = None
    if intr is not None:
        d = np.where(view.depth_mm > 0, view.depth_mm * 1e-3, np.inf).astype(np.float32)
        near = minimum_filter(d, size=3, mode="nearest")
    return RegView(view.name, p, n, po, pf, nf, pc, nc, seg.plane, pm, nm, near, intr, pon, po_ir, p_ir, p_amp, pm_amp,
                   pm_ir)


def free_space_violation(src: RegView, tgt: RegView, T: np.ndarray, tol_m: float,
                         max_incidence_deg: float = 65.0) -> float:
    """Share of the source object points that, mapped by ``T`` into the target camera, lie more than
    ``tol_m`` in front of everything the target camera observed around that pixel (3x3): space the
    target saw through. A correct pose leaves only noise there; a near-symmetric false match puts
    surface where the other camera saw the background (visibility consistency). 0 when the target
    has no depth image; points outside its image or over invalid pixels are not counted.

    Only the points the target would face at an incidence below ``max_incidence_deg`` are tested
    (with the source's normals): a surface the source sees frontally and the target at its limb
    crowds into the target's silhouette band, whose pixels are mixed with the background behind or
    removed as flying pixels. Counted there, a correct pose of a rounded object read 0.13-0.17 on a
    vase at 0.7 m (60-80 degrees between the views), beyond the gate; with the limb left out 0.01-0.04.
    """
    if tgt.near_depth_m is None or tgt.intr is None:
        return 0.0
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    front = p[:, 2] > 1e-3
    if src.obj_normals is not None:
        front &= _faces_camera(src.obj_normals @ T[:3, :3].T, p, max_incidence_deg)
    p = p[front]
    if len(p) == 0:
        return 0.0
    d = _observed_depth(tgt, p)
    known = np.isfinite(d)
    if not known.any():
        return 0.0
    return float(np.sum(p[known, 2] < d[known] - tol_m) / known.sum())


def _faces_camera(normals: np.ndarray, points: np.ndarray, max_incidence_deg: float) -> np.ndarray:
    """Mask of ``points`` ((N, 3) camera frame [m]) whose unit ``normals`` (same frame) face the
    camera at an incidence below ``max_incidence_deg``."""
    cos_inc = -np.einsum("ij,ij->i", normals, points) / np.maximum(np.linalg.norm(points, axis=1), 1e-12)
    return cos_inc > np.cos(np.radians(max_incidence_deg))


def visibility_violation(src: RegView, tgt: RegView, T: np.ndarray, tol_m: float) -> float:
    """:func:`free_space_violation` both ways (source into target, target into source): the larger."""
    return max(free_space_violation(src, tgt, T, tol_m), free_space_violation(tgt, src, np.linalg.inv(T), tol_m))


def expected_visible(src: RegView, tgt: RegView, T: np.ndarray, max_incidence_deg: float = 65.0) -> np.ndarray:
    """Mask of the source object points the target camera could see under ``T``: in front of it,
    inside its image and facing it at an incidence below ``max_incidence_deg`` (self-occlusion is
    not tested). Without normals or intrinsics: the points inside the target's bounding box."""
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    if src.obj_normals is None or tgt.intr is None:
        lo, hi = tgt.icp_points.min(0), tgt.icp_points.max(0)
        return np.all((p >= lo) & (p <= hi), axis=1)
    ok = (p[:, 2] > 1e-3) & _faces_camera(src.obj_normals @ T[:3, :3].T, p, max_incidence_deg)
    uv = tgt.intr.project(np.where(ok[:, None], p, [0.0, 0.0, 1.0]))
    H, W = tgt.intr.shape
    ok &= (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
    return ok


def seen_by(points: np.ndarray, normals: np.ndarray, tgt: RegView, T: np.ndarray, tol_m: float,
            max_incidence_deg: float = 65.0) -> np.ndarray:
    """Mask of ``points`` ((N, 3) source camera frame [m], unit ``normals`` (N, 3)) that the target
    camera observed under ``T`` (source -> target, (4, 4)): in front of it, facing it at an incidence
    below ``max_incidence_deg``, inside its image, and within ``tol_m`` of the nearest depth it
    observed around that pixel (:attr:`RegView.near_depth_m`, 3x3), so neither hidden behind a nearer
    surface nor in space it saw through. All True without the target's depth image."""
    if tgt.near_depth_m is None or tgt.intr is None:
        return np.ones(len(points), bool)
    p = points @ T[:3, :3].T + T[:3, 3]
    ok = (p[:, 2] > 1e-3) & _faces_camera(normals @ T[:3, :3].T, p, max_incidence_deg)
    d = np.full(len(p), np.inf)
    d[ok] = _observed_depth(tgt, p[ok])
    return ok & (np.abs(p[:, 2] - d) <= tol_m)


def _observed_depth(tgt: RegView, p: np.ndarray) -> np.ndarray:
    """(N,) the nearest depth [m] the target camera observed around the pixel of each point ``p``
    ((N, 3) in front of it, target frame [m]); inf outside its image or over invalid pixels."""
    with np.errstate(all="ignore"):  # far outside the image the lens model overflows: not observed
        uv = tgt.intr.project(p) if len(p) else np.zeros((0, 2))
    ok = np.isfinite(uv).all(axis=1)
    uv = np.rint(np.where(ok[:, None], uv, -1.0)).astype(np.int64)
    H, W = tgt.near_depth_m.shape
    ok &= (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    d = np.full(len(p), np.inf)
    d[ok] = tgt.near_depth_m[uv[ok, 1], uv[ok, 0]]
    return d


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


def overlap_jacobian(src: RegView, tgt: RegView, T: np.ndarray, radius_m: float, min_matched: int = 30,
                     normal_radius_m: float = 0.01) -> tuple[np.ndarray | None, int]:
    """(M, 6) point-to-plane Jacobian of the overlap at ``T`` (source -> target, (4, 4) [m]): rows
    ``[((q - c) x n) / L, n]`` over the target points ``q`` matched by the source object points within
    ``radius_m`` (``c`` their centroid, ``L`` their RMS distance from it, so that the rotation columns
    are displacements at the object's size), ``n`` their normals by PCA over ``normal_radius_m`` (see
    :func:`registration_conditioning`); None where fewer than ``min_matched`` points match. With it,
    the number of source points matched."""
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    d, idx = tgt.tree.query(p, distance_upper_bound=radius_m, workers=-1)
    ok = np.isfinite(d)
    if ok.sum() < min_matched:
        return None, int(ok.sum())
    q = tgt.icp_points[np.unique(idx[ok])]
    n = estimate_normals(q, normal_radius_m, 60, toward=np.zeros(3))
    return point_to_plane_rows(q, n), int(ok.sum())


def point_to_plane_rows(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(M, 6) point-to-plane Jacobian rows ``[((q - c) x n) / L, n]`` of surface points ``q`` [m] with
    unit normals ``n`` (``c`` their centroid, ``L`` their RMS distance from it: the rotation columns
    are displacements at the surface's size, comparable with the translation columns)."""
    q, n = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    c = q.mean(0)
    L = float(np.sqrt(np.mean(np.sum((q - c) ** 2, 1))))
    return np.c_[np.cross(q - c, n) / max(L, 1e-12), n]


def constrained_stiffness(H: np.ndarray, motions: np.ndarray) -> np.ndarray:
    """The stiffness of each of ``motions`` (K, 6) (rotation, translation, as the columns of
    :func:`point_to_plane_rows`) with every other motion left free: ``1 / (e' H^-1 e)`` for the
    (6, 6) normal matrix ``H``. Raises ``numpy.linalg.LinAlgError`` where ``H`` is singular."""
    Hi = np.linalg.inv(H)
    E = np.asarray(motions, np.float64)
    return 1.0 / np.einsum("ki,ij,kj->k", E, Hi, E)


def yaw_stiffness_ratio(H: np.ndarray, up: np.ndarray) -> float:
    """The stiffness of the rotation about ``up`` through the surface's centroid, the other five
    parameters left free (:func:`constrained_stiffness`), over the smaller stiffness of the two
    rotations about horizontal axes; ``H`` (6, 6) the normal matrix of :func:`point_to_plane_rows`.
    Near 0 on a surface of revolution about ``up`` (the turn about it is free); 0.0 where ``H`` is
    singular."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    a1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    a1 /= np.linalg.norm(a1)
    a2 = np.cross(up, a1)
    try:
        k = constrained_stiffness(H, np.c_[np.stack([up, a1, a2]), np.zeros((3, 3))])
    except np.linalg.LinAlgError:
        return 0.0
    return round(float(k[0]) / max(float(min(k[1], k[2])), 1e-300), 4)


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
    J, n_matched = overlap_jacobian(src, tgt, T, radius_m, 30, normal_radius_m)
    if J is None:
        return {"ratio": 0.0, "weak_rotation": 1.0, "weak_axis": [0.0, 0.0, 0.0], "yaw_ratio": None,
                "n_matched": n_matched}
    H = J.T @ J / len(J)
    w, V = np.linalg.eigh(H)
    v = V[:, 0]
    rot = float(np.sum(v[:3] ** 2))
    yaw = None if tgt.plane is None else yaw_stiffness_ratio(H, tgt.plane[:3])
    return {"ratio": float(w[0] / max(w[-1], 1e-300)), "weak_rotation": round(rot, 3),
            "weak_axis": [round(float(x), 3) for x in v[:3] / max(np.linalg.norm(v[:3]), 1e-12)],
            "yaw_ratio": yaw, "n_matched": n_matched}


def passes_gates(fit: float, rmse_m: float, cfg: RegistrationConfig) -> bool:
    """A pairwise hypothesis's fitness and RMSE [m] against the registration's gates (``cfg.min_fitness``,
    ``cfg.max_rmse_mm``)."""
    return fit >= cfg.min_fitness and rmse_m * 1e3 <= cfg.max_rmse_mm


def leaves_yaw_free(conditioning: dict | None, ratio: float) -> bool:
    """Whether a registration's overlap leaves the turn about the vertical free: its
    :func:`registration_conditioning` ``yaw_ratio`` is known and below ``ratio``."""
    yr = (conditioning or {}).get("yaw_ratio")
    return yr is not None and yr < ratio
