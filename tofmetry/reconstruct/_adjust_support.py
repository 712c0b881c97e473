"""The support plane is one plane: a term of the global adjustment that holds the views' tilts.

The object stands on a table (or a turntable's top) that every view sees around it. Each view's
support plane, fitted on thousands of its points (:func:`~tofmetry.reconstruct._segment.segment_object`),
is a measurement of that view's tilt and height: placed by the view's pose, all of them must be the
same plane. The object's points alone leave the tilts weakly held where the object is smooth or
round (a dome, a pebble: a small tilt of one view slides its points along the surface), and a
depth error common to the views pulls them there (measured with ``bench/robustness/drift.py``).

A view ``v`` with support plane ``(n_c, d_c)`` in its camera frame (``n . p + d = 0`` on the
plane) and camera-to-world pose ``(R, t)`` puts it at ``n = R n_c``, ``d = d_c - n . t`` in the
world. Under the adjustment's left increment ``(w, dt)`` (``T -> exp(w) T`` then ``+ dt``),
``n -> n + w x n`` and ``d -> d - n . dt`` (the rotation keeps ``n . t``). The term is, for every
pair of views, the difference of their planes: its two components across the common normal
[rad] and the difference of heights [m], each with standard deviation ``sqrt(V) sigma``: that is
every view tied to an unknown common plane with ``sigma``, the common plane marginalised out.

``sigma`` is not the plane fits' noise (a few thousandths of a degree) but how far one view's
plane can sit from another's: the depth calibration's residual over the table's part of the image,
a table that is not flat, a turntable that wobbles (:attr:`RegistrationConfig.support_plane_deg`,
``support_plane_mm``). A view whose plane lies more than :data:`OFF_PLANE_DEG` from the others' (placed
upside down, or a segmentation that took another plane) is left out of the term and named.

The planes also tell the run's verdict which part of the joint fit's move from the pose graph they
measured: the tilt (:func:`moved_about_vertical` splits off the turn about the vertical). Measured
(2026-11-30, family draws 48-49 with the term): the pose graph's planes lay up to 0.3-0.8 deg apart
on most runs and the joint fit took them to within 0.02-0.16 deg; its moves beyond the pose gate were
nearly all about the vertical (0.58 of 0.64 deg, 1.36 of 1.38 deg), which the planes cannot vouch for.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tofmetry._shared.geometry import skew

#: a view whose support plane lies farther than this from the others' [deg] is left out of the term
OFF_PLANE_DEG = 20.0


def world_planes(poses: np.ndarray, planes_cam: list[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The views' support planes placed in the world by their poses.

    Parameters
    ----------
    poses : (V, 4, 4) camera-to-world [m]
    planes_cam : per view (4,) ``(a, b, c, d)`` in the camera frame (unit normal, ``n . p + d = 0``
        on the plane [m]), or None where the view found none

    Returns
    -------
    (views, normals, heights): indices (K,) of the views with a plane, their world normals (K, 3)
    (each toward its camera, as the segmentation gives it: a view turned upside down shows), and
    ``d`` (K,) [m]
    """
    idx = [v for v, pl in enumerate(planes_cam) if pl is not None and np.all(np.isfinite(pl))]
    if not idx:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)
    n = np.array([poses[v][:3, :3] @ np.asarray(planes_cam[v][:3], np.float64) for v in idx])
    d = np.array([float(planes_cam[v][3]) for v in idx]) - np.einsum("ij,ij->i", n, poses[idx][:, :3, 3])
    return np.asarray(idx, np.int64), n, d


def common_normal(normals: np.ndarray, max_deg: float = OFF_PLANE_DEG) -> tuple[np.ndarray, np.ndarray]:
    """The views' common support-plane normal and which views agree with it.

    Parameters
    ----------
    normals : (K, 3) world normals of the views' planes (:func:`world_planes`)
    max_deg : a normal farther than this from the median direction is not the others' plane (a view
        placed upside down or far off, or a segmentation that took another plane)

    Returns
    -------
    (normal (3,), agree (K,) bool): the mean of the agreeing normals, normalised
    """
    med = np.median(normals, axis=0)
    med = med / (np.linalg.norm(med) or 1.0)
    agree = normals @ med >= np.cos(np.radians(max_deg))
    m = normals[agree].mean(0) if agree.any() else med
    return m / (np.linalg.norm(m) or 1.0), agree


