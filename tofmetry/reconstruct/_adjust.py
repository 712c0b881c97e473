"""Global adjustment: all views registered jointly (multi-view point-to-plane), with an optional
self-calibrated depth gain.

Why a joint adjustment: pairwise ICP + pose graph averages *pairwise* transforms; an edge whose
ICP slid (small overlap, prism-like object) pulls the graph, and the graph never looks at the
points again. Here every view's points are matched against every other view's surface at the
current poses and all poses move together (Gauss-Newton, Huber weights, view 0 fixed), iterated.

Why a depth gain: a depth calibration from a few wall stations leaves a range-dependent residual
between the stations (wiggling, study §4.2.2). Over the few decimetres of depth an object spans,
it is mostly linear: ``dz = g (z - z_ref)``. Such a depth-only stretch is not a rigid or similar
transformation of the object (each view stretches it along its own line of sight), so views of
a 360-degree scan disagree unless it is corrected, and pairwise registration turns the
disagreement into a rotation bias (measured: ~0.2 deg per edge for g = 0.55 %). The multi-view
residuals observe ``g`` (the shape of the object differs between views); a uniform scale is not
observable, which is why the model is zero at ``z_ref`` (the median object depth): the range
there stays the depth calibration's, only the local gain is estimated. It is estimated only when
the views determine it, counting the calibration's own residual as an error common to whole views
(:func:`~tofmetry.reconstruct._adjust_sigma.gain_sigmas`); a weak prior (``gain_prior_sigma``)
keeps ``g`` near 0 otherwise.

Points move along their rays: ``p' = p (z + g (z - z_ref)) / z`` (camera frame, ``z`` = Z).

Why an amplitude-bias correction: dark and oblique surfaces read long by ``k ln(A_white / A)``
(study §3.3.1; :mod:`tofmetry.reconstruct._amplitude`), and the preprocessing removes it with a
fixed ``k`` (6.7 mm per ln unit, the study's). A sensor's own ``k`` differs (the virtual family
draws 4-9 mm); the rest shifts every surface along the rays by ``dk ln(A_white / A)``, more on dark
and oblique parts. One point seen by two views at different incidences gets different amplitudes,
so the views disagree unless ``dk`` is right: it is observable from the scan itself. When the views
carry ``ln(A_white / A)`` per point (``source_amp``, ``target_amp``), ``dk`` [m per ln unit] is an
unknown like the gain (``Z -> Z - dk ln(A_white / A)``), estimated only when the data alone determine
it better than its prior (measured on a family draw with k = 8.3: model mean error 1.45 mm with
the fixed 6.7, 0.55 mm with the true k).
"""

from __future__ import annotations

import numpy as np

from tofmetry._shared.geometry import rotation_angle_deg
from tofmetry.errors import EstimationError, InputError
from tofmetry.reconstruct._adjust_albedo import albedo_gradients, albedo_terms
from tofmetry.reconstruct._adjust_circle import circle_terms, turn_axis_point
from tofmetry.reconstruct._adjust_field import DepthFieldPrior
from tofmetry.reconstruct._adjust_prior import pose_prior_terms
from tofmetry.reconstruct._adjust_result import AdjustResult
from tofmetry.reconstruct._adjust_sigma import (
    curve_sigmas,
    determined_terms,
    gain_sigmas,
    pose_covariance,
    pose_sigmas,
)
from tofmetry.reconstruct._adjust_support import moved_about_vertical, plane_spread, support_plane_terms
from tofmetry.reconstruct._adjust_terms import (
    AdjustView,
    _correlation_with_gain,
    _correspondences,
    _exp_se3,
    _normal_equations,
    apply_depth_gain,
    world_sources,
)
from tofmetry.reconstruct._calibration_pose import calibration_pose

__all__ = ["AdjustView", "TILT_MAX_PRIORS", "apply_depth_gain", "global_adjust"]


#: an image tilt estimated beyond this many prior standard deviations is refused (it traded with the
#: poses: measured -46 and -39 mm per unit on a vase and a plaque whose sensors had 8 and 4)
TILT_MAX_PRIORS = 3.0


