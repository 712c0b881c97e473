"""The joint-fit stage of a reconstruction: the global adjustment of the pose-graph poses set up
from the configuration, the depth calibration and the amplitude reference, checked by its
restart, and applied to the views.

:class:`~tofmetry.reconstruct.ReconstructionPipeline` calls :func:`joint_adjustment` between
the pose graph and the fusion; the algorithm itself is :func:`~tofmetry.reconstruct._adjust.global_adjust`.
"""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import transform_points
from tofmetry.errors import EstimationError
from tofmetry.pointcloud import project_to_local_planes
from tofmetry.reconstruct._adjust import AdjustView, global_adjust
from tofmetry.reconstruct._adjust_albedo import albedo_gradients
from tofmetry.reconstruct._adjust_apply import correct_views
from tofmetry.reconstruct._adjust_circle import turntable_path
from tofmetry.reconstruct._adjust_restart import came_back, pair_walks, restart_probe, tied_probe
from tofmetry.reconstruct._adjust_result import AdjustResult, keep_amplitude_if_it_explains
from tofmetry.reconstruct._amplitude import amplitude_log_ratio
from tofmetry.reconstruct._calibration_pose import calibration_pose, field_pose_response
from tofmetry.reconstruct._calibration_support import calibration_central_mm, calibration_gain_sigma, depth_field_prior
from tofmetry.reconstruct._config import ReconstructionConfig
from tofmetry.reconstruct._model_build import median_object_depth_m, object_depth_span_mm
from tofmetry.reconstruct._icp_stages import refine_pair
from tofmetry.reconstruct._regview import RegView
from tofmetry.reconstruct._scale_budget import PoseUncertainty, scale_budget


def curve_prior_mm(cfg: ReconstructionConfig, cal) -> float:
    """Prior standard deviation of the range curve's coefficients [mm]: configured, or the depth
    calibration's predicted central error between its stations (1 mm without one)."""
    rc = cfg.registration
    if rc.range_curve_prior_mm is not None:
        return float(rc.range_curve_prior_mm)
    e = calibration_central_mm(cal.prediction or {}) if cal is not None else None
    return float(e) if e else 1.0


def view_distance_spread(regs: list[RegView], poses: np.ndarray) -> float:
    """Relative spread (standard deviation over median) of the views' distances to the object:
    the depth [m], in each camera, of the centroid of all views' object points placed by ``poses``
    (V, 4, 4) camera to world. 0 on a turntable with the object on its axis; a hand-held loop
    varies it by several per cent. NaN with fewer than two views."""
    if len(regs) < 2:
        return float("nan")
    P = np.asarray(poses, float)
    c = np.concatenate([transform_points(r.obj_points, T) for r, T in zip(regs, P)]).mean(axis=0)
    z = np.einsum("vi,vi->v", P[:, :3, 2], c - P[:, :3, 3])  # along each camera's optical axis
    return float(np.std(z) / np.median(z))


def curve_degree_for(spread: float, cfg: ReconstructionConfig) -> tuple[int, str]:
    """The range curve's degree for views whose distances to the object spread by ``spread``
    (:func:`view_distance_spread`), with the reason.

    Views at different distances see the same surface at different ranges at about the same
    incidence and image position, which separates the range error from the errors that follow
    the image position and the incidence; a turntable's views, all at one distance, see a
    surface at another range only after it has turned, where those errors change too, and the
    higher terms then take up the per-pixel residual instead of the range's. Measured from the
    true poses (every error term, 25 family seeds): degree 5 left 3 of 16 hand-held scans beyond
    the pose gate instead of 7 and turned none wrong; on 9 turntables it made 4 worse and 2 better.
    """
    rc = cfg.registration
    base, hi, lim = rc.range_curve_degree, rc.range_curve_degree_varied, rc.range_varied_min
    if base and hi > base and np.isfinite(spread) and spread >= lim:
        return hi, (f"up to degree {hi}: the views' distances to the object vary by {100 * spread:.1f} % "
                    f"(>= {100 * lim:g} %), so they see the same surfaces at different ranges")
    if base and hi > base:
        return base, (f"up to degree {base}: the views' distances to the object vary by {100 * spread:.1f} % only "
                      f"(< {100 * lim:g} % for degree {hi})")
    return base, ""


