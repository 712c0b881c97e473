"""A second registration search, by the painted pattern, for the edges the pattern contradicts.

The pairwise search (:func:`~tofmetry.reconstruct._register.register_pair`) ranks its hypotheses by
the geometry: the share of object points matched. On a nearly symmetric object (a box, a dome) a
pose turned by the symmetry matches as many points as the right one, often more, and the search
may keep only the wrong one. Where the object carries a pattern the IR amplitude sees (paint,
print, labels), the matched points' relative log albedo
(:func:`~tofmetry.reconstruct._photometric.ir_agreement`) tells the two apart.

A scan *shows a pattern* when one of its accepted edges lines it up (``ir_corr`` at least
``pattern_seen_corr``): two views registered right agree in albedo. Its best edge sets the level
the pattern reaches on this object; an edge none of whose hypotheses comes within
``pattern_search_drop`` of that level is searched again (:func:`pattern_sweep`): the support
planes put on one another, the yaw about their normal swept over the whole turn in
``pattern_search_step_deg`` steps, at each yaw the shift along the plane fitted by the geometry
(the yaw held: :func:`~tofmetry.reconstruct._ir_yaw_local.plane_yaw_icp`) and the pose scored by the
albedo agreement; the best yaw is refined in 1 deg steps about it. No free ICP runs: started near
the right pose, a geometric or photometric ICP of a smooth or symmetric object slides back to the
turned one (measured on a painted dome: from a seed 4 deg off, the photometric ICP ended 15-58 deg
off; the geometric search reached the right pose from none of its seeds).

The pose found becomes the edge's first hypothesis, its geometric ones alternatives, where it lines
the pattern up (``pattern_min_corr``), better than the edge's own best hypothesis by ``pattern_gain``
(else the geometry's poses stand: the sweep holds the tilt to the support planes and finds the yaw to
about a degree, a right geometric pose is finer), and passes the free-space test and the RMSE gate. Its
fitness gate is ``pattern_min_fitness``, below the geometric one: two views far apart on a box
share one face, and the right pose matches a small share of the points (measured: 0.15-0.25 for
views 55-93 deg apart), where the pose turned by the symmetry matches all of them; the pattern on
the shared face, not the share, decides there. The multi-view selection then refuses the geometric
hypotheses the pattern contradicts (:func:`~tofmetry.reconstruct._loops.select_hypotheses`).

A plain object shows no pattern (its albedo correlation is noise, below 0.1 at 200 or more
matches): nothing here runs.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
from scipy.spatial import cKDTree

from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._icp_stages import yaw_in_frame
from tofmetry.reconstruct._ir_yaw_local import in_plane_frames, peak_between_steps, plane_yaw_icp, yaw_sweep_near
from tofmetry.reconstruct._photometric import ir_agreement
from tofmetry.reconstruct._register import PairResult, pair_result, _same_pose
from tofmetry.reconstruct._regview import RegView, object_fitness, visibility_violation

METHOD = "pattern-yaw"  # the method of an edge the pattern placed


def best_ir(p: PairResult) -> float:
    """Highest albedo agreement among an edge's hypotheses (``-inf`` where none is known)."""
    cs = [h.ir_corr for h in [p, *p.alternatives] if h.ir_corr is not None]
    return max(cs) if cs else -np.inf


def pattern_level(pairs: list[PairResult]) -> float:
    """Highest albedo agreement of an accepted edge's chosen hypothesis (``-inf`` where none is known)."""
    cs = [p.ir_corr for p in pairs if p.accepted and p.ir_corr is not None]
    return max(cs) if cs else -np.inf