def creep_factor(step: np.ndarray, prev_step: np.ndarray | None, max_extra: float, min_cos: float = 0.9) -> float:
    """How far to take a Gauss-Newton step of the poses when the fit creeps (1: as solved).

    With nearest-neighbour correspondences cut at the radius and Huber weights, the joint fit's
    steps along a weakly held direction shrink by a ratio ``rho`` each outer iteration while they
    point the same way (measured on a hand-held box: cos 0.9-0.99 between successive steps from the
    4th iteration on, ``rho`` ~0.9, still 0.05 mm an iteration after 24). The remaining way is then
    ``step rho / (1 - rho)``: the step is taken ``1 + min(rho / (1 - rho), max_extra)`` times
    (Besl and McKay's accelerated ICP, 1992). A step that turns (cos below ``min_cos``) or grows is
    taken as solved; so is any step when ``max_extra`` is 0.

    Parameters
    ----------
    step, prev_step : (6 (V - 1),) this and the previous outer iteration's pose increments
    max_extra : the most extra multiples of the step taken
    """
    if max_extra <= 0 or prev_step is None:
        return 1.0
    a, b = float(np.linalg.norm(step)), float(np.linalg.norm(prev_step))
    if a == 0.0 or b == 0.0 or a >= b or float(step @ prev_step) / (a * b) < min_cos:
        return 1.0
    rho = a / b
    return 1.0 + min(rho / (1.0 - rho), max_extra)