def _views(regs: list[RegView]) -> list[AdjustView]:
    """The joint fit's view of each registration view (mid-voxel points and targets where there are)."""
    return [AdjustView(*(r.mid_points, r.mid_normals, r.icp_points, r.icp_normals, r.mid_amp, r.icp_amp, r.mid_ir,
                         r.icp_ir) if r.mid_points is not None else
                       (r.icp_points, r.icp_normals, r.icp_points, r.icp_normals, r.icp_amp, r.icp_amp, r.icp_ir,
                        r.icp_ir)) for r in regs]


def joint_adjustment(views, segs, regs: list[RegView], poses: np.ndarray, cfg: ReconstructionConfig, cal,
                     white_map: np.ndarray | None, progress, *, turntable: bool = False,
                     loops: list[dict] | None = None, edges=(), edge_ir=(),
                     yaw_free: bool = False, tied=(),
                     placed: tuple[np.ndarray, np.ndarray] | None = None,
                     tilt_measured_mm: float | None = None) -> tuple[AdjustResult | None, str | None]:
    """Global adjustment of the pose-graph poses ``poses`` (V, 4, 4) camera to world [m] (and the
    depth gain); applies the gain to ``views`` (depth and points) in place.

    ``turntable``: the poses start on a declared turntable (the pose prior is its accuracy).
    ``placed``: the poses were placed each on its own (on a dot mat, whose frame is the world): the
    pose prior is this (rotation [deg], displacement at the object [mm]), each (V, 3): per view, along
    the world's x, y, z (:meth:`~tofmetry.reconstruct._mat_stage.MatPlacement.prior`).
    ``loops``: the pose graph's loop closures (:func:`loop_closures`); half the worst one widens
    the pose prior (a loop that closes only to X deg leaves up to X / 2 on a view once spread).
    ``edges``: the pose graph's kept pairs (i, j); when the fit moved a view beyond the pose gate
    and its restart came back, those of that view are registered again from the joint fit
    (:func:`pair_walks`). ``edge_ir``: those pairs' IR albedo correlations (None where unknown);
    ``yaw_free``: one of them leaves the rotation about the vertical free (a surface of
    revolution): then the joint fit matches the albedo too, about the vertical only, when their
    median reaches ``adjust_albedo_min_corr`` (:mod:`tofmetry.reconstruct._adjust_albedo`); with
    ``adjust_albedo_weak_ratio`` (opt-in), on any object whose pairs see the pattern, along each view's
    weak directions instead.
    ``tilt_measured_mm``: the depth tilt's 1-sigma left after the scan measured it (the dot mat's
    dots; :func:`~tofmetry.reconstruct._calibration_support.depth_field_prior`), or None.
    ``tied``: the pose-graph poses (V, 4, 4) of the choices of pairwise hypotheses tied with the one
    ``poses`` come from; the fit is run from each too (:func:`tied_probe`, in ``AdjustResult.tied``).

    Returns
    -------
    (AdjustResult or None, failure): None and no failure when switched off; None and the reason
    when the adjustment failed (the pose-graph poses are then kept)
    """
    rc = cfg.registration
    if not rc.global_adjust:
        return None, None
    prior_deg, prior_mm = rc.adjust_prior_deg, rc.adjust_prior_mm
    if placed is not None:  # each view placed on its own: no loops, no turntable path
        prior_deg, prior_mm = (np.asarray(x, np.float64) for x in placed)
    elif turntable:  # the poses start on the declared turntable
        prior_deg, prior_mm = rc.turntable_accuracy_deg, rc.turntable_axis_mm
    elif prior_deg is not None and prior_mm is not None and loops:
        prior_deg = max(prior_deg, max(lp["closure_deg"] for lp in loops) / 2)
        prior_mm = max(prior_mm, max(lp.get("closure_object_mm", lp["closure_mm"]) for lp in loops) / 2)
    z_ref = median_object_depth_m(views, segs)
    span = object_depth_span_mm(views, segs)
    sg_cal = None if cal is None else calibration_gain_sigma(cal.prediction or {}, span)
    e_sys = rc.gain_systematic_mm
    if e_sys is None:  # opt-in: the calibration's predicted central error
        e_sys = (calibration_central_mm(cal.prediction or {}) if cal is not None else None) or 0.0
    av = _views(regs)
    weak = rc.adjust_albedo_weak_ratio
    albedo = (rc.adjust_albedo_min_corr is not None and bool(edge_ir)
              and (weak is not None or (yaw_free and segs[0].plane is not None))
              and float(np.median([c if c is not None else -1.0 for c in edge_ir])) >= rc.adjust_albedo_min_corr)
    vertical = None if segs[0].plane is None else poses[0][:3, :3] @ np.asarray(segs[0].plane[:3], np.float64)
    up = vertical if albedo and weak is None else None
    circle = (None if turntable or placed is not None or rc.turn_axis_mm is None else
              turntable_path(poses, vertical, rc.turn_axis_detect_mm * 1e-3))
    if rc.adjust_target_smooth_k:  # the targets without their noise (tofmetry.pointcloud._smooth)
        for a in av:
            a.target = project_to_local_planes(a.target, rc.adjust_target_smooth_k, a.target_normals,
                                               rc.adjust_target_smooth_deg)
    if albedo:  # once for every run of the joint fit below (its restart, the amplitude variant)
        for a in av:
            a.target_ir_gradient = albedo_gradients(a.target, a.target_normals, a.target_ir)
    amp_prior = rc.amplitude_k_prior_mm if white_map is not None else None
    degree, degree_why = curve_degree_for(view_distance_spread(regs, poses), cfg)
    if placed is not None and not rc.mat_range_curve:  # views placed on a mat: no range curve to slide them along
        degree, degree_why = 0, ""
    field = None if cal is None else depth_field_prior(cal.prediction or {}, span,
                                                       regs[0].intr, tilt_sigma_mm=rc.uncalibrated_tilt_mm,
                                                       z_ref_m=z_ref if rc.predict_gain_pose else None,
                                                       tilt_measured_mm=tilt_measured_mm)
    tilt_prior = None if rc.image_tilt_prior_mm is None or (
        cal is not None and (cal.prediction or {}).get("tilt_calibrated")) else rc.image_tilt_prior_mm * 1e-3

    def run(amplitude_prior_mm: float | None, start: np.ndarray = poses) -> AdjustResult:
        return global_adjust(av, start, z_ref, tuple(x * 1e-3 for x in rc.adjust_radii_mm), rc.adjust_iters,
                             estimate_gain=rc.estimate_depth_gain, gain_prior_sigma=rc.depth_gain_prior,
                             gain_max_sigma=rc.gain_max_sigma, sigma_inflation=rc.sigma_inflation,
                             gain_max_abs=None if sg_cal is None else rc.gain_max_calibration_sigmas * sg_cal,
                             systematic_m=e_sys * 1e-3, curve_degree=degree,
                             curve_prior_m=curve_prior_mm(cfg, cal) * 1e-3,
                             amplitude_prior_m=None if amplitude_prior_mm is None else amplitude_prior_mm * 1e-3,
                             pose_prior_deg=prior_deg, pose_prior_m=None if prior_mm is None else prior_mm * 1e-3,
                             tilt_prior_m=tilt_prior, albedo=albedo, up=up, prior_poses=poses,
                             symmetric_normals=rc.adjust_symmetric_normals,
                             support_planes=[sg.plane for sg in segs] if rc.support_plane_deg is not None else None,
                             support_sigma=None if rc.support_plane_deg is None else (rc.support_plane_deg,
                                                                                      rc.support_plane_mm * 1e-3),
                             circle_up=None if circle is None else vertical,
                             circle_sigma_m=None if circle is None else rc.turn_axis_mm * 1e-3,
                             albedo_weak_ratio=weak, extrapolate=rc.adjust_extrapolate)

    with progress("global adjustment", None):
        try:
            res = run(None)
            if amp_prior is not None:
                res = keep_amplitude_if_it_explains(res, run(amp_prior), rc.amplitude_min_rms_drop)
            if rc.restart_check and float(np.max(res.moved_deg)) > rc.pose_gate_deg / 2:
                res.restart = _restart(res, poses, regs, cfg, lambda S: run(
                    amp_prior if res.amplitude_estimated else None, S).poses)
                _pair_walks(res, regs, edges, cfg)
            if len(tied):
                res.tied = _tied(res, tied, regs, lambda S: run(amp_prior if res.amplitude_estimated else None, S).poses)
            if degree_why and res.range_curve_m is not None:
                res.range_curve_note = f"{res.range_curve_note} ({degree_why})"
            if field is not None:  # once, on the adjustment kept
                res.field_response = (field_pose_response(res, field), field)
                res.calibration_pose = calibration_pose(res, field, res.field_response[0])
        except EstimationError as exc:  # keep the pose-graph poses; the reason goes to the diagnostics
            return None, str(exc)
    if circle is not None and res.turn_axis is not None:
        res.turn_axis["detected"] = circle
    correct_views(views, segs, res, z_ref, regs[0].intr, white_map, cfg.segment.plane_threshold_mm * 1e-3)
    return res, None


