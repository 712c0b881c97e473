"""The IR amplitude where the geometry leaves a rotation free (study §6.3: more than geometry).

A surface of revolution matches itself at any rotation about its axis: two views of a vase
register equally well at every yaw (:func:`~tofmetry.reconstruct.registration_conditioning` measures
it). A ToF camera also measures the amplitude of the returned light, and a painted or printed
pattern shows in it. Per point, the amplitude ``A`` falls with the range ``r`` as ``1 / r^2`` and
with the incidence as ``cos``: ``log A + 2 log r - log cos`` (minus the log of the white-wall
amplitude reference at that pixel, which removes the vignetting, when one is given) is the log
albedo up to a constant per view (:func:`log_albedo`); its median over the object is removed.

:func:`ir_yaw_sweep` turns the source about the surface's axis of revolution (fitted to the matched
points: every normal of a surface of revolution meets its axis, :func:`revolution_axis`) in 5 deg
steps over the full turn, then 1 deg steps about the best, and scores each yaw by the correlation
of the matched points' log albedos. The geometry does not change along the sweep (that is what
"yaw free" means), so no ICP is needed inside it. The yaw is *decided* when the best correlation
reaches ``min_corr`` and beats every yaw more than ``exclusion_deg`` away by ``min_margin``; a
plain object (no pattern) or a pattern repeating round the axis leaves it undecided, and the edge
stays flagged.

SIFT keypoints on the amplitude image were tried first and dropped: at 1 m a 3-8 cm paint blob is
10-30 px wide, and the blobs look alike; the putative matches of 8 views of a painted vase held
0-2 true ones per pair (measured).
"""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import skew
from tofmetry.errors import EstimationError
from tofmetry.reconstruct._o3d import colored_icp
from tofmetry.sensor import CameraIntrinsics


def log_albedo(view, intr: CameraIntrinsics, white_map: np.ndarray | None = None) -> np.ndarray:
    """Relative log IR albedo of each point of a prepared view (module docstring).

    Parameters
    ----------
    view : ViewData (points, index, cos_incidence, ir)
    intr : its intrinsics; white_map : optional (H, W) white amplitude at 1 m

    Returns
    -------
    (N,) float64, 0 at the view's median; 0 where the amplitude is not positive
    """
    ir = np.asarray(view.ir, np.float64).ravel()[view.index]
    r = np.linalg.norm(view.points, axis=1)
    ok = (ir > 0) & (r > 0)
    la = np.zeros(len(ir))
    la[ok] = np.log(ir[ok]) + 2.0 * np.log(r[ok]) - np.log(np.maximum(view.cos_incidence[ok], 0.2))
    if white_map is not None:
        w = np.asarray(white_map, np.float64).ravel()[view.index]
        good = ok & np.isfinite(w) & (w > 0)
        la[good] -= np.log(w[good])
    if ok.any():
        la[ok] -= np.median(la[ok])
    return la


def revolution_axis(points: np.ndarray, normals: np.ndarray, up: np.ndarray) -> np.ndarray:
    """A point of the axis of revolution parallel to ``up`` that the normal lines of ``points`` meet
    best (least squares in the plane perpendicular to ``up``, weighted by the normals' horizontal part)."""
    up = up / np.linalg.norm(up)
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    p2 = np.c_[points @ e1, points @ e2]
    n2 = np.c_[normals @ e1, normals @ e2]
    w = np.linalg.norm(n2, axis=1)
    ok = w > 0.3
    if ok.sum() < 10:
        return points.mean(0)
    n2 = n2[ok] / w[ok, None]
    perp = np.c_[-n2[:, 1], n2[:, 0]]  # the axis a lies on the normal line: perp . (a - p) = 0
    A = perp * w[ok, None]
    b = np.einsum("ij,ij->i", perp, p2[ok]) * w[ok]
    a2, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = points.mean(0)
    return a2[0] * e1 + a2[1] * e2 + (c @ up) * up


def _rot_about(axis_pt: np.ndarray, up: np.ndarray, deg: float) -> np.ndarray:
    a = np.radians(deg)
    u = up / np.linalg.norm(up)
    K = skew(u)
    R = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, axis_pt - R @ axis_pt
    return T


