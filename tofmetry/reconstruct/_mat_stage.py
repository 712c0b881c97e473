"""The registration stage of a scan on a dot mat: every view placed on the mat on its own.

With :attr:`~tofmetry.reconstruct.RegistrationConfig.mat` set, the pairwise registrations, their
loops and their selection are not needed: :func:`~tofmetry.reconstruct._mat_locate.locate_on_mat`
places each view, so an error in one view stays in that view (nothing is chained), and an object
the geometry cannot pin (a vase of revolution, a thin plaque) is placed as well as any other. The
successive pairs are still scored at the placed poses (the object's fitness, its RMSE and the
conditioning): an object that does not fit where the mat puts the views is reported, and the joint
fit (:func:`~tofmetry.reconstruct._adjust_stage.joint_adjustment`, its pose prior the mat's) then
refines the placements on the object's points.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from tofmetry._shared.geometry import displacement_at, rotation_angle_deg
from tofmetry._shared.dot_mat import DotMat
from tofmetry.reconstruct._config import RegistrationConfig
from tofmetry.reconstruct._mat_dense import locate_by_pattern
from tofmetry.reconstruct._mat_dots import albedo_image, plane_frame
from tofmetry.reconstruct._mat_level import plane_at_depth
from tofmetry.reconstruct._mat_locate import MatFix, locate_on_mat, pooled_dot_noise, with_pooled_noise
from tofmetry.reconstruct._adjust_field import DepthFieldPrior
from tofmetry.reconstruct._mat_plane import matched_dots, view_dot_plane
from tofmetry.reconstruct._mat_range import moved_along_sight, range_offset, widened_fit
from tofmetry.reconstruct._mat_tilt import (combined_tilt, depth_plane_tilt_cov, largest_sigma, retilted_fix,
                                            support_mask)
from tofmetry.reconstruct._photometric import log_albedo
from tofmetry.reconstruct._posegraph import PoseGraphResult
from tofmetry.reconstruct._register import pair_result, register_pair, rejection_reason
from tofmetry.reconstruct._regview import object_fitness, passes_gates, visibility_violation

#: the method of the edges a mat placed
MAT_METHOD = "mat"
#: a standard normal's 90th percentile of |x|: a placement's 1-sigma times this is its p90
P90_Z = 1.645
#: the joint fit moving a view by more than this many of its placement's sigmas (and beyond the pose
#: gate) contradicts the placement (:func:`departures`). Not 3: over the family's stored mat runs
#: (each seed once, 160 runs, 1737 placed views, against the truth) the placements' turns about the
#: vertical were off by RMS 1.05 of their own sigmas, p99 2.8, at most 4.5; 0.75 % beyond 3
DEPARTURE_Z = 5.0
#: how far the mat's placements themselves are off, at p99: the rotation [deg] and the largest
#: displacement of the object's points [mm] (the family's stored mat runs, each seed once, 400 runs,
#: 4211 placed views against the truth: p90 0.09 deg / 1.1 mm, p99 0.21 deg / 2.1 mm, the most
#: 0.60 deg / 4.1 mm). A fit that moved a view by less than the gate plus this may have taken it from
#: a placement this far off to one within the gate (:func:`departures`)
PLACEMENT_P99 = (0.21, 2.1)


@dataclass
class MatPlacement:
    """The views a mat placed.

    Attributes
    ----------
    graph : poses (V_kept, 4, 4) camera to mat frame [m], the successive pairs' edges (method
        ``"mat"``), no loops
    fixes : view name -> :class:`MatFix` (every view, placed or not)
    kept : indices of the placed views; left_out : name -> why a view was not placed
    dot_planes : view name -> :class:`~tofmetry.reconstruct._mat_plane.DotPlane`, the mat's plane its
        dots alone give (views placed by their dots, with enough of them matched)
    through : name -> {"via": neighbours' names, "agree_deg", "agree_mm"} of a view the mat did not
        place, registered onto its placed neighbours instead
    range_offset : the mat's range error its dots' size gave
        (:func:`~tofmetry.reconstruct._mat_range.range_offset`; ``applied``: taken out of the
        placements, ``registration.mat_range_from_dots``), None where not measured
    plane_levels : view name -> ``{"moved_mm", "points"}``: how far its support plane was moved toward the
        camera onto the support at the object's depths before it was placed
        (:func:`~tofmetry.reconstruct._mat_level.plane_at_depth`, ``registration.mat_plane_at_object``)
    """

    graph: PoseGraphResult
    fixes: dict
    kept: list
    left_out: dict = field(default_factory=dict)
    through: dict = field(default_factory=dict)
    dot_planes: dict = field(default_factory=dict)
    range_offset: dict | None = None
    plane_levels: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {name: f.to_dict() | ({"through": self.through[name]} if name in self.through else {})
                | ({"dot_plane": self.dot_planes[name].to_dict()} if name in self.dot_planes else {})
                | ({"plane_level": self.plane_levels[name]} if name in self.plane_levels else {})
                for name, f in self.fixes.items()}

    def view_verdicts(self) -> dict:
        """name -> {verdict, reason} of every placed view."""
        out = {}
        for n, f in self.fixes.items():
            if f.located:
                how = {"dots": "", "pattern+dots": "the whole pattern placed it, then ",
                       "pattern": "the whole pattern placed it (too few dots seen whole to refine it); "}[f.how]
                out[n] = {"verdict": "placed on the mat",
                          "reason": how + (f"{f.n_matched} of {f.n_dots} dots seen match the mat's layout, RMS "
                                           f"{f.rms_mm:.2f} mm " if f.how != "pattern" else "")
                          + f"(+/- {f.sigma_deg:.3f} deg, {f.sigma_mm:.2f} mm in the plane"
                          + (f"; tilt +/- {f.tilt_sigma_deg:.2f} deg" if np.isfinite(f.tilt_sigma_deg) else "")
                          + (f", turned {f.tilt_deg:.2f} deg from the depth's plane by its dots" if f.tilt_deg >= 0.01
                             else "") + ")"}
            elif n in self.through:
                t = self.through[n]
                two = len(t["via"]) == 2
                out[n] = {"verdict": "placed through its neighbours" if two else "unverified",
                          "reason": (f"the mat is not seen well enough ({f.reason}); registered onto "
                                     + " and ".join(t["via"]) + (f", which agree within {t['agree_deg']:.2f} deg / "
                                                                  f"{t['agree_mm']:.1f} mm at the object" if two else
                                                                  " only: nothing checks it"))}
        return out

    def loose_views(self, gate_deg: float, gate_mm: float, z: float = P90_Z) -> dict:
        """name -> (sigma_deg, sigma_mm) of the placed views whose placement's own ``z``-sigma (p90 by
        default) reaches beyond the pose gate (``gate_deg`` in rotation, ``gate_mm`` along the sheet):
        few dots seen, or a tilt neither the depth nor the dots pin (:attr:`MatFix.rotation_sigma_deg`),
        the pose is not vouched for within the gate by the mat alone."""
        return {n: (f.rotation_sigma_deg, f.sigma_mm) for n, f in self.fixes.items()
                if f.located and (z * f.rotation_sigma_deg > gate_deg or z * f.sigma_mm > gate_mm)}

    def allowed_moves(self, centre_m: np.ndarray, z: float = DEPARTURE_Z) -> dict:
        """name -> (rotation [deg], displacement of ``centre_m`` (3,) [mm], mat frame [m]) within which
        a placed view's own placement holds it at ``z`` sigma (:meth:`MatFix.sigma_at_mm`): how far
        the joint fit may move it before fit and placement contradict each other."""
        return {n: (z * f.rotation_sigma_deg, z * f.sigma_at_mm(centre_m)) for n, f in self.fixes.items()
                if f.located and np.isfinite(f.sigma_deg) and np.isfinite(f.sigma_mm)}

    def prior(self, tilt_deg: float, height_mm: float, inflation: float = 2.0, floor_deg: float = 0.03,
              floor_mm: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """The joint fit's pose prior of each kept view along the mat's x, y, z: rotation [deg] and
        displacement at the object [mm], each (V_kept, 3). A view the mat placed: about the vertical and
        along the sheet, ``inflation`` times its placement's 1-sigma, at least ``floor_deg`` /
        ``floor_mm``; its tilt and height, which the support plane gives, ``tilt_deg`` / ``height_mm``.
        A view placed through its neighbours: ``tilt_deg`` / ``height_mm`` along every axis."""
        names = list(self.fixes)
        deg, mm = [], []
        for k in self.kept:
            f = self.fixes[names[k]]
            if f.located:
                deg.append([tilt_deg, tilt_deg, max(inflation * f.sigma_deg, floor_deg)])
                s = max(inflation * f.sigma_mm, floor_mm)
                mm.append([s, s, height_mm])
            else:
                deg.append([tilt_deg] * 3)
                mm.append([height_mm] * 3)
        return np.array(deg), np.array(mm)


def place_views(views, segs, regs, intr, white_map, rc: RegistrationConfig, names: list[str],
                plane_threshold_m: float, dot_planes: bool = False,
                depth_field: DepthFieldPrior | None = None) -> MatPlacement:
    """Place every view on the mat ``rc.mat`` (module docstring).

    Parameters
    ----------
    views, segs, regs : the prepared views, their segmentations and registration clouds
    intr : CameraIntrinsics of the depth images; white_map : (H, W) amplitude reference or None
    names : the views' names; plane_threshold_m : the support plane's inlier distance [m]
    dot_planes : also fit each view's plane from its dots alone (``MatPlacement.dot_planes``; always
        with ``depth_field``)
    depth_field : the depth calibration's residual field; given, each view placed by its dots takes
        its tilt from the depth's support plane and the dots' own plane, weighed by their
        covariances (:mod:`~tofmetry.reconstruct._mat_tilt`); None: from the support plane alone

    Returns
    -------
    MatPlacement (``kept`` empty when fewer than two views were placed)
    """
    mat = DotMat.from_dict(rc.mat, "registration.mat")
    rays = intr.ray_table(True)
    fixes, poses, planes, levels = {}, {}, {}, {}
    for k, (v, s) in enumerate(zip(views, segs)):
        if s.plane is None or v.ir is None:
            fixes[names[k]] = MatFix(False, reason="no support plane was found in the view" if s.plane is None else
                                     "the view has no IR frames (the mat's dots are seen in the IR amplitude)")
            continue
        ground = support_mask(v, s, plane_threshold_m)
        plane_k = s.plane
        if rc.mat_plane_at_object and s.object_mask.any():  # its offset read at the object's depths
            on = (np.abs(v.points @ s.plane[:3] + s.plane[3]) < plane_threshold_m) & ~s.object_mask
            plane_k, moved, n_on = plane_at_depth(s.plane, v.points[on], float(np.median(v.points[s.object_mask, 2])),
                                                  1e-3 * rc.mat_plane_band_mm)
            levels[names[k]] = {"moved_mm": round(moved, 3), "points": n_on}
        alb = albedo_image(v.index, intr.shape, ground, log_albedo(v, intr, white_map))
        fx = locate_on_mat(alb, rays, plane_k, mat, rc.mat_min_dots)
        if not fx.located and s.object_mask.any():  # too few whole dots: the whole pattern
            G = plane_frame(plane_k)
            foot = (v.points[s.object_mask] @ G[:2, :3].T + G[:2, 3]).mean(0)
            fp = locate_by_pattern(alb, rays, plane_k, foot, mat,
                                   pattern_sigma=(rc.mat_pattern_sigma_deg, rc.mat_pattern_sigma_mm))
            fx = fp if fp.located else replace(fx, reason=f"{fx.reason}; {fp.reason}")
        wanted = (dot_planes or depth_field is not None) and fx.located and "dots" in fx.how
        seen = matched_dots(alb, rays, plane_k, fx, mat) if wanted else None
        dp = None if seen is None else view_dot_plane(alb, rays, plane_k, fx, mat, seen=seen)
        if depth_field is not None and fx.located:
            cov = depth_plane_tilt_cov(plane_k, v.points[ground], depth_field)
            if dp is not None:
                tilt, tcov = combined_tilt(dp, cov)
                fx, _ = retilted_fix(fx, plane_k, seen[0], seen[1], tilt, tcov, mat)
            else:
                fx = replace(fx, tilt_sigma_deg=float(np.degrees(largest_sigma(cov))))
        fixes[names[k]] = fx
        if fx.located:
            poses[k] = fx.camera_to_mat
            if dp is not None:
                planes[names[k]] = dp
    pooled, _ = pooled_dot_noise(fixes.values())  # a view of few dots cannot tell its own noise
    fixes = {n: with_pooled_noise(f, pooled) for n, f in fixes.items()}
    rng = range_offset(list(fixes.values()), rc.mat_min_dots)  # the mat's own range error, from its dots' size
    if rng is not None:
        rng["applied"] = bool(rc.mat_range_from_dots and rng["significant"])
    if rng is not None and rng["applied"]:  # taken out of every placement
        fixes = {n: moved_along_sight(f, rng["delta_mm"]) for n, f in fixes.items()}
        poses = {k: fixes[names[k]].camera_to_mat for k in poses}
    through, not_through = {}, {}
    if len(poses) >= 2:
        on_mat = dict(poses)  # placed through views the mat placed, not through each other
        for k in range(len(views)):
            if k not in on_mat:
                T, info = _through_neighbours(k, on_mat, regs, rc, names)
                if T is not None:
                    poses[k], through[names[k]] = T, info
                else:
                    not_through[names[k]] = info
    kept = sorted(poses)
    left_out = {names[k]: "not placed on the dot mat: " + fixes[names[k]].reason
                          + ("; " + not_through[names[k]] if names[k] in not_through else "")
                for k in range(len(views)) if k not in poses}
    P = np.array([poses[k] for k in kept]).reshape(-1, 4, 4)
    r_final = rc.icp_radii_mm[-1] * 1e-3
    tol = rc.see_through_tol_mm * 1e-3
    edges = []
    for a in range(len(kept) - 1 + (len(kept) > 2)):
        b = (a + 1) % len(kept)
        i, j = kept[a], kept[b]
        T = np.linalg.inv(P[b]) @ P[a]
        fit, rmse = object_fitness(regs[i], regs[j], T, r_final)
        p = pair_result(regs[i], regs[j], a, b, T, fit, rmse, visibility_violation(regs[i], regs[j], T, tol),
                        MAT_METHOD, True, r_final)
        d = p.to_dict([names[k] for k in kept]) | {"kept": True}
        if not passes_gates(fit, rmse, rc):
            d["object_disagrees"] = rejection_reason(replace(p, accepted=False), rc)
        edges.append(d)
    graph = PoseGraphResult(P, edges, {"reasons": [], "loops": [], "placed_by": "dot mat"})
    return MatPlacement(graph, fixes, kept, left_out, through, planes, rng, levels)


def _through_neighbours(k: int, poses: dict, regs, rc: RegistrationConfig, names: list[str]):
    """The pose of view ``k`` (which the mat did not place) from its nearest placed views in scan
    order, one on each side (registered onto each, :func:`register_pair`). With two, they must agree
    within twice the pose gate at the object; with one, the view is unverified. Returns (pose (4, 4)
    camera to mat, {"via": names, "agree_deg", "agree_mm"}), or (None, why) when no neighbour
    registers or two disagree."""
    n = len(regs)
    near = []
    for step in (-1, 1):
        for d in (1, 2):
            j = (k + step * d) % n
            if j in poses and j != k and j not in near:
                near.append(j)
                break
    got = []
    for j in near:
        p = register_pair(regs[k], regs[j], k, j, rc)
        if p.accepted:
            got.append((j, poses[j] @ p.transform))
    if not got:
        return None, (f"nor registered onto its placed neighbour(s) {', '.join(names[j] for j in near)}"
                      if near else "and no placed view is next to it")
    info = {"via": [names[j] for j, _ in got]}
    if len(got) == 2:
        c = regs[k].obj_points.mean(0) if len(regs[k].obj_points) else np.zeros(3)
        E = np.linalg.inv(got[0][1]) @ got[1][1]
        deg, mm = rotation_angle_deg(E), displacement_at(E, c) * 1e3
        info |= {"agree_deg": round(deg, 3), "agree_mm": round(mm, 2)}
        if deg > 2 * rc.pose_gate_deg or mm > 2 * rc.pose_gate_mm:
            return None, (f"registered onto {names[got[0][0]]} and {names[got[1][0]]}, which place it "
                          f"{deg:.2f} deg / {mm:.1f} mm apart at the object")
    return got[0][1], info


def pattern_scale(fixes: dict, offset_mm: float | None, floor_pct: float = 0.1, min_dots: int = 6) -> dict | None:
    """The depth camera's scale on the mat, from every view's dots (:func:`fix_from_matches`'s
    ``pattern_scale``): their inverse-variance mean, its 1-sigma (widened by the views' scatter when
    they disagree more than their own sigmas say), and whether it agrees with the depth calibration.

    The calibration's predicted range error ``offset_mm`` [mm] moves the ground, and the pattern's
    scale by ``offset / H`` (``H`` the cameras' median height over the sheet); ``floor_pct`` [%] is
    the method's own systematic error (1 sigma: on exact depth the dots came out 0.09 % +- 0.02 %
    small over 8 views of a vase, the views ranging -0.03 to -0.15 %). Beyond 3 sigma of the three
    together the pattern is ``consistent: False``: the camera's scale
    differs from what the calibration vouches for (a depth gain, a focal length, a mat not printed
    at 100 %), and the model's scale with it. None where fewer than two views matched
    ``min_dots`` dots.

    Parameters
    ----------
    fixes : view name -> MatFix
    offset_mm : the calibration's predicted central range error [mm], or None (uncalibrated: 0)
    """
    use = [f for f in fixes.values() if f.located and f.n_matched >= min_dots and np.isfinite(f.pattern_scale)
           and f.pattern_scale_sigma > 0]
    if len(use) < 2:
        return None
    mean, sigma, chi2_dof = widened_fit(np.array([f.pattern_scale for f in use]),
                                        np.array([f.pattern_scale_sigma for f in use]), np.ones(len(use)))
    height = float(np.median([f.camera_to_mat[2, 3] for f in use]))
    from_offset = (offset_mm or 0.0) * 1e-3 / max(height, 1e-3)
    allowed = 3.0 * float(np.sqrt(sigma ** 2 + from_offset ** 2 + (floor_pct / 100) ** 2))
    return {"scale_pct": round(100 * mean, 4), "sigma_pct": round(100 * sigma, 4), "views": len(use),
            "chi2_per_view": round(chi2_dof, 3), "camera_height_mm": round(1e3 * height, 1),
            "from_offset_pct": round(100 * from_offset, 4), "consistent": bool(abs(mean) <= allowed),
            "floor_pct": floor_pct, "allowed_pct": round(100 * allowed, 4),
            "rule": "|scale| <= 3 sqrt(sigma^2 + (calibration's predicted range error / camera height)^2 + floor^2)"}


def pattern_scale_warning(check: dict | None) -> str | None:
    """The warning of a :func:`pattern_scale` check that failed (None: it held, or there was none)."""
    if check is None or check["consistent"]:
        return None
    big = "larger" if check["scale_pct"] > 0 else "smaller"
    return (f"the mat's dots, measured through the depth camera in {check['views']} views, come out "
            f"{abs(check['scale_pct']):.2f} % +/- {check['sigma_pct']:.2f} % {big} than printed, beyond what the depth "
            f"calibration's predicted range error and the method leave (+/- {check['allowed_pct']:.2f} %): the depth scale at the "
            f"mat (a depth gain or a focal length off) or the print is off, and the model is likely {big} by about as "
            "much; check that the mat was printed at 100 %, then the depth and lens calibrations")


def loose_reason(loose: dict, gate_deg: float, gate_mm: float, why: str) -> str:
    """The verdict's reason for views the mat placed too loosely (:meth:`MatPlacement.loose_views`)
    whose placements stand unrefined (``why``: what kept the joint fit from refining them)."""
    views = ", ".join(f"{n} (+/- {d:.2f} deg, {m:.1f} mm)" for n, (d, m) in loose.items())
    return (f"view(s) {views} were placed by the dot mat alone from few dots: at p90 the placement reaches beyond the "
            f"pose gate ({gate_deg:g} deg / {gate_mm:g} mm), and the joint fit did not refine it ({why}); "
            "take the view where more of the mat is seen")


def departures(start: np.ndarray, end: np.ndarray, centre_m: np.ndarray, gate_deg: float, gate_mm: float,
               names: list[str], allowed: dict | None = None, margin: tuple = PLACEMENT_P99) -> dict:
    """The views the joint fit moved beyond the pose gate plus how far placements are off
    (``margin``: rotation [deg], displacement [mm]; :data:`PLACEMENT_P99`), and beyond what their
    placement allows, from where the mat placed them: name -> (rotation [deg], displacement of the
    object centre ``centre_m`` (3,) [m], world [mm]).

    ``start``, ``end``: (V, 4, 4) camera to mat frame before and after the fit; ``allowed``: name ->
    (deg, mm) the placement's own reach (:meth:`MatPlacement.allowed_moves`), None: the gate alone.
    The mat places a view from many dots on its own to about 0.1 deg / 2 mm (measured on the
    family); a fit that moves one farther has slid along what the object's points leave free (a
    smooth or symmetric object, or a depth residual the points cannot tell from a pose), and the
    placement is the better of the two. A view placed from few dots holds only to its own sigma:
    the fit moving it within :data:`DEPARTURE_Z` of them refines it (family draw 86: three dots
    placed a fandisk's view 0.69 deg off, +/- 0.27 deg, and the fit moved it 0.54 deg toward the
    truth). Held-out draw 91 (2026-12-05) had two runs whose fit moved one view by 3.1 and 4.0 of its
    placement's sigmas, both toward the truth; counted as departures at 3 sigmas they stood at the
    placements and came out 0.60 deg / 4.1 mm and 0.38 deg / 3.6 mm off, yet reliable. At 5 sigmas
    the rocker arm 780939817 came out 0.11 deg / 0.53 mm off; the fandisk's view still departs (the
    fit moved it 5.4 of its placement's sigmas along the sheet at the object).

    A move just beyond the gate is no evidence against the fit: the fit is surely beyond the gate
    only if it moved the view farther than the gate plus how far the placement itself may be off.
    Held-out draw 103 (2026-12-05) had two rocker arms whose fit moved one view by 0.17 deg / 3.1 mm
    and 0.21 deg / 3.2 mm; counted as departures they stood at the placements, 0.44 deg / 3.44 mm
    (truly wrong, reliable) and 0.25 deg / 2.31 mm off with scales +0.67 and +0.34 %; with the fit
    kept, 0.16 deg / 0.47 mm and 0.34 deg / 0.98 mm, -0.11 and +0.09 % (``bench/robustness/fit_kept``).
    The igea of that draw, whose fit moved three views by 0.78-1.23 deg / 4.8-7.9 mm, still departs
    (kept, that fit ended 1.15 deg / 8.4 mm off)."""
    out = {}
    allowed = allowed or {}
    for n, A, B in zip(names, start, end):
        E = B @ np.linalg.inv(A)
        deg, mm = rotation_angle_deg(E), displacement_at(E, centre_m) * 1e3
        a_deg, a_mm = allowed.get(n, (0.0, 0.0))
        if deg > max(gate_deg + margin[0], a_deg) or mm > max(gate_mm + margin[1], a_mm):
            out[n] = (round(deg, 3), round(mm, 2))
    return out


def calibration_beyond_gate(calibration_pose: dict | None, gate_deg: float, gate_mm: float) -> tuple | None:
    """(rotation [deg], displacement at the object [mm]) at p90 by which the depth calibration's own
    residual can move the joint fit's poses (:func:`~tofmetry.reconstruct._calibration_pose.calibration_pose`,
    the field alone, without the views' noise), when either exceeds the pose gate; None otherwise.

    The mat places each view from its dots on its own, and a calibration residual that bends the
    object's depth hardly moves those placements (measured on the family's mat runs whose calibration
    predicted 1.9-4.1 mm: placements within 0.2 deg / 2.3 mm). The joint fit matches the object's
    surfaces across the views, and the residual moves it as far as this prediction says (family draw
    70, a bunny on a 1.3 mm calibration: predicted 0.51 deg / 4.8 mm, the fit moved a view from
    0.11 deg / 1.3 mm to 0.36 deg / 3.9 mm off). Beyond the gate the placements are the better poses."""
    if not calibration_pose:
        return None
    deg = float((calibration_pose.get("rot_deg") or {}).get("p90", 0.0))
    mm = float((calibration_pose.get("object_mm") or {}).get("p90", 0.0))
    return (round(deg, 3), round(mm, 2)) if deg > gate_deg or mm > gate_mm else None


def judge_placements(verdict: dict, mat: MatPlacement, unsure: tuple | None, kept: dict | None, gate_deg: float,
                     gate_mm: float) -> None:
    """The verdict (``verdict``: its ``warnings``, ``reasons`` and ``reliable``, in place) of a scan whose
    mat placements stand unrefined: because the depth calibration's residual could move the joint fit
    beyond the gate (``unsure``: :func:`calibration_beyond_gate`), or because the fit slid views
    beyond it (``kept``: :func:`departures`). Then a placement the mat alone does not hold within the
    gate (:meth:`MatPlacement.loose_views`) makes the run unreliable."""
    if unsure:
        verdict["warnings"].append(
            f"the depth calibration's residual could move the joint fit's poses by up to {unsure[0]:g} deg / "
            f"{unsure[1]:g} mm at the object (p90), beyond the pose gate ({gate_deg:g} deg / {gate_mm:g} mm): the "
            "dot mat's placements are kept, unrefined")
    if kept:
        verdict["warnings"].append(
            "the joint fit moved view(s) " + ", ".join(f"{n} by {d:.2f} deg / {m:.1f} mm" for n, (d, m) in kept.items())
            + f" at the object from where the dot mat placed them (beyond the pose gate, {gate_deg:g} deg / "
            f"{gate_mm:g} mm, plus how far placements are off at p99, {PLACEMENT_P99[0]:g} deg / "
            f"{PLACEMENT_P99[1]:g} mm): it slid along what the object's points leave free; the mat's placements "
            "are kept, unrefined")
    loose = mat.loose_views(gate_deg, gate_mm) if unsure or kept else {}
    if loose:  # the placements stand unrefined, and the mat alone does not hold these within the gate
        verdict["reasons"].append(loose_reason(loose, gate_deg, gate_mm,
                                               "the depth calibration's residual could move it beyond the gate"
                                               if unsure else "it slid along what the object's points leave free"))
        verdict["reliable"] = False
