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
from scipy.spatial import cKDTree

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._icp_stages import plane_frame, refine_fine, refine_mid, yaw_hops, yaw_in_frame
from tofmetry.reconstruct._ir_yaw_local import pattern_yaw
from tofmetry.reconstruct._photometric import ir_agreement, ir_yaw_sweep, photometric_icp
from tofmetry.reconstruct._o3d import (
    global_register,
    icp,
    information_matrix,
)
from tofmetry.reconstruct._regview import (
    RegView,
    leaves_yaw_free,
    object_fitness,
    passes_gates,
    registration_conditioning,
    visibility_violation,
)
from tofmetry.reconstruct._turntable import TurntablePrior


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


def yaw_candidates(src: RegView, tgt: RegView, step_deg: float = 30.0,
                   angles_deg: tuple[float, ...] | None = None) -> list[np.ndarray]:
    """Transforms that put the source support plane on the target one, at yaw steps about its normal
    (or at the yaws ``angles_deg``: a declared turntable's turns)."""
    Fs = plane_frame(src.plane, src.obj_points)
    Ft = plane_frame(tgt.plane, tgt.obj_points)
    out = []
    yaws = np.arange(0.0, 360.0, step_deg) if angles_deg is None else np.asarray(angles_deg, np.float64)
    for a in np.radians(yaws):
        out.append(Ft @ yaw_in_frame(a) @ np.linalg.inv(Fs))
    return out