def ir_yaw_sweep(src, tgt, T: np.ndarray, radius_m: float, min_corr: float = 0.5, min_margin: float = 0.2,
                 exclusion_deg: float = 15.0, min_points: int = 200, lobe_tol: float = 0.02) -> dict:
    """Choose the yaw of a yaw-free registration by the IR albedo (module docstring).

    Parameters
    ----------
    src, tgt : RegView with ``obj_ir`` / ``icp_ir`` (source object points, target cloud)
    T : (4, 4) the geometric hypothesis, source -> target
    radius_m : matching radius of the points compared
    lobe_tol : rise in correlation that ends the best yaw's lobe (:func:`peak_lobe`)

    Returns
    -------
    dict: decided (bool), correlation (best), margin (over the best yaw beyond ``exclusion_deg``
    and outside the best yaw's own lobe: paint blobs a few centimetres wide on a vase a few
    centimetres in radius make the correlation fall over tens of degrees, and its slope is not a
    rival yaw; measured on a painted vase seen from 6 views, the right yaw at correlation 0.95 was
    left undecided by its own flank 22 deg away at 0.73),
    yaw_deg (the turn applied to ``T``), n (matched points), axis (point of the axis, target frame),
    transform ((4, 4), the turned hypothesis; only when decided), reason; when undecided between two
    yaws that both reach ``min_corr``: rival_deg, rival_correlation and candidates (the two turned
    hypotheses, best first), for the views' loops to choose from
    (:func:`~tofmetry.reconstruct._loops.select_hypotheses`)
    """
    up = tgt.plane[:3] / np.linalg.norm(tgt.plane[:3])
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    d, idx = tgt.tree.query(p, distance_upper_bound=radius_m, workers=-1)
    ok = np.isfinite(d)
    if ok.sum() < min_points:
        return {"decided": False, "correlation": 0.0, "margin": 0.0, "yaw_deg": 0.0, "n": int(ok.sum()),
                "reason": "too few matched points"}
    q = tgt.icp_points[idx[ok]]
    axis = revolution_axis(q, tgt.icp_normals[idx[ok]], up)

    def score(deg):
        R = _rot_about(axis, up, deg)
        pp = p @ R[:3, :3].T + R[:3, 3]
        dd, ii = tgt.tree.query(pp, distance_upper_bound=radius_m, workers=-1)
        m = np.isfinite(dd)
        if m.sum() < min_points:
            return -1.0, int(m.sum())
        a, b = src.obj_ir[m], tgt.icp_ir[ii[m]]
        if a.std() < 1e-6 or b.std() < 1e-6:
            return 0.0, int(m.sum())
        return float(np.corrcoef(a, b)[0, 1]), int(m.sum())

    coarse = np.arange(-180.0, 180.0, 5.0)
    sc = np.array([score(x)[0] for x in coarse])
    k = int(np.argmax(sc))
    fine = coarse[k] + np.arange(-4.0, 4.5, 1.0)
    fs = np.array([score(x)[0] for x in fine])
    best_deg, best = float(fine[np.argmax(fs)]), float(fs.max())
    lobe = peak_lobe(sc, k, lobe_tol)
    far = (np.abs((coarse - best_deg + 180.0) % 360.0 - 180.0) > exclusion_deg) & ~lobe
    second = float(sc[far].max()) if far.any() else -1.0
    n = score(best_deg)[1]
    decided = best >= min_corr and best - second >= min_margin
    out = {"decided": bool(decided), "correlation": round(best, 4), "margin": round(best - second, 4),
           "yaw_deg": round(best_deg, 2), "n": n, "axis": [round(float(x), 5) for x in axis],
           "reason": ("the albedo pattern decides the yaw" if decided else
                      f"no yaw stands out (best correlation {best:.2f}, next {second:.2f})")}
    if decided:
        out["transform"] = _rot_about(axis, up, best_deg) @ T
    elif best >= min_corr and far.any() and second >= min_corr:
        # two yaws line the pattern up: both are hypotheses, the views' loops may tell them apart
        kk = int(np.flatnonzero(far)[np.argmax(sc[far])])
        fine2 = coarse[kk] + np.arange(-4.0, 4.5, 1.0)
        fs2 = np.array([score(x)[0] for x in fine2])
        rival = float(fine2[np.argmax(fs2)])
        out["rival_deg"], out["rival_correlation"] = round(rival, 2), round(float(fs2.max()), 4)
        out["candidates"] = [_rot_about(axis, up, best_deg) @ T, _rot_about(axis, up, rival) @ T]
    return out