def pattern_sweep(src: RegView, tgt: RegView, step_deg: float, radii_m: tuple[float, ...],
                  r_final: float, max_points: int = 2000) -> list[tuple[float, np.ndarray]]:
    """Every yaw of the whole turn about the support normal, in ``step_deg`` steps, with the
    shift along the plane fitted at it; scored by the albedo agreement.

    Parameters
    ----------
    src, tgt : prepared views with support planes, coarse-voxel clouds and IR
    step_deg : yaw step [deg]
    radii_m : correspondence radii of the shift fit, wide to narrow [m]
    r_final : radius of the albedo agreement's matches [m]
    max_points : the agreement is scored on about this many of the source's object points

    Returns
    -------
    [(albedo agreement, (4, 4) source camera -> target camera [m])], best first; yaws where the
    views part (too few matches) or the agreement is unknown are left out
    """
    if src.plane is None or tgt.plane is None or src.coarse_points is None or tgt.coarse_points is None:
        return []
    Fs, Ft, a, b, bn = in_plane_frames(src, tgt, src.coarse_points, tgt.coarse_points, tgt.coarse_normals)
    iFs = np.linalg.inv(Fs)
    tree = cKDTree(b)
    k = max(1, len(src.obj_points) // max_points)  # the agreement of the sweep on a subsample
    few = SimpleNamespace(obj_points=src.obj_points[::k], obj_ir=src.obj_ir[::k]) if src.obj_ir is not None else src
    out = []
    for yaw in np.radians(np.arange(0.0, 360.0, step_deg)):
        shift, n = np.zeros(2), 0
        for r in radii_m:
            _, shift, n = plane_yaw_icp(a, b, bn, tree, float(yaw), shift, r, max_iter=8, fix_yaw=True)
            if n == 0:
                break
        if n == 0:
            continue
        R = yaw_in_frame(float(yaw))
        R[:2, 3] = shift
        T = Ft @ R @ iFs
        c = ir_agreement(few, tgt, T, r_final)
        if c is not None:
            out.append((c, T))
    return sorted(out, key=lambda x: -x[0])


def pattern_hypothesis(src: RegView, tgt: RegView, i: int, j: int, cfg: RegistrationConfig) -> PairResult | None:
    """The pose of view ``i`` (source) on view ``j`` (target) that lines the pattern up (module
    docstring): the best yaw of :func:`pattern_sweep`, refined in 1 deg steps about it; None where
    no yaw reaches ``cfg.pattern_min_corr`` or the pose fails the free-space test, the RMSE gate or
    ``cfg.pattern_min_fitness``. Method ``"pattern-yaw"``, ``ir_corr`` set."""
    r_final = cfg.icp_radii_mm[-1] * 1e-3
    coarse = (2.5 * cfg.coarse_voxel_mm * 1e-3, 1.25 * cfg.coarse_voxel_mm * 1e-3)
    swept = pattern_sweep(src, tgt, cfg.pattern_search_step_deg, coarse, r_final)
    if not swept or swept[0][0] < 0.5 * cfg.pattern_min_corr:
        return None
    radii = tuple(x * 1e-3 for x in cfg.icp_radii_mm[:-1])
    near = [(off, U, ir_agreement(src, tgt, U, r_final))
            for off, U in yaw_sweep_near(src, tgt, swept[0][1], cfg.pattern_search_step_deg, 1.0, radii)]
    near = [x for x in near if x[2] is not None]
    if not near:
        return None
    k = max(range(len(near)), key=lambda m: near[m][2])
    _, T, c = near[k]
    if c < cfg.pattern_min_corr:
        return None
    Tv = peak_between_steps(src, tgt, near, k, 1.0, radii, 0.05)  # the peak between the 1 deg steps
    cs = ir_agreement(src, tgt, Tv, r_final) if Tv is not None else None
    if cs is not None and cs >= c:
        c, T = cs, Tv
    fit, rmse = object_fitness(src, tgt, T, r_final)
    v = visibility_violation(src, tgt, T, cfg.see_through_tol_mm * 1e-3)
    if fit < cfg.pattern_min_fitness or rmse * 1e3 > cfg.max_rmse_mm or v > cfg.max_see_through:
        return None
    return pair_result(src, tgt, i, j, T, fit, rmse, v, METHOD, True, r_final, ir_corr=c)


def with_pattern_hypothesis(p: PairResult, h: PairResult) -> PairResult:
    """Edge ``p`` with the pattern's hypothesis ``h`` first and its own accepted ones after it."""
    own = ([replace(p, alternatives=[])] if p.accepted else []) + [a for a in p.alternatives if a.accepted]
    return replace(h, alternatives=[a for a in own if not _same_pose(a.transform, h.transform)])


def search_by_pattern(pairs: list[PairResult], regs: list[RegView], cfg: RegistrationConfig,
                      names: list[str]) -> tuple[list[PairResult], dict | None]:
    """Every edge the pattern contradicts, searched again by the pattern (module docstring).

    Returns
    -------
    pairs : the edges; those the pattern placed with its hypothesis first
    report : None where the scan shows no pattern, else {"level": the best edge's albedo agreement,
        "searched": [edge names], "found": {edge: [albedo agreement, fitness] of the pattern's pose}}
    """
    level = pattern_level(pairs)
    if not level >= cfg.pattern_seen_corr:
        return pairs, None
    report: dict = {"level": round(float(level), 3), "searched": [], "found": {}}
    out = []
    for p in pairs:
        if best_ir(p) >= level - cfg.pattern_search_drop:
            out.append(p)
            continue
        tag = f"{names[p.source]}->{names[p.target]}"
        report["searched"].append(tag)
        h = pattern_hypothesis(regs[p.source], regs[p.target], p.source, p.target, cfg)
        if h is None or h.ir_corr - best_ir(p) < cfg.pattern_gain:
            # nothing lines the pattern up clearly better than the geometry's own poses: they stand
            out.append(p)
            continue
        report["found"][tag] = [round(float(h.ir_corr), 3), round(float(h.fitness), 3)]
        out.append(with_pattern_hypothesis(p, h))
    return out, report