def shifted_yaw_candidates(src: RegView, tgt: RegView, step_deg: float = 30.0, frac: float = 0.5,
                           angles_deg: tuple[float, ...] | None = None) -> list[np.ndarray]:
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
    for T0 in yaw_candidates(src, tgt, step_deg, angles_deg):
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
    method : "fpfh+icp", "plane-yaw+icp" or "init+icp", "+hop" where :func:`yaw_hops` moved it
    accepted : passed the fitness / RMSE gates and the free-space test
    alternatives : other distinct hypotheses that pass the gates (PairResult each), best first
    conditioning : :func:`registration_conditioning` of the transform
    see_through : :func:`visibility_violation` of the transform (share of points seen through)
    ir_yaw : the photometric yaw search of a yaw-free edge (:func:`~tofmetry.reconstruct._photometric.ir_yaw_sweep`:
        correlation of the best yaw, its margin over the next, whether it decided) or None
    ir_corr : correlation of the matched points' IR albedos under ``transform``
        (:func:`~tofmetry.reconstruct._photometric.ir_agreement`), or None without IR or contrast
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
    ir_corr: float | None = None

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
        if self.ir_corr is not None:
            d["ir_corr"] = round(self.ir_corr, 4)
        return d

    def with_hypothesis(self, alt: PairResult) -> PairResult:
        """This edge with ``alt`` (one of :attr:`alternatives`) as its transform; the old one becomes an alternative."""
        rest = [a for a in self.alternatives if a is not alt]
        old = PairResult(self.source, self.target, self.transform, self.fitness, self.inlier_rmse_mm, self.information,
                         self.method, self.accepted, conditioning=self.conditioning, see_through=self.see_through,
                         ir_yaw=self.ir_yaw, ir_corr=self.ir_corr)
        return PairResult(self.source, self.target, alt.transform, alt.fitness, alt.inlier_rmse_mm, alt.information,
                          alt.method, alt.accepted, [old] + rest, alt.conditioning, alt.see_through, alt.ir_yaw,
                          alt.ir_corr)


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
    is used when there is no ``init`` or when the initialised ICP fails the gates. Without the
    global search, the ICP must stay within the loop-closure jump bound of ``init``
    (``cfg.max_loop_jump_deg`` / ``_mm``); where its wide stages leave it, the last stage alone from
    ``init`` is tried (method ``"init+fine-icp"``). The
    candidate with the best (fitness, -RMSE) wins. With ``cfg.turntable_step_deg`` the yaw seeds
    are the declared turns and a hypothesis off them is not accepted (:mod:`._turntable`).
    """
    r_final = cfg.icp_radii_mm[-1] * 1e-3
    tol = cfg.see_through_tol_mm * 1e-3
    prior = None if cfg.turntable_step_deg is None else TurntablePrior(
        i, j, cfg.turntable_step_deg, cfg.turntable_tol_deg, None if tgt.plane is None else tgt.plane[:3])
    seeds = None if prior is None else prior.seeds_deg()

    def allowed(T, widen: float = 1.0) -> bool:
        return prior is None or prior.allows(T, widen)

    def key(c):  # hypotheses the other camera sees through rank last, then by fitness, then RMSE
        return (c[4] > cfg.max_see_through, -c[0], c[1])

    def vis(T):
        return visibility_violation(src, tgt, T, tol)

    cands = []
    if init is not None:
        T = refine_mid(src, tgt, init, cfg)
        if global_search or _same_pose(init, T, cfg.max_loop_jump_deg, cfg.max_loop_jump_mm):
            T = refine_fine(src, tgt, T, cfg)
            cands.append((*object_fitness(src, tgt, T, r_final), T, "init+icp", vis(T)))
        else:
            # the wide stages slid beyond the bound (they are biased where the views overlap in part,
            # most on a smooth object: a pebble's pair 4 deg from its right pose slid 20 deg away):
            # the last stage alone from the initial pose, within the same bound
            T = refine_fine(src, tgt, init, cfg)
            if _same_pose(init, T, cfg.max_loop_jump_deg, cfg.max_loop_jump_mm):
                cands.append((*object_fitness(src, tgt, T, r_final), T, "init+fine-icp", vis(T)))
    if global_search and (not cands or not passes_gates(cands[0][0], cands[0][1], cfg) or not plane_consistent(src, tgt, cands[0][2])
                          or cands[0][4] > cfg.max_see_through):
        def fpfh():
            return [(global_register(src.feat_points, src.feat_normals, tgt.feat_points, tgt.feat_normals,
                                     cfg.feature_voxel_mm * 1e-3, seed=cfg.seed + s).transform, "fpfh+icp")
                    for s in range(cfg.ransac_seeds)]

        def good(c):
            return (passes_gates(c[0], c[1], cfg) and c[4] <= cfg.max_see_through and plane_consistent(src, tgt, c[2])
                    and allowed(c[2]))

        if src.plane is not None and tgt.plane is not None:
            _search(src, tgt, cfg, [(T, "plane-yaw+icp") for T in yaw_candidates(src, tgt, cfg.yaw_step_deg, seeds)],
                    cands, key, vis, allowed)
            # fallbacks when no yaw seed converged to an acceptable pose: shifted yaw seeds, then FPFH + RANSAC
            if not any(good(c) for c in cands):
                _search(src, tgt, cfg, [(T, "shifted-yaw+icp") for T in
                                        shifted_yaw_candidates(src, tgt, cfg.yaw_step_deg, angles_deg=seeds)],
                        cands, key, vis, allowed)
            if not any(good(c) for c in cands):
                _search(src, tgt, cfg, fpfh(), cands, key, vis, allowed)
        else:
            _search(src, tgt, cfg, fpfh(), cands, key, vis, allowed)
    if not cands:
        return PairResult(i, j, np.eye(4), 0.0, np.inf, np.zeros((6, 6)), "none", False)
    ranked = sorted(cands, key=lambda c: (not plane_consistent(src, tgt, c[2]), not allowed(c[2]), *key(c)))
    out = []
    for fit, rmse, T, method, v in ranked:
        ok = passes_gates(fit, rmse, cfg) and v <= cfg.max_see_through and allowed(T)
        if out and not (ok and plane_consistent(src, tgt, T)):
            continue
        out.append(pair_result(src, tgt, i, j, T, fit, rmse, v, method, ok, r_final))
    best = out[0]
    if best.accepted:
        best, out = _hopped(src, tgt, best, out, cfg, vis, allowed, r_final)
    c0 = ir_agreement(src, tgt, best.transform, r_final) if (cfg.ir_icp or cfg.ir_local_yaw) and best.accepted else None
    best = replace(best, ir_corr=c0)
    if (cfg.ir_local_yaw and c0 is not None and c0 >= 0.5 * cfg.ir_icp_min_corr
            and not (cfg.ir_yaw and leaves_yaw_free(best.conditioning, cfg.yaw_free_ratio))):
        # a yaw the geometry pins only loosely (a yaw-free edge gets the full turn about its axis below)
        best, out = _ir_local_yaw(src, tgt, best, out, cfg, vis, allowed, r_final)
        c0 = best.ir_corr
    if cfg.ir_icp and c0 is not None and c0 >= 0.5 * cfg.ir_icp_min_corr:  # no pattern at all (a plain object): not tried
        # the IR albedo as a photometric term, kept where the pattern lines up clearly better and the
        # geometry matches as well (the object fitness within its noise, 0.005)
        T = photometric_icp(src, tgt, best.transform, tuple(x * 1e-3 for x in cfg.icp_radii_mm[-2:]),
                            cfg.ir_icp_lambda)
        if T is not None:  # None: no correspondence left (the geometric registration stays)
            fit, rmse = object_fitness(src, tgt, T, r_final)
            c1 = ir_agreement(src, tgt, T, r_final)
            v = vis(T)
            if (c1 is not None and c1 >= cfg.ir_icp_min_corr and c1 - c0 >= cfg.ir_icp_min_gain
                    and fit >= best.fitness - 0.005 and passes_gates(fit, rmse, cfg) and v <= cfg.max_see_through
                    and plane_consistent(src, tgt, T) and allowed(T)):
                best = pair_result(src, tgt, i, j, T, fit, rmse, v, best.method + "+ir-icp", True, r_final, ir_corr=c1)
                out = [best] + out[1:]
    if cfg.ir_yaw and leaves_yaw_free(best.conditioning, cfg.yaw_free_ratio) and src.obj_ir is not None and tgt.icp_ir is not None:
        # the geometry leaves the yaw free: let the painted pattern (IR amplitude) choose it
        sw = ir_yaw_sweep(src, tgt, best.transform, r_final)
        turned = _ir_turned(src, tgt, i, j, sw.pop("transform"), cfg, r_final, vis, best.method + "+ir-yaw", sw) \
            if sw["decided"] else None
        if turned is not None and allowed(turned.transform):
            return _with_ir(replace(turned, alternatives=[a for a in out if not _same_pose(a.transform, turned.transform)]),
                            src, tgt, r_final)
        cands = sw.pop("candidates", None)
        if cands:
            # two yaws line the pattern up better than the geometric choice: both become hypotheses
            # (the better first) and the loops of the views choose (select_hypotheses); the geometric
            # ones stay as alternatives, which the pattern then vetoes
            turned = [_ir_turned(src, tgt, i, j, T0, cfg, r_final, vis, best.method + "+ir-yaw-candidate", sw)
                      for T0 in cands]
            turned = [t for t in turned if t.accepted and allowed(t.transform)]
            if turned and (best.ir_corr is None or turned[0].ir_corr is not None and turned[0].ir_corr > best.ir_corr):
                rest = [a for a in turned[1:] + out if not _same_pose(a.transform, turned[0].transform)]
                return _with_ir(replace(turned[0], alternatives=rest), src, tgt, r_final)
        best = replace(best, ir_yaw=sw)
    return _with_ir(replace(best, alternatives=out[1:]), src, tgt, r_final)


def _hopped(src: RegView, tgt: RegView, best: PairResult, out: list[PairResult], cfg: RegistrationConfig, vis, allowed,
            r_final: float) -> tuple[PairResult, list[PairResult]]:
    """The chosen hypothesis after :func:`yaw_hops`, where the hopped pose passes every gate the
    hypothesis did; the other hypotheses are not hopped (a turned-over one of a nearly symmetric
    object would match as well as the right one, measured on a fandisk: 131 deg off, 100 % against
    99.8 %), and one the hops reached is no alternative any more."""
    T = yaw_hops(src, tgt, best.transform, cfg)
    if T is best.transform:
        return best, out
    fit, rmse = object_fitness(src, tgt, T, r_final)
    v = vis(T)
    if not (passes_gates(fit, rmse, cfg) and v <= cfg.max_see_through and plane_consistent(src, tgt, T) and allowed(T)):
        return best, out
    hopped = pair_result(src, tgt, best.source, best.target, T, fit, rmse, v, best.method + "+hop", True, r_final)
    return hopped, [hopped] + [a for a in out[1:] if not _same_pose(a.transform, T)]


def _ir_local_yaw(src: RegView, tgt: RegView, best: PairResult, out: list[PairResult], cfg: RegistrationConfig, vis,
                  allowed, r_final: float) -> tuple[PairResult, list[PairResult]]:
    """The accepted hypothesis, or the yaw near it that the painted pattern picks
    (:func:`pattern_yaw`), where that pose passes every gate."""
    got = pattern_yaw(src, tgt, best.transform, best.fitness, best.ir_corr, cfg, r_final)
    if got is None:
        return best, out
    T, fit, rmse, c = got
    v = vis(T)
    if v > cfg.max_see_through or not plane_consistent(src, tgt, T) or not allowed(T):
        return best, out
    chosen = pair_result(src, tgt, best.source, best.target, T, fit, rmse, v, best.method + "+ir-yaw-sweep", True,
                          r_final, ir_corr=c)
    return chosen, [chosen] + [a for a in out if not _same_pose(a.transform, T)]


def _ir_turned(src: RegView, tgt: RegView, i: int, j: int, T0: np.ndarray, cfg: RegistrationConfig, r_final: float,
               vis, method: str, sweep: dict) -> PairResult:
    """The hypothesis of a yaw the IR pattern chose (``T0``, source -> target), refined: the geometric
    ICP, and the photometric one where it lines the pattern up better at the same fitness."""
    T = refine_fine(src, tgt, T0, cfg)
    fit, rmse = object_fitness(src, tgt, T, r_final)
    c = ir_agreement(src, tgt, T, r_final)
    if cfg.ir_icp:
        # the geometric ICP is free to slide in yaw here: the pattern holds it (measured on a
        # painted vase at 0.74 m: the geometric refinement left 7.4 degrees, the pattern 1.4)
        Tp = photometric_icp(src, tgt, T0, tuple(x * 1e-3 for x in cfg.icp_radii_mm[-2:]), cfg.ir_icp_lambda)
        if Tp is not None:
            fit_p, rmse_p = object_fitness(src, tgt, Tp, r_final)
            cp = ir_agreement(src, tgt, Tp, r_final)
            if cp is not None and (c is None or cp > c) and fit_p >= fit - 0.005:
                T, fit, rmse, c = Tp, fit_p, rmse_p, cp
    v = vis(T)
    ok = passes_gates(fit, rmse, cfg) and v <= cfg.max_see_through
    return pair_result(src, tgt, i, j, T, fit, rmse, v, method, ok, r_final, ir_yaw=sweep, ir_corr=c)


def pair_result(src: RegView, tgt: RegView, i: int, j: int, T: np.ndarray, fit: float, rmse_m: float, v: float,
                 method: str, ok: bool, radius_m: float, **extra) -> PairResult:
    """A scored hypothesis (fitness, RMSE [m], see-through share ``v``) with its information matrix and
    conditioning at the final ICP radius ``radius_m``."""
    return PairResult(i, j, T, fit, rmse_m * 1e3,
                      information_matrix(src.icp_points, tgt.icp_points, radius_m, T, tgt.icp_normals), method, ok,
                      conditioning=registration_conditioning(src, tgt, T, radius_m), see_through=v, **extra)


def _with_ir(p: PairResult, src: RegView, tgt: RegView, radius_m: float) -> PairResult:
    """``p`` and its alternatives with their IR agreement (:func:`ir_agreement`; ``p``'s only where
    it is not known yet)."""
    return replace(p, ir_corr=p.ir_corr if p.ir_corr is not None else ir_agreement(src, tgt, p.transform, radius_m),
                   alternatives=[replace(a, ir_corr=ir_agreement(src, tgt, a.transform, radius_m))
                                 for a in p.alternatives])


def _search(src: RegView, tgt: RegView, cfg: RegistrationConfig, coarse: list, cands: list, key, vis,
            allowed=None) -> None:
    """Coarse hypotheses ``coarse`` [(T, how)] -> quick ICP -> distinct -> mid ICP -> fine ICP; appends
    (fitness, rmse, T, how, see_through) of the winner and of every other distinct hypothesis that
    passes the gates to ``cands``; ``allowed(T, widen)``: a declared turntable's test (the quick ICP's
    poses within twice its tolerance go on)."""
    r_final = cfg.icp_radii_mm[-1] * 1e-3
    # quick ICP of every coarse candidate on the feature-voxel clouds, keep the best few
    quick = []
    for T0, how in coarse:
        T = T0
        for r in (2.5 * cfg.coarse_voxel_mm, 1.25 * cfg.coarse_voxel_mm):
            T = icp(src.coarse_points, tgt.coarse_points, tgt.coarse_normals, T, r * 1e-3, kernel=cfg.kernel,
                    max_iter=12).transform
        if plane_consistent(src, tgt, T, 5.0, 15.0) and (allowed is None or allowed(T, 2.0)):
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
        T = refine_mid(src, tgt, c[2], cfg)
        if plane_consistent(src, tgt, T):
            mids.append((*object_fitness(src, tgt, T, r_final), T, c[3], vis(T)))
    mids.sort(key=key)
    for k, (fit0, rm0, T, how, v0) in enumerate(mids):
        # alternatives are kept for the multi-view (loop consistency) selection
        if k > 0 and not (passes_gates(fit0, rm0, cfg) and v0 <= cfg.max_see_through
                          and all(not _same_pose(T, c[2]) for c in cands)):
            continue
        T = refine_fine(src, tgt, T, cfg)
        if plane_consistent(src, tgt, T) and all(not _same_pose(T, c[2]) for c in cands):
            cands.append((*object_fitness(src, tgt, T, r_final), T, how, vis(T)))


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
