"""The ICP stages of a pair's registration: the wide stages on the mid-voxel clouds, the last one
on the full ICP clouds, and the yaw hops that look for a better minimum of the last stage nearby.

Poses are (4, 4) source camera -> target camera [m]; the clouds are a
:class:`~tofmetry.reconstruct._regview.RegView`'s (camera frame, x right, y down, z forward).
"""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._o3d import icp
from tofmetry.reconstruct._regview import RegView, object_fitness, seen_by


def plane_frame(plane: np.ndarray, obj: np.ndarray) -> np.ndarray:
    """4x4 frame: origin = object centroid projected on the plane, z = plane normal (up)."""
    n = plane[:3]
    c = obj.mean(0)
    o = c - (n @ c + plane[3]) * n
    x = np.array([1.0, 0, 0]) - n[0] * n
    x /= np.linalg.norm(x)
    F = np.eye(4)
    F[:3, 0], F[:3, 1], F[:3, 2], F[:3, 3] = x, np.cross(n, x), n, o
    return F


def yaw_in_frame(a_rad: float) -> np.ndarray:
    """(4, 4) rotation by ``a_rad`` about the z axis of a :func:`plane_frame` (the support plane's normal)."""
    Rz = np.eye(4)
    Rz[:2, :2] = [[np.cos(a_rad), -np.sin(a_rad)], [np.sin(a_rad), np.cos(a_rad)]]
    return Rz


def stage_icp(sp: np.ndarray, sn: np.ndarray, tp: np.ndarray, tn: np.ndarray, tgt: RegView, init: np.ndarray,
              radius_m: float, cfg: RegistrationConfig, max_iter: int) -> np.ndarray:
    """One ICP stage: source points ``sp`` (normals ``sn``) onto the target's ``tp`` (normals ``tn``)
    from ``init`` with correspondences within ``radius_m``; (4, 4) source -> target [m].

    With ``cfg.icp_seen_only`` only the source points the target camera observed at the current
    pose (:func:`~tofmetry.reconstruct._regview.seen_by`, within ``max(cfg.icp_seen_tol_mm,
    radius)``) are matched, the mask recomputed every ``cfg.icp_seen_every`` iterations. A source
    point the target did not see has no partner there, and its nearest target point lies on
    whatever the target saw nearby: on a view that sees a thin or smooth object edge-on those pull
    the pose one way (measured from the true pose on edge-on pairs of a plaque: +8.2 and +5.6 deg
    of yaw with every point, -0.9 and -0.5 deg with the seen ones). Falls back on every point where
    fewer than a tenth (or 30) are seen."""
    if not cfg.icp_seen_only:
        return icp(sp, tp, tn, init, radius_m, kernel=cfg.kernel, max_iter=max_iter).transform
    T, done = init, 0
    tol = max(cfg.icp_seen_tol_mm * 1e-3, radius_m)
    while done < max_iter:
        m = seen_by(sp, sn, tgt, T, tol)
        if m.sum() < max(30, len(sp) // 10):
            m = np.ones(len(sp), bool)
        n = min(cfg.icp_seen_every, max_iter - done)
        T1 = icp(sp[m], tp, tn, T, radius_m, kernel=cfg.kernel, max_iter=n).transform
        done += n
        step = np.linalg.inv(T) @ T1
        T = T1
        if rotation_angle_deg(step) < 1e-4 and np.linalg.norm(step[:3, 3]) < 1e-6:
            break
    return T


def refine_mid(src: RegView, tgt: RegView, init: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """All ICP stages but the last, on the mid-voxel clouds (cheap; within ~1 mm of the fine result)."""
    T = init
    sp, sn, tp, tn = ((src.mid_points, src.mid_normals, tgt.mid_points, tgt.mid_normals) if src.mid_points is not None
                      else (src.icp_points, src.icp_normals, tgt.icp_points, tgt.icp_normals))
    for r in cfg.icp_radii_mm[:-1]:
        T = stage_icp(sp, sn, tp, tn, tgt, T, r * 1e-3, cfg, cfg.icp_max_iter)
    return T


def refine_fine(src: RegView, tgt: RegView, init: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """The last (narrowest) ICP stage on the full ICP clouds."""
    return stage_icp(src.icp_points, src.icp_normals, tgt.icp_points, tgt.icp_normals, tgt, init,
                     cfg.icp_radii_mm[-1] * 1e-3, cfg, cfg.fine_max_iter)


def refine_pair(src: RegView, tgt: RegView, init: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """The pair's ICP from ``init`` (every stage: the mid-voxel ones, then the fine one), as the
    registration refines a pair from an initial pose. (4, 4) source camera -> target camera [m]."""
    return refine_fine(src, tgt, refine_mid(src, tgt, init, cfg), cfg)


def yaw_hops(src: RegView, tgt: RegView, T: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """``T`` (source -> target, (4, 4) [m]) after the hops of ``cfg.yaw_hops_deg``: the last ICP stage
    from ``T`` turned about the target's support-plane normal through its object centre, kept where
    it matches a larger share of the object points (:func:`object_fitness` at the last ICP radius)
    by more than ``cfg.yaw_hop_min_gain`` and still within the largest hop of ``T`` (the hops look
    for a better minimum nearby, not for another hypothesis); repeated from the new pose. Without
    a support plane or hops, ``T`` itself."""
    if not cfg.yaw_hops_deg or tgt.plane is None or src.plane is None:
        return T
    r_final = cfg.icp_radii_mm[-1] * 1e-3
    F = plane_frame(tgt.plane, tgt.obj_points)
    Fi = np.linalg.inv(F)
    T0, reach = T, cfg.yaw_hop_reach_deg or max(abs(a) for a in cfg.yaw_hops_deg)
    fit = object_fitness(src, tgt, T, r_final)[0]
    for _ in range(cfg.yaw_hop_rounds):
        best = None
        for a in np.radians(cfg.yaw_hops_deg):
            T1 = refine_fine(src, tgt, F @ yaw_in_frame(a) @ Fi @ T, cfg)
            f1 = object_fitness(src, tgt, T1, r_final)[0]
            if (f1 > fit + cfg.yaw_hop_min_gain and (best is None or f1 > best[0])
                    and rotation_angle_deg(np.linalg.inv(T0) @ T1) <= reach):
                best = (f1, T1)
        if best is None:
            break
        fit, T = best
    return T