def support_plane_terms(poses: np.ndarray, planes_cam: list[np.ndarray | None], sigma_rad: float, sigma_m: float,
                        weight: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """Gauss-Newton terms of the views' support planes being one plane (module docstring).

    Parameters
    ----------
    poses : (V, 4, 4) current camera-to-world poses [m] (view 0 held)
    planes_cam : per view (4,) support plane in the camera frame, or None
    sigma_rad : how far one view's plane normal can sit from the common one [rad]
    sigma_m : how far its height can [m]
    weight : the data's variance in the normal equations' units (``s2 * inflation^2`` [m^2]), so
        that the term weighs against the points as a prior does
        (:func:`~tofmetry.reconstruct._adjust_prior.pose_prior_terms`)

    Returns
    -------
    (H (6 (V - 1), 6 (V - 1)), b (6 (V - 1),), info): the term's normal matrix and gradient over the
    poses' increments (rotation vector [rad], translation [m]), and ``info``: ``n_views`` in the
    term, ``spread_deg`` and ``spread_mm`` (largest difference from the mean plane), ``off_plane``
    (views whose plane lies more than :data:`OFF_PLANE_DEG` from the others', left out)
    """
    V = len(poses)
    H = np.zeros((6 * (V - 1), 6 * (V - 1)))
    b = np.zeros(6 * (V - 1))
    idx, n, d, m, info = _one_plane(poses, planes_cam)
    K = len(idx)
    if K < 2:
        return H, b, info
    T = np.linalg.svd(m[None], full_matrices=True)[2][1:]  # (2, 3) across the common normal
    w_rot, w_off = weight / (K * sigma_rad ** 2), weight / (K * sigma_m ** 2)
    for a in range(K):
        for c in range(a + 1, K):
            va, vc = int(idx[a]), int(idx[c])
            J = np.zeros((3, 12))  # rows: 2 tilts, height; columns: (w, dt) of va, then of vc
            J[:2, 0:3] = -T @ skew(n[a])  # d(w x n) / dw = -[n]x
            J[:2, 6:9] = T @ skew(n[c])
            J[2, 3:6] = -n[a]
            J[2, 9:12] = n[c]
            r = np.r_[T @ (n[a] - n[c]), d[a] - d[c]]
            W = np.array([w_rot, w_rot, w_off])
            cols = np.r_[np.arange(6 * (va - 1), 6 * va) if va > 0 else np.full(6, -1),
                         np.arange(6 * (vc - 1), 6 * vc) if vc > 0 else np.full(6, -1)]
            keep = cols >= 0
            JW = J[:, keep] * W[:, None]
            cc = cols[keep]
            H[np.ix_(cc, cc)] += JW.T @ J[:, keep]
            b[cc] += JW.T @ r
    return H, b, info


def plane_spread(poses: np.ndarray, planes_cam: list[np.ndarray | None]) -> dict:
    """How far the views' support planes, placed by ``poses``, lie from one plane: the ``info`` of
    :func:`support_plane_terms` without its terms."""
    return _one_plane(poses, planes_cam)[-1]


def _one_plane(poses: np.ndarray, planes_cam: list[np.ndarray | None]):
    """The views' world planes that agree with the common one (:func:`common_normal`):
    ``(views, normals, heights, common normal or None, info)``, ``info`` as :func:`support_plane_terms` gives it."""
    idx, n, d = world_planes(poses, planes_cam)
    if len(idx) < 2:
        return idx, n, d, None, {"n_views": int(len(idx))}
    m, agree = common_normal(n)
    off = [int(v) for v in idx[~agree]]
    idx, n, d = idx[agree], n[agree], d[agree]
    if len(idx) < 2:
        return idx, n, d, m, {"n_views": int(len(idx))}
    ang = np.degrees(np.arccos(np.clip(n @ m, -1.0, 1.0)))
    return idx, n, d, m, {"n_views": int(len(idx)), "spread_deg": round(float(ang.max()), 4),
                          "spread_mm": round(float(np.abs(d - d.mean()).max()) * 1e3, 3), "off_plane": off}


def moved_about_vertical(start: np.ndarray, end: np.ndarray, planes_cam: list[np.ndarray | None]) -> np.ndarray | None:
    """Each view's move from ``start`` to ``end`` turned about the vertical: the part of the move
    its support plane cannot see (the tilt part is what the planes measure).

    Parameters
    ----------
    start, end : (V, 4, 4) camera-to-world poses [m]
    planes_cam : per view (4,) support plane in the camera frame, or None

    Returns
    -------
    (V,) |rotation about the common plane normal| of ``end_v start_v^-1`` [deg], or None with fewer
    than two planes
    """
    idx, n, _ = world_planes(end, planes_cam)
    if len(idx) < 2:
        return None
    up, _ = common_normal(n)
    out = np.zeros(len(end))
    for v in range(len(end)):
        M = end[v][:3, :3] @ start[v][:3, :3].T
        out[v] = abs(np.degrees(Rotation.from_matrix(M).as_rotvec()) @ up)
    return out