def peak_lobe(scores: np.ndarray, best: int, tol: float = 0.02) -> np.ndarray:
    """The samples of a circular score curve that belong to the peak at index ``best``.

    From the peak, each side is followed while the score stays at most ``tol`` above the lowest
    score met so far on that side (a slope down, noise allowed); the first sample rising more
    belongs to another peak. Invalid samples (below -0.99, too few matched points) end a side.

    Parameters
    ----------
    scores : (K,) scores on a full turn, equally spaced; best : index of the highest
    tol : rise that ends the lobe (in score units)

    Returns
    -------
    (K,) bool, True on the lobe (the peak included)
    """
    sc = np.asarray(scores, np.float64)
    n = len(sc)
    lobe = np.zeros(n, bool)
    lobe[best] = True
    for step in (1, -1):
        low = sc[best]
        for m in range(1, n):
            k = (best + step * m) % n
            if lobe[k] or sc[k] < -0.99 or sc[k] > low + tol:
                break
            lobe[k] = True
            low = min(low, sc[k])
    return lobe


def albedo_intensity(log_alb: np.ndarray) -> np.ndarray:
    """Relative log albedo (:func:`log_albedo`) -> an intensity in [0, 1] for the photometric ICP
    (0.5 at the view's median; the two paints of a painted object, a factor 3 apart, 0.27 apart)."""
    return np.clip(0.5 + 0.25 * np.asarray(log_alb, np.float64), 0.0, 1.0)


def photometric_icp(src, tgt, T: np.ndarray, radii_m: tuple[float, ...], lambda_geometric: float = 0.968) -> np.ndarray:
    """Refine a registration with the IR albedo as a photometric term (:func:`~tofmetry.reconstruct._o3d.colored_icp`).

    Where the geometry leaves a slide free (a bar of constant section, a cylinder), a painted or
    printed pattern still fixes it. The caller keeps the result only where it matches more of the
    object (:func:`~tofmetry.reconstruct._regview.object_fitness`) than the geometric one: on a plain
    object the intensity carries nothing but noise and reflections.

    Parameters
    ----------
    src, tgt : RegView with ``icp_ir`` (source and target ICP clouds, target normals)
    T : (4, 4) the geometric registration, source -> target
    radii_m : correspondence radii, coarse to fine [m]

    Returns
    -------
    (4, 4) refined source -> target transform, or None when an iteration left no source point within
    the radius of the target (the refinement failed; the caller keeps ``T``)
    """
    a, b = albedo_intensity(src.icp_ir), albedo_intensity(tgt.icp_ir)
    try:
        for r in radii_m:
            T = colored_icp(src.icp_points, a, tgt.icp_points, tgt.icp_normals, b, T, r, lambda_geometric).transform
    except EstimationError:
        return None
    return T


def ir_agreement(src, tgt, T: np.ndarray, radius_m: float, min_points: int = 200) -> float | None:
    """Correlation of the relative log IR albedo of the source object points and the target points
    they match under ``T`` (within ``radius_m``): near 1 where a painted pattern lines up, near 0
    on a plain object or a wrong pose. None without IR, with fewer than ``min_points`` matches or
    with no albedo contrast (nothing to compare)."""
    if src.obj_ir is None or tgt.icp_ir is None:
        return None
    p = src.obj_points @ T[:3, :3].T + T[:3, 3]
    d, idx = tgt.tree.query(p, distance_upper_bound=radius_m, workers=-1)
    ok = np.isfinite(d)
    if ok.sum() < min_points:
        return None
    a, b = src.obj_ir[ok], tgt.icp_ir[idx[ok]]
    if a.std() < 1e-6 or b.std() < 1e-6:
        return None
    return float(np.corrcoef(a, b)[0, 1])

