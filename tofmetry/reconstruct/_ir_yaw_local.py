"""The turn about the support normal that a smooth painted object leaves to its pattern.

Why: on a smooth object (a pebble, a dome) the geometry pins two views' relative pose only to
within several degrees about the vertical, and the calibration's residual biases where in that
range the ICP ends. Measured on a painted pebble of the object family (seed 1698206712, 11
turntable views; the support planes put on each other and the yaw swept about the plane normal in
1 deg steps, the shift along the plane fitted at each): the fitness stayed within 0.01-0.02 of its
best over 10 deg, and the pairwise registration kept poses 3.3-9.1 deg off. The relative IR
albedo of the matched points (:func:`~tofmetry.reconstruct._photometric.ir_agreement`) peaked
within 0.8 deg of the truth on each pair swept (correlation 0.29-0.63 there, 0.17-0.33 at the
kept poses). The photometric ICP started near those poses slid 5-38 deg away (on another painted
pebble, 918864800), so no photometric ICP is run here: the geometry fits the shift at each yaw,
the pattern picks the yaw.

:func:`plane_yaw_icp` is the point-to-plane ICP with the support planes held on each other: it
moves only the yaw about the plane normal and the shift along the plane (or the shift alone).
:func:`yaw_sweep_near` turns a pose's yaw over a range and fits the shift at each yaw;
:func:`pattern_yaw` picks the yaw there, where the geometry leaves it loose.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._icp_stages import plane_frame, refine_fine, yaw_in_frame
from tofmetry.reconstruct._photometric import ir_agreement
from tofmetry.reconstruct._regview import RegView, object_fitness, passes_gates


def plane_yaw_icp(a: np.ndarray, b: np.ndarray, bn: np.ndarray, tree: cKDTree, yaw: float, shift: np.ndarray,
                  radius_m: float, max_iter: int = 30, fix_yaw: bool = False) -> tuple[float, np.ndarray, int]:
    """Point-to-plane ICP in the yaw about z and the shift in x, y only (3 degrees of freedom; the
    shift only, 2, with ``fix_yaw``).

    Parameters
    ----------
    a : (N, 3) source points in the source's support-plane frame (z up, on the plane) [m]
    b, bn : (M, 3) target points and unit normals in the target's support-plane frame [m]
    tree : cKDTree of ``b``
    yaw : initial rotation about z [rad]; shift : (2,) initial x, y shift [m]
    radius_m : correspondence radius [m]

    Returns
    -------
    yaw [rad], shift (2,) [m], number of matched points at the end (0 when fewer than 30 matched)
    """
    shift = np.asarray(shift, np.float64).copy()
    n_ok = 0
    for _ in range(max_iter):
        c, s = np.cos(yaw), np.sin(yaw)
        p = a @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
        p[:, :2] += shift
        d, idx = tree.query(p, distance_upper_bound=radius_m)  # one thread: a few thousand points, called often
        ok = np.isfinite(d)
        n_ok = int(ok.sum())
        if n_ok < 30:
            return yaw, shift, 0
        n, pp = bn[idx[ok]], p[ok]
        r = np.einsum("ij,ij->i", n, pp - b[idx[ok]])
        J = np.c_[n[:, 1] * pp[:, 0] - n[:, 0] * pp[:, 1], n[:, 0], n[:, 1]]
        w = 1.0 / np.maximum(1.0, np.abs(r) / (radius_m / 3.0))  # Huber at a third of the radius
        if fix_yaw:
            J[:, 0] = 0.0
        H = (J * w[:, None]).T @ J + 1e-12 * np.eye(3)
        if fix_yaw:
            H[0, 0] = 1.0
        step = -np.linalg.solve(H, (J * w[:, None]).T @ r)
        yaw += step[0]
        shift += step[1:]
        if abs(step[0]) < 1e-5 and np.linalg.norm(step[1:]) < 1e-6:
            break
    return yaw, shift, n_ok


def in_plane_frames(src, tgt, sp: np.ndarray, tp: np.ndarray, tn: np.ndarray) -> tuple[np.ndarray, ...]:
    """Two views' support-plane frames (:func:`~tofmetry.reconstruct._icp_stages.plane_frame`: z up,
    origin under the object's centroid) and, in them, the source points ``sp``, the target points
    ``tp`` and their normals ``tn`` ((N, 3) each, camera frames [m]). Returns ``(Fs, Ft, a, b, bn)``."""
    Fs, Ft = plane_frame(src.plane, src.obj_points), plane_frame(tgt.plane, tgt.obj_points)
    iFs, iFt = np.linalg.inv(Fs), np.linalg.inv(Ft)
    return Fs, Ft, sp @ iFs[:3, :3].T + iFs[:3, 3], tp @ iFt[:3, :3].T + iFt[:3, 3], tn @ iFt[:3, :3].T


def yaw_sweep_near(src, tgt, T: np.ndarray, half_width_deg: float, step_deg: float,
                   radii_m: tuple[float, ...]) -> list[tuple[float, np.ndarray]]:
    """The yaw of ``T`` about the support normal swept over ``+-half_width_deg`` in ``step_deg``
    steps; at each yaw the support planes are put on each other and the shift along them is fitted
    by :func:`plane_yaw_icp` (yaw held, mid-voxel clouds). Each yaw starts from its neighbour's
    shift, turned about the target object's centre, with the last of ``radii_m`` only (the pose's
    own yaw and the first step below it with every stage). Returns ``[(offset_deg, pose)]`` in
    increasing offset, pose: (4, 4) source camera -> target camera [m]; empty without support
    planes or mid clouds; a side of the sweep ends where too few points match."""
    if src.plane is None or tgt.plane is None or src.mid_points is None or tgt.mid_points is None:
        return []
    Fs, Ft, a, b, bn = in_plane_frames(src, tgt, src.mid_points, tgt.mid_points, tgt.mid_normals)
    iFs = np.linalg.inv(Fs)
    tree = cKDTree(b)
    M = np.linalg.inv(Ft) @ T @ Fs
    yaw0 = float(np.arctan2(M[1, 0], M[0, 0]))
    c = np.mean(b[:, :2], axis=0)  # the target object's centre: turned about it, it stays in place
    k = int(np.floor(half_width_deg / step_deg + 1e-9))
    found: dict[int, np.ndarray] = {}
    for side in (1, -1):  # outward from the pose's own yaw, each yaw started at its neighbour's shift
        shift, prev = M[:2, 3], 0
        for m in range(0 if side > 0 else -1, side * (k + 1), side):
            d = np.radians((m - prev) * step_deg)
            shift = np.array([[np.cos(d), -np.sin(d)], [np.sin(d), np.cos(d)]]) @ (shift - c) + c
            n = 0
            for r in (radii_m if m in (0, -1) else radii_m[-1:]):
                _, shift, n = plane_yaw_icp(a, b, bn, tree, yaw0 + np.radians(m * step_deg), shift, r, fix_yaw=True)
                if n == 0:
                    break
            if n == 0:
                break  # the views part: no further yaw on this side matches either
            R = yaw_in_frame(yaw0 + np.radians(m * step_deg))
            R[:2, 3] = shift
            found[m] = Ft @ R @ iFs
            prev = m
    return [(m * step_deg, found[m]) for m in sorted(found)]


def peak_between_steps(src, tgt, swept: list, k: int, step_deg: float, radii_m: tuple[float, ...],
                       min_deg: float) -> np.ndarray | None:
    """The pose at the vertex of the parabola through the scores of the yaws ``k - 1``, ``k``, ``k + 1``
    of a sweep, where the peak lies between its steps.

    Parameters
    ----------
    src, tgt : the views of :func:`yaw_sweep_near`
    swept : [(offset [deg], (4, 4) pose, score)] in increasing offset; ``k``: the best score's index
    step_deg : the sweep's step [deg]; radii_m : its shift fit's radii [m]
    min_deg : a vertex closer than this to the yaw ``k`` is not looked at [deg]

    Returns
    -------
    (4, 4) source camera -> target camera [m] at the vertex (the shift fitted there), or None where
    ``k`` ends the sweep, its neighbours are not one step either side, the scores bend upward, or
    the vertex lies within ``min_deg``; the caller scores it
    """
    if not (0 < k < len(swept) - 1 and abs(swept[k + 1][0] - swept[k - 1][0] - 2 * step_deg) < 1e-6 * step_deg):
        return None
    cm, c, cp = swept[k - 1][2], swept[k][2], swept[k + 1][2]
    curv = cm - 2.0 * c + cp
    delta = float(np.clip(0.5 * (cm - cp) / curv, -0.5, 0.5)) * step_deg if curv < 0 else 0.0
    if abs(delta) <= min_deg:
        return None
    sub = [U for o, U in yaw_sweep_near(src, tgt, swept[k][1], abs(delta), abs(delta), radii_m) if o * delta > 0]
    return sub[0] if sub else None


def pattern_yaw(src: RegView, tgt: RegView, T0: np.ndarray, fit0: float, c0: float, cfg: RegistrationConfig,
                r_final: float) -> tuple[np.ndarray, float, float, float] | None:
    """The yaw near the pose ``T0`` (source -> target, (4, 4) [m]; its fitness ``fit0`` and IR
    albedo correlation ``c0``) about the support normal that lines the painted pattern up best
    (module docstring), as ``(pose, fitness, RMSE [m], correlation)``; None where it stays.

    Where turning the yaw by ``cfg.ir_local_gate_deg`` either way loses more than
    ``cfg.ir_local_fit_tol`` of fitness, the geometry pins it and it stays. Otherwise it is swept
    over ``+-cfg.ir_local_yaw_deg`` in ``cfg.ir_local_yaw_step_deg`` steps (the shift along the
    support fitted at each); among the yaws that fit within ``cfg.ir_local_fit_tol`` of the best
    fitness (of the sweep and of ``T0``), the one whose matched points' IR albedos correlate most
    is taken where that correlation reaches ``cfg.ir_icp_min_corr`` and beats ``c0`` by
    ``cfg.ir_local_min_gain``; the parabola through the correlations of its yaw and the two beside
    it places the peak between the steps. The fine ICP then refines it, kept where it stays within
    one step of the yaw the pattern chose."""
    radii = tuple(x * 1e-3 for x in cfg.icp_radii_mm[:-1])
    gate = cfg.ir_local_gate_deg
    probe = [object_fitness(src, tgt, T, r_final)[0] for off, T in yaw_sweep_near(src, tgt, T0, gate, gate, radii)
             if off != 0]
    if len(probe) == 2 and max(probe) < max(fit0, *probe) - cfg.ir_local_fit_tol:
        return None  # the geometry pins the yaw: turned by the gate either way, the surfaces part
    swept = []
    for off, T in yaw_sweep_near(src, tgt, T0, cfg.ir_local_yaw_deg, cfg.ir_local_yaw_step_deg, radii):
        sc = _scored(src, tgt, T, cfg, r_final)
        if sc is not None:
            swept.append((off, *sc))
    if not swept:
        return None
    f_top = max([fit0] + [f[1] for f in swept])
    near = [f for f in swept if f[1] >= f_top - cfg.ir_local_fit_tol]
    if not near:
        return None
    k = swept.index(max(near, key=lambda f: f[4]))
    off, fit, rmse, T, c = swept[k]
    if c < cfg.ir_icp_min_corr or c - c0 < cfg.ir_local_min_gain:
        return None
    step = cfg.ir_local_yaw_step_deg
    Tv = peak_between_steps(src, tgt, [(f[0], f[3], f[4]) for f in swept], k, step, radii, 1e-3)
    sc = _scored(src, tgt, Tv, cfg, r_final) if Tv is not None else None
    if sc is not None and sc[3] >= c:
        fit, rmse, T, c = sc
    Tf = refine_fine(src, tgt, T, cfg)
    if rotation_angle_deg(np.linalg.inv(T) @ Tf) <= step:
        sc = _scored(src, tgt, Tf, cfg, r_final)
        if sc is not None:
            fit, rmse, T, c = sc
    E = np.linalg.inv(T0) @ T
    if rotation_angle_deg(E) < 0.05 and np.linalg.norm(E[:3, 3]) < 5e-4:  # where it started
        return None
    return T, fit, rmse, c


def _scored(src: RegView, tgt: RegView, T: np.ndarray, cfg: RegistrationConfig,
            r_final: float) -> tuple[float, float, np.ndarray, float] | None:
    """``(fitness, RMSE [m], T, IR albedo correlation)`` of the pose ``T``, or None where the
    correlation is unknown (no IR, too few matches, no contrast) or the pose fails the pairwise gates."""
    fit, rmse = object_fitness(src, tgt, T, r_final)
    c = ir_agreement(src, tgt, T, r_final)
    return (fit, rmse, T, c) if c is not None and passes_gates(fit, rmse, cfg) else None