def global_adjust(views: list[AdjustView], poses: np.ndarray, z_ref_m: float, radii_m: tuple[float, ...] = (0.006, 0.003),
                  iters_per_radius: tuple[int, ...] = (2, 6), inner_iters: int = 1, huber_m: float | None = None,
                  estimate_gain: bool = True, gain_prior_sigma: float = 0.02, max_normal_deg: float = 45.0,
                  tol_deg: float = 1e-3, tol_m: float = 1e-5, gain_max_sigma: float | None = None,
                  sigma_inflation: float = 1.0, gain_max_abs: float | None = None,
                  systematic_m: float = 0.0, curve_degree: int = 0, curve_prior_m: float = 5e-4,
                  curve_half_span_m: float | None = None, amplitude_prior_m: float | None = None,
                  pose_prior_deg: float | None = None, pose_prior_m: float | None = None,
                  depth_field: DepthFieldPrior | None = None, tilt_prior_m: float | None = None,
                  albedo: bool = False, up: np.ndarray | None = None,
                  prior_poses: np.ndarray | None = None, symmetric_normals: bool = True,
                  support_planes: list | None = None, support_sigma: tuple[float, float] | None = None,
                  circle_up: np.ndarray | None = None, circle_sigma_m: float | None = None,
                  albedo_weak_ratio: float | None = None, extrapolate: float = 0.0) -> AdjustResult:
    """Jointly refine all poses (view 0 fixed) and, optionally, the depth gain.

    Each outer iteration matches every view's ``source`` points (gain-corrected, to world) to
    the nearest ``target`` point of every other view within the radius (orientations within
    ``max_normal_deg``); residual = point-to-plane distance along both points' normals (or the target's). Then ``inner_iters`` Gauss-Newton
    steps on these correspondences move all poses (6 parameters each, left-multiplied
    increments) and the gain, with Huber weights (``huber_m``, default radius / 3). After the
    first outer iteration at a radius only the pairs that had correspondences are searched.

    Parameters
    ----------
    views : list of AdjustView (camera frames)
    poses : (V, 4, 4) initial camera-to-world (e.g. the pose-graph solution)
    z_ref_m : depth [m] at which the gain correction is zero (median object depth)
    radii_m, iters_per_radius : correspondence radius schedule [m] and outer iterations at each
    gain_prior_sigma : prior standard deviation of the gain (keeps it at 0 when not observed)
    tol_deg, tol_m : stop (at the last radius) when no pose moves more than this in an outer iteration
    extrapolate : at the last radius, a step that points the way the previous one did and is shorter is
        taken up to ``1 + extrapolate`` times, as far as the two steps' ratio says the fit still has to
        creep (:func:`creep_factor`); 0: every step as solved
    gain_max_sigma : the gain is estimated only when the views observe it: its standard error from the
        data alone (poses marginalised, no prior, times ``sigma_inflation``), taken at the first
        iteration of the last radius, must be below this. Otherwise it is fixed at 0 from then on and
        :attr:`AdjustResult.gain_note` says why. None: always estimated (with the prior)
    sigma_inflation : factor on the standard errors from the normal equations (correspondences
        are not independent: neighbouring points of one view share their depth error)
    gain_max_abs : largest plausible gain (e.g. a few times what the depth calibration can leave
        between its stations). An estimated gain beyond it is refused: the adjustment is run again
        from ``poses`` with the gain fixed at 0 and :attr:`AdjustResult.gain_note` starts with
        "implausible" (the views then disagree by more than the calibration allows: a smooth
        object lets a wrong pose and a gain trade against each other, measured -5 % on a pebble
        whose poses were 1.2 deg off). None: no bound
    systematic_m : depth error [m] common to whole views that the noise model does not cover (the
        depth calibration's predicted error between its stations): it enters the gain's standard
        error (:func:`gain_sigmas`). Without it, the residuals of a few hundred thousand points
        make any gain look determined, and the gain and the poses trade along a valley whose
        bottom such an error decides (measured: -1.7 % and 1.1 deg from the true poses on a clean
        simulated sensor, where fixing the gain kept the poses within 0.1 deg)
    curve_degree : 0 (off) or the highest Legendre degree (>= 2) of a range-error curve shared by
        all views (:mod:`tofmetry.reconstruct._range_curve`), estimated with the poses and the gain
    curve_prior_m : prior standard deviation of each curve coefficient [m] (the residual the depth
        calibration can leave); the curve is estimated only when the data alone (poses and gain
        marginalised, times ``sigma_inflation``) determine every coefficient better than this prior,
        checked at the first iteration and at the first of the last radius; otherwise its highest
        terms are left out while that makes the rest determined (:func:`determined_terms`: two terms
        the views cannot tell apart over a shallow object), and when not even the lowest is, it stays
        0; :attr:`AdjustResult.range_curve_note` says which
    curve_half_span_m : half the depth span of the curve [m]; None: the largest distance from
        ``z_ref_m`` of the central 98 % of all views' ``source`` depths
    amplitude_prior_m : prior standard deviation of the amplitude-bias correction ``dk`` [m per ln
        unit]; None: not estimated (also when a view carries no ``source_amp`` / ``target_amp``).
        Estimated only when the data alone (poses, curve and gain marginalised, times
        ``sigma_inflation``) determine it better than this prior, checked like the curve
    pose_prior_deg, pose_prior_m : standard deviations [deg], [m] of a Gaussian prior holding each view
        near its initial pose (rotation; displacement of the object centre, the mean of the initial
        world points), weighed against the data at their inflated uncertainty
        (:mod:`tofmetry.reconstruct._adjust_prior`): it holds the directions the points leave free
        (the axis of a surface of revolution). None: no prior
    prior_poses : (V, 4, 4) where that prior holds the views (default ``poses``): a restart from other
        poses keeps the prior of the fit it checks, so that it minimises the same objective
    depth_field : the size of the per-pixel depth residual the calibration leaves; the poses' spread
        under such fields (:func:`~tofmetry.reconstruct._calibration_pose.calibration_pose`) is returned
        as :attr:`AdjustResult.calibration_pose`. None: not predicted here (the function can be asked
        for later)
    tilt_prior_m : prior standard deviation of a depth error linear in the image position,
        ``Z -> Z + a x + b y`` (``x = X / Z``, ``y = Y / Z``) [m per unit]: a calibration from walls
        of unknown orientation cannot tell it from the walls' tilt and leaves it in. Estimated,
        like ``dk``, only when the data alone determine both coefficients better than this prior;
        None: not estimated
    albedo : the IR albedo of the views (``source_ir``, ``target_ir``) as a term beside the geometry
        (:mod:`tofmetry.reconstruct._adjust_albedo`): it fixes the rotation a surface of revolution
        leaves free where a pattern is painted or printed on it. Ignored when a view carries no albedo
    up : (3,) the vertical (support-plane normal) in the frame of ``poses``: the albedo term then acts
        only on each view's rotation about the vertical through the object's centre (the mean of the
        initial world points); None: on all six degrees of freedom
    symmetric_normals : the residual along the normalised sum of both points' normals (the symmetric
        point-to-plane of Rusinkiewicz 2019), or along the target's normal (False). The source normals
        come from the sparser, unsmoothed ``source`` cloud; with them the fit started at the true poses
        with the sensor's noise alone shrank a box's model by 0.30 mm (0.10 mm with the target's normal),
        and with every error term it ended beyond the pose gate on 8 of 12 family scans instead of 5.
        Started from the registrations, though, the target's form came out worse on 7 of 17 held-out
        scans and better on 2 (``bench/robustness/README.md``): it stays the option
    support_planes : per view (4,) its support plane in its camera frame (``n . p + d = 0`` [m]) or
        None; with ``support_sigma`` ``(deg, m)``, how far one view's plane can sit from the others'
        (tilt [deg], height [m]), the planes placed by the poses are held to one plane
        (:mod:`tofmetry.reconstruct._adjust_support`). None: not used
    circle_up, circle_sigma_m : the vertical (3,) in the frame of ``poses`` and a standard deviation [m]:
        the views were taken on a turntable, and every view's motion from view 0 is held to a turn
        about one vertical axis (:mod:`tofmetry.reconstruct._adjust_circle`). None: not used
    albedo_weak_ratio : with ``albedo`` and no ``up``: the albedo term acts on each view only along the
        directions of its pose where its information is at least this many times the geometry's
        (:func:`~tofmetry.reconstruct._adjust_albedo.weak_bases`, recomputed at every step: the
        turn about a vase's own axis, the slide along a bar). None: on all six degrees of freedom

    Returns
    -------
    AdjustResult (``depth_gain_sigma`` treats correspondences as independent: a lower bound)

    Raises
    ------
    InputError on inconsistent inputs; EstimationError when the views have (almost) no
    correspondences at the initial poses.
    """
    V = len(views)
    poses = np.asarray(poses, np.float64)
    if V < 2 or poses.shape != (V, 4, 4):
        raise InputError(f"global adjustment: need >= 2 views and (V, 4, 4) poses, found {V} views, poses {poses.shape}")
    if len(radii_m) != len(iters_per_radius):
        raise InputError("global adjustment: radii_m and iters_per_radius must have the same length")
    if not np.isfinite(poses).all():
        raise InputError("global adjustment: the initial poses are not all finite")
    P = poses.copy()
    g = 0.0
    asked_gain = estimate_gain
    prior_on = pose_prior_deg is not None and pose_prior_m is not None
    planes_on = support_planes is not None and support_sigma is not None and len(support_planes) == V
    plane_info: dict = {"used": False, "note": "not asked for" if support_planes is None else "no planes"}
    if planes_on:
        plane_info = {"start": plane_spread(poses, support_planes)}
    circle_on = circle_up is not None and circle_sigma_m is not None and V >= 3
    held_at = poses if prior_poses is None else prior_poses  # where the pose prior holds the views
    centre = world_sources(views, held_at).mean(0) if prior_on else None
    cos_max = np.cos(np.radians(max_normal_deg))
    rms_hist: list[float] = []
    schedule = [r for r, n in zip(radii_m, iters_per_radius) for _ in range(n)]
    n_last = iters_per_radius[-1]
    converged = False
    sigma_g = np.inf
    counts = np.zeros((V, V), np.int64)
    pair_rms = np.full((V, V), np.nan)
    pairs, prev_r, it = None, None, 0
    prev_step = None  # the last Gauss-Newton step of the poses, (6 (V - 1),)
    sigma_data = sigma_sys = float("nan")
    note = "not asked for" if not estimate_gain else "estimated"
    H_data = None
    # range curve: coefficients [m], active flag, half span
    D = max(int(curve_degree) - 1, 0)
    c_curve = np.zeros(D)
    if curve_half_span_m is None and D:
        zs = np.concatenate([v.source[:, 2] for v in views])
        lo, hi = np.percentile(zs, [1, 99])
        curve_half_span_m = float(max(hi - z_ref_m, z_ref_m - lo, 1e-3))
    curve_on = D > 0
    curve_note = "estimated" if D else "not asked for"
    curve_sd = np.full(D, np.nan)
    curve_cov = np.zeros((D, D))
    curve_checked = False
    curve_cut = ""  # what the views left undetermined above the degree kept
    # amplitude bias: dk [m per ln unit], active flag
    amp_on = amplitude_prior_m is not None and all(v.source_amp is not None and v.target_amp is not None
                                                   for v in views)
    amp_note = "estimated" if amp_on else ("not asked for" if amplitude_prior_m is None
                                           else "not available: a view carries no amplitude regressor")
    a_k, amp_sd, amp_var, amp_corr, amp_slope = 0.0, float("nan"), float("nan"), float("nan"), float("nan")
    amp_checked = False
    # image tilt: (a, b) [m per unit of x / z, y / z], active flag
    tilt_on = tilt_prior_m is not None
    tilt_note = "estimated" if tilt_on else "not asked for"
    t_xy, tilt_sd, tilt_cov = np.zeros(2), np.full(2, np.nan), np.zeros((2, 2))
    tilt_checked = False
    # zero at the views' mean image position: otherwise a tilt over an object off the image centre acts
    # as a depth offset there, and takes up the offset that noise gives nearest-neighbour pairs on
    # curved surfaces (measured: -1.8 mm per unit on a noisy synthetic ring scan whose truth is 0)
    tilt_centre = (np.concatenate([v.source[:, :2] / v.source[:, 2:3] for v in views]).mean(0) if tilt_on
                   else np.zeros(2))

    # IR albedo term: the targets' albedo gradients once (camera frames; the poses rotate them)
    alb_on = albedo and all(v.source_ir is not None and v.target_ir is not None for v in views)
    alb_src = [(v.source, v.source_ir) for v in views] if alb_on else None
    alb_tgt = ([(v.target, v.target_ir, v.target_ir_gradient if v.target_ir_gradient is not None else
                 albedo_gradients(v.target, v.target_normals, v.target_ir)) for v in views] if alb_on else None)
    alb_axis = None if up is None or not alb_on else (np.asarray(up, np.float64), world_sources(views, poses).mean(0))
    alb_info: dict = {"used": False, "note": "not asked for" if not albedo else "not available: a view carries no albedo"}
    alb_weak = None
    if alb_on and alb_axis is None and albedo_weak_ratio is not None:
        pts = world_sources(views, poses)
        c0 = pts.mean(0)
        alb_weak = (c0, float(np.sqrt(np.mean(np.sum((pts - c0) ** 2, 1)))), float(albedo_weak_ratio))

    def ne(with_gain: bool):
        """The normal equations of the correspondences, with the albedo term when it is on."""
        out = _normal_equations(views, P, g, z_ref_m, corr, k, with_gain, cv(), ampv(), tv(), symmetric=symmetric_normals)
        if alb_on:
            Ha, ba, info = albedo_terms(P, alb_src, alb_tgt, corr, len(out[1]), out[2], alb_axis,
                                        None if alb_weak is None else (out[0], *alb_weak))
            out[0][:] += Ha
            out[1][:] += ba
            alb_info.update(used=True, note="used", **info)
        return out

    def cv():
        return (c_curve, curve_half_span_m) if curve_on else None

    def ampv():
        return a_k if amp_on else None

    def tv():
        return (t_xy, tilt_centre) if tilt_on else None

    def n_extra():
        return (D if curve_on else 0) + int(amp_on) + 2 * int(tilt_on)

    def without_curve(H):
        if not n_extra():
            return H
        keep = np.r_[np.arange(6 * (V - 1)), len(H) - 1]
        return H[np.ix_(keep, keep)]

    for it, r in enumerate(schedule, start=1):
        if r != prev_r:
            pairs, prev_r = None, r
        corr = _correspondences(views, P, g, z_ref_m, r, cos_max, pairs, cv(), ampv(), tv())
        pairs = {(i, j) for i, j, _, _ in corr}
        if sum(len(c[2]) for c in corr) < 6 * V:
            raise EstimationError(f"global adjustment: too few correspondences between the views at {r * 1e3:.1f} mm "
                             "(views do not overlap at the initial poses)")
        k = huber_m if huber_m is not None else r / 3.0
        P_start = P.copy()
        for _ in range(inner_iters):
            H, b, s2, counts, pair_rms, sw = ne(estimate_gain)
            check = it == 1 or (r == radii_m[-1] and it == len(schedule) - n_last + 1)
            if check and ((curve_on and not curve_checked) or (amp_on and not amp_checked)
                          or (tilt_on and not tilt_checked)):
                sd = curve_sigmas(H, s2, sigma_inflation, n_extra(), estimate_gain)
                i_amp = D if curve_on else 0
                i_tilt = i_amp + int(amp_on)
                off = False
                if curve_on and not curve_checked:
                    curve_sd, curve_checked = sd[:D], r == radii_m[-1]
                    if not np.all(curve_sd < curve_prior_m):
                        sds = ", ".join(f"{x * 1e3:.3f}" for x in curve_sd)
                        kept, kept_sd = determined_terms(H, s2, sigma_inflation, D, n_extra() - D, 6 * (V - 1),
                                                         estimate_gain, curve_prior_m)
                        if kept:  # the lower terms the views determine: the curve up to that degree
                            curve_cut = (f"; up to degree {kept + 1} only (up to degree {D + 1} the views determine "
                                         f"its coefficients only to +-{sds} mm, prior +-{curve_prior_m * 1e3:.3f} mm)")
                            D, c_curve, curve_sd, off = kept, c_curve[:kept], kept_sd, True
                        else:
                            curve_note = (f"not observable: the views determine its coefficients only to +-{sds} mm "
                                          f"(prior +-{curve_prior_m * 1e3:.3f} mm); kept at 0")
                            curve_on, c_curve, off = False, np.zeros(D), True
                if amp_on and not amp_checked:
                    amp_sd, amp_checked = float(sd[i_amp]), r == radii_m[-1]
                    amp_corr, amp_slope = (_correlation_with_gain(H, 6 * (V - 1) + i_amp)
                                           if estimate_gain else (0.0, 0.0))
                    if not amp_sd < amplitude_prior_m:
                        amp_note = (f"not observable: the views determine dk only to +-{amp_sd * 1e3:.2f} mm per ln "
                                    f"unit (prior +-{amplitude_prior_m * 1e3:.2f}); kept at 0")
                        amp_on, a_k, off = False, 0.0, True
                if tilt_on and not tilt_checked:
                    tilt_sd, tilt_checked = sd[i_tilt:i_tilt + 2], r == radii_m[-1]
                    if not np.all(tilt_sd < tilt_prior_m):
                        tilt_note = ("not observable: the views determine it only to +-"
                                     + ", ".join(f"{x * 1e3:.2f}" for x in tilt_sd)
                                     + f" mm per unit (prior +-{tilt_prior_m * 1e3:.2f}); kept at 0")
                        tilt_on, t_xy, off = False, np.zeros(2), True
                if off:
                    H, b, s2, counts, pair_rms, sw = ne(estimate_gain)
            H_data = without_curve(H).copy()
            if estimate_gain:
                sigma_data, sigma_sys = gain_sigmas(H_data, s2, sw, sigma_inflation, systematic_m)
                # with a systematic error, checked at the start too: a gain left free while it is not
                # observable walks the poses along the gain-pose valley before the last radius
                first = it == 1 and systematic_m > 0
                if gain_max_sigma is not None and (first or (r == radii_m[-1] and it == len(schedule) - n_last + 1)) \
                        and not sigma_data <= gain_max_sigma:
                    note = (f"not observable: the views determine it only to +-{100 * sigma_data:.2f} % "
                            f"(> {100 * gain_max_sigma:.2f} %); kept at 0")
                    estimate_gain, g = False, 0.0
                    H, b, s2, counts, pair_rms, sw = ne(False)
                    H_data = without_curve(H).copy()
            if estimate_gain:
                H[-1, -1] += s2 / gain_prior_sigma ** 2  # prior g ~ N(0, sigma) in residual units
                b[-1] += s2 / gain_prior_sigma ** 2 * g
            else:
                H[-1, -1], b[-1] = 1.0, 0.0
            if curve_on:
                cc = np.arange(6 * (V - 1), 6 * (V - 1) + D)
                H[cc, cc] += s2 / curve_prior_m ** 2  # prior c_k ~ N(0, curve_prior_m)
                b[cc] += s2 / curve_prior_m ** 2 * c_curve
            if amp_on:
                ai = 6 * (V - 1) + (D if curve_on else 0)
                # prior dk ~ N(0, amplitude_prior_m), against the data at their inflated uncertainty
                H[ai, ai] += s2 * sigma_inflation ** 2 / amplitude_prior_m ** 2
                b[ai] += s2 * sigma_inflation ** 2 / amplitude_prior_m ** 2 * a_k
            if tilt_on:
                ti = 6 * (V - 1) + (D if curve_on else 0) + int(amp_on) + np.arange(2)
                H[ti, ti] += s2 * sigma_inflation ** 2 / tilt_prior_m ** 2  # prior a, b ~ N(0, tilt_prior_m)
                b[ti] += s2 * sigma_inflation ** 2 / tilt_prior_m ** 2 * t_xy
            if prior_on:
                Hp, bp = pose_prior_terms(P, held_at, centre, np.radians(pose_prior_deg), pose_prior_m,
                                          s2 * sigma_inflation ** 2)
                H[:len(bp), :len(bp)] += Hp
                b[:len(bp)] += bp
            if planes_on:
                Hs, bs, _ = support_plane_terms(P, support_planes, np.radians(support_sigma[0]), support_sigma[1],
                                                s2 * sigma_inflation ** 2)
                H[:len(bs), :len(bs)] += Hs
                b[:len(bs)] += bs
            if circle_on:
                Hc, bc = circle_terms(P, circle_up, circle_sigma_m, s2 * sigma_inflation ** 2)
                H[:len(bc), :len(bc)] += Hc
                b[:len(bc)] += bc
            n_all = len(H)
            H += np.eye(n_all) * 1e-12 * np.trace(H) / n_all  # numerical damping only
            H_solve = H
            dx = -np.linalg.solve(H, b)
            step = dx[:6 * (V - 1)].copy()
            grow = creep_factor(step, prev_step, extrapolate) if r == radii_m[-1] else 1.0
            prev_step = step
            for v in range(1, V):
                P[v] = _exp_se3(grow * dx[6 * (v - 1):6 * v]) @ P[v]
            if curve_on:
                c_curve = c_curve + dx[cc]
                curve_cov = np.linalg.inv(H)[np.ix_(cc, cc)] * s2 * sigma_inflation ** 2
            if tilt_on:
                t_xy = t_xy + dx[ti]
                tilt_cov = np.linalg.inv(H)[np.ix_(ti, ti)] * s2 * sigma_inflation ** 2
            if amp_on:
                a_k += float(dx[ai])
                amp_var = float(np.linalg.inv(H)[ai, ai]) * s2 * sigma_inflation ** 2
            if estimate_gain:
                g += float(dx[-1])
                sigma_g = float(np.hypot(np.sqrt(max(np.linalg.inv(H)[-1, -1] * s2, 0.0)), sigma_sys))
            else:
                sigma_g = 0.0
        rms_hist.append(float(np.sqrt(s2)) * 1e3)
        moved = [np.linalg.inv(P_start[v]) @ P[v] for v in range(V)]
        max_rot = max(rotation_angle_deg(E) for E in moved)
        max_t = max(np.linalg.norm(E[:3, 3]) for E in moved)
        if r == radii_m[-1] and it > len(schedule) - n_last and max_rot < tol_deg and max_t < tol_m:
            converged = True
            break
    moved_deg, moved_mm = np.zeros(V), np.zeros(V)
    for v in range(V):
        E = np.linalg.inv(poses[v]) @ P[v]
        moved_deg[v] = rotation_angle_deg(E)
        moved_mm[v] = np.linalg.norm(E[:3, 3]) * 1e3
    if tilt_on and np.max(np.abs(t_xy)) > TILT_MAX_PRIORS * tilt_prior_m:
        fixed = global_adjust(views, poses, z_ref_m, radii_m, iters_per_radius, inner_iters, huber_m, asked_gain,
                              gain_prior_sigma, max_normal_deg, tol_deg, tol_m, gain_max_sigma, sigma_inflation,
                              gain_max_abs, systematic_m, curve_degree, curve_prior_m, curve_half_span_m,
                              amplitude_prior_m, pose_prior_deg, pose_prior_m, depth_field, None, albedo, up,
                              prior_poses, symmetric_normals, support_planes, support_sigma, circle_up, circle_sigma_m,
                              albedo_weak_ratio, extrapolate)
        fixed.image_tilt_sigma_data_m = tilt_sd
        fixed.image_tilt_note = ("implausible: the views ask for " + ", ".join(f"{x * 1e3:+.1f}" for x in t_xy)
                                 + f" mm per unit, beyond {TILT_MAX_PRIORS:g} x its prior (+-{tilt_prior_m * 1e3:.1f}): "
                                 "it trades with the poses on this object; kept at 0")
        return fixed
    if estimate_gain and gain_max_abs is not None and abs(g) > gain_max_abs:
        fixed = global_adjust(views, poses, z_ref_m, radii_m, iters_per_radius, inner_iters, huber_m, False,
                              gain_prior_sigma, max_normal_deg, tol_deg, tol_m, None, sigma_inflation,
                              curve_degree=curve_degree, curve_prior_m=curve_prior_m,
                              curve_half_span_m=curve_half_span_m, amplitude_prior_m=amplitude_prior_m,
                              pose_prior_deg=pose_prior_deg, pose_prior_m=pose_prior_m, depth_field=depth_field,
                              tilt_prior_m=tilt_prior_m, albedo=albedo, up=up, prior_poses=prior_poses,
                              symmetric_normals=symmetric_normals, support_planes=support_planes,
                              support_sigma=support_sigma, circle_up=circle_up, circle_sigma_m=circle_sigma_m,
                              albedo_weak_ratio=albedo_weak_ratio, extrapolate=extrapolate)
        fixed.gain_sigma_data, fixed.gain_sigma_systematic = sigma_data, sigma_sys
        fixed.gain_refused, fixed.gain_max_abs = float(g), float(gain_max_abs)
        if np.isfinite(amp_slope):  # the gain's trade with dk, from this run where the gain was free
            fixed.amplitude_gain_correlation, fixed.amplitude_gain_slope = amp_corr, amp_slope
        fixed.gain_note = (f"implausible: the views ask for {100 * g:+.2f} % (+-{100 * sigma_data:.2f} %), beyond the "
                           f"+-{100 * gain_max_abs:.2f} % the depth calibration can leave; kept at 0")
        return fixed
    pose_cov = pose_covariance(H_data, s2, V, estimate_gain, sigma_inflation)
    sig_deg, sig_mm = pose_sigmas(pose_cov, V)
    if estimate_gain and note == "estimated":
        note = f"estimated: the views determine it to +-{100 * sigma_data:.3f} %"
    res = AdjustResult(P, g, sigma_g, z_ref_m, it, np.array(rms_hist), counts, pair_rms, moved_deg, moved_mm, converged,
                       estimate_gain, sigma_data, note, sig_deg, sig_mm, sigma_sys)
    res.final_state = (views, P.copy(), g, z_ref_m, corr, k, estimate_gain, cv(), ampv(), tv(), H_solve, pose_cov,
                       symmetric_normals)
    res.albedo = alb_info
    if planes_on:
        plane_info = {"used": True, "sigma_deg": float(support_sigma[0]), "sigma_mm": float(support_sigma[1]) * 1e3,
                      "start": plane_info["start"],
                      "end": plane_spread(P, support_planes)}
        res.moved_turn_deg = moved_about_vertical(poses, P, support_planes)
    res.support_plane = plane_info
    res.turn_axis = ({"used": True, "sigma_mm": float(circle_sigma_m) * 1e3,
                      "start_mm": [round(float(x) * 1e3, 3) for x in turn_axis_point(poses, circle_up)[1]],
                      "end_mm": [round(float(x) * 1e3, 3) for x in turn_axis_point(P, circle_up)[1]]}
                     if circle_on else None)
    if depth_field is not None:
        res.calibration_pose = calibration_pose(res, depth_field)
    res.image_tilt_m, res.image_tilt_estimated = (t_xy.copy(), True) if tilt_on else (np.zeros(2), False)
    res.image_tilt_centre = tilt_centre.copy()
    res.image_tilt_sigma_m = np.sqrt(np.clip(np.diag(tilt_cov), 0, None)) if tilt_on else np.full(2, np.nan)
    res.image_tilt_sigma_data_m = tilt_sd
    res.image_tilt_note = ("estimated: the views determine it to +-" + ", ".join(f"{x * 1e3:.2f}" for x in tilt_sd)
                           + " mm per unit (data alone)") if tilt_on else tilt_note
    res.amplitude_dk_m, res.amplitude_estimated = (a_k, True) if amp_on else (0.0, False)
    res.amplitude_dk_sigma_m = float(np.sqrt(max(amp_var, 0.0))) if amp_on else float("nan")
    res.amplitude_dk_sigma_data_m = amp_sd
    res.amplitude_gain_correlation = amp_corr
    res.amplitude_gain_slope = amp_slope
    res.amplitude_note = (f"estimated: the views determine dk to +-{amp_sd * 1e3:.2f} mm per ln unit (data alone)"
                          if amp_on else amp_note)
    if D:
        res.range_curve_m = c_curve.copy()
        res.range_curve_cov_m2 = curve_cov if curve_on else np.zeros((D, D))
        res.range_curve_sigma_m = np.sqrt(np.clip(np.diag(res.range_curve_cov_m2), 0, None))
        res.range_curve_sigma_data_m = curve_sd
        res.range_curve_half_span_m = float(curve_half_span_m)
        res.range_curve_prior_m = float(curve_prior_m)
        res.range_curve_estimated = bool(curve_on)
        res.range_curve_note = ("estimated: the views determine its coefficients to +-"
                                + ", ".join(f"{x * 1e3:.3f}" for x in curve_sd) + " mm (data alone)" + curve_cut) \
            if curve_on else curve_note
    return res