def _restart(res: AdjustResult, start: np.ndarray, regs: list[RegView], cfg: ReconstructionConfig, rerun) -> dict:
    """:func:`restart_probe` of the adjustment ``res`` started at ``start`` (``rerun``: the same
    adjustment from other poses), measured on ~5000 of the views' object points (not the ground
    ring); a restart that fails says why (``{"failed": reason}``; the verdict weighs it)."""
    try:
        return restart_probe(res.poses, start, rerun, _object_sample(res, regs), cfg.registration.pose_gate_deg)
    except EstimationError as exc:
        return {"failed": str(exc)}


def _tied(res: AdjustResult, starts, regs: list[RegView], rerun) -> list[dict]:
    """:func:`tied_probe` of the adjustment ``res`` from the tied choices' poses ``starts``, measured
    as :func:`_restart` does; a fit that fails says why (``{"failed": reason}``)."""
    try:
        return tied_probe(res.poses, list(starts), rerun, _object_sample(res, regs))
    except EstimationError as exc:
        return [{"failed": str(exc)}]


def _object_sample(res: AdjustResult, regs: list[RegView]) -> np.ndarray:
    """~5000 of the views' object points (not the ground ring) placed by the adjustment ``res``,
    (N, 3) world [m]: where a probe's displacement at the object is measured."""
    obj = np.concatenate([transform_points(r.obj_points, T) for r, T in zip(regs, res.poses)])
    return obj[:: max(1, len(obj) // 5000)]


def _pair_walks(res: AdjustResult, regs: list[RegView], edges, cfg: ReconstructionConfig) -> None:
    """When the fit moved a view beyond the pose gate and its restart came back, the kept pairs
    of that view registered again from the joint fit (:func:`pair_walks`), in ``res.restart["pairs"]``."""
    rc = cfg.registration
    w = int(np.argmax(res.moved_deg))
    if float(res.moved_deg[w]) <= rc.pose_gate_deg or not came_back(res.restart, rc.pose_gate_deg, rc.pose_gate_mm,
                                                                     rc.restart_share):
        return
    mine = [(i, j) for i, j in edges if w in (i, j)]
    res.restart["pairs"] = pair_walks(res.poses, mine, lambda i, j, init: refine_pair(regs[i], regs[j], init, rc),
                                      [r.obj_points for r in regs])


def scale_budget_of(views, segs, poses: np.ndarray, intr, z_ref: float, white_map: np.ndarray | None,
                    k_sigma_mm: float, adjustment: AdjustResult | None = None):
    """``(offset_sigma_m, gain_sigma) -> dict``: :func:`scale_budget` on the object points of
    ``views`` placed by ``poses`` (camera to world, the frame of the joint fit's increments), the gain
    acting about ``z_ref`` [m], with the amplitude term (coefficient uncertainty ``k_sigma_mm``) when an
    amplitude reference was given, and the poses' term when the joint fit ``adjustment`` carries its
    pose covariance or its response to the calibration's residual field."""
    pts = [v.points[s.object_mask] for v, s in zip(views, segs)]
    nrm = [v.normals[s.object_mask] for v, s in zip(views, segs)]
    L = None
    if white_map is not None and all(v.ir is not None for v in views):
        L = [amplitude_log_ratio(v.depth_mm, v.ir, white_map, intr).ravel()[v.index[s.object_mask]]
             for v, s in zip(views, segs)]
    free = None
    if adjustment is not None and (adjustment.pose_covariance is not None or adjustment.field_response is not None):
        resp, prior = adjustment.field_response or (None, None)
        free = PoseUncertainty(adjustment.pose_covariance, resp,
                               None if prior is None else prior.coefficient_sigmas(),
                               None if prior is None else prior.basis)

    def budget(offset_sigma_m: float, gain_sigma: float) -> dict:
        return scale_budget(pts, nrm, poses, z_ref, L, offset_sigma_m, gain_sigma, k_sigma_mm * 1e-3, poses_free=free)
    return budget
