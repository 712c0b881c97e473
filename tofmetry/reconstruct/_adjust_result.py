"""Result of the global adjustment (:func:`tofmetry.reconstruct._adjust.global_adjust`) and the
choice between the adjustments with and without the amplitude-bias correction."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tofmetry.reconstruct._range_curve import range_curve_m, range_curve_sigma_m


@dataclass
class AdjustResult:
    """Outcome of :func:`global_adjust`.

    Attributes
    ----------
    poses : (V, 4, 4) camera-to-world, view 0 unchanged
    depth_gain : estimated ``g`` (dimensionless; 0.005 = the depth reads 0.5 % of (z - z_ref) short)
    depth_gain_sigma : its standard error (from the Gauss-Newton normal matrix and the residual scale)
    z_ref_m : reference depth [m] where the gain correction is zero
    iterations : number of Gauss-Newton iterations run
    rms_mm : (iterations,) robust RMS point-to-plane residual per iteration [mm]
    pair_counts : (V, V) number of correspondences source view i -> target view j at the end
    pair_rms_mm : (V, V) their RMS point-to-plane residual [mm] (NaN without correspondences)
    moved_deg, moved_mm : (V,) how far each pose moved from the initial one [deg], [mm]
    converged : the last update was below the tolerance
    gain_estimated : whether the gain was estimated (asked for and observable)
    gain_sigma_data : standard error of the gain from the data alone (the poses marginalised, no
        prior; NaN when not asked for): what the views say about it, random part (noise, times the
        inflation) and systematic part (:attr:`gain_sigma_systematic`) combined
    gain_sigma_systematic : the part of ``gain_sigma_data`` that a systematic depth error of the
        views (``systematic_m`` of :func:`global_adjust`) leaves (NaN when not asked for)
    gain_note : why the gain was or was not estimated
    pose_sigma_deg, pose_sigma_mm : (V,) standard errors of each pose (rotation [deg], camera
        translation [mm]) from the normal equations, correspondences taken as independent (a lower
        bound: the residuals of one view are correlated; the range curve, when estimated, held fixed)
    range_curve_m : (D,) coefficients of the range-error curve [m] (:mod:`tofmetry.reconstruct._range_curve`;
        None when not asked for, zeros when not observable); ``range_curve_sigma_m``, ``range_curve_cov_m2``:
        their standard errors and covariance (noise only, times the inflation; no systematic part);
        ``range_curve_sigma_data_m``: from the data alone, no prior; ``range_curve_note``: why it was or was not estimated
    amplitude_dk_m, amplitude_dk_sigma_m, amplitude_dk_sigma_data_m, amplitude_estimated, amplitude_note :
        the amplitude-bias correction ``dk`` [m per ln unit] (:func:`keep_amplitude_if_it_explains`)
    amplitude_gain_correlation, amplitude_gain_slope : correlation of ``dk`` with the gain in the
        adjustment with ``dk`` free, and the gain's regression on it (gain per m per ln unit): how
        far the gain moves when ``k`` is wrong, which is how the amplitude coefficient's
        uncertainty enters the gain's (:func:`~tofmetry.reconstruct._scale_report.scale_report`)
    restart : the adjustment restarted from the far side of its solution
        (:func:`~tofmetry.reconstruct._adjust_restart.restart_probe`: ``deg``, ``mm``, ``view``,
        ``start_deg``, ``per_view_deg``; ``{"failed": reason}``), or None when not run
    tied : the adjustment run from the pose graph of each choice of pairwise hypotheses the selection
        found tied with its own (:func:`~tofmetry.reconstruct._adjust_restart.tied_probe`: per choice
        ``deg``, ``mm``, ``view``, ``per_view_deg``; ``[{"failed": reason}]``), or None when not run
    image_tilt_m, image_tilt_sigma_m, image_tilt_sigma_data_m, image_tilt_estimated, image_tilt_note :
        the depth error linear in the image position, ``Z -> Z + a x + b y`` ((a, b) [m per unit of
        ``x / z``, ``y / z``]; ``tilt_prior_m`` of :func:`~tofmetry.reconstruct._adjust.global_adjust`)
    calibration_pose : how far the calibration's per-pixel residual can move the poses
        (:func:`~tofmetry.reconstruct._adjust_field.pose_spread`: worst view's rotation [deg] and
        object displacement [mm], p50 and p90 over random fields of the calibration's size), or
        None when not predicted
    albedo : the IR albedo term of the joint fit (:mod:`~tofmetry.reconstruct._adjust_albedo`):
        ``used``, ``note``, and when used ``n`` (residuals), ``scale`` (their robust standard
        deviation, log albedo units), ``n_pairs``
    field_response : how the calibration's residual field moves the poses, ``(response, prior)``:
        (6 (V - 1), T) left increments per unit coefficient of each term of the
        :class:`~tofmetry.reconstruct._adjust_field.DepthFieldPrior` ``prior``
        (:func:`~tofmetry.reconstruct._calibration_pose.field_pose_response`), or None when not predicted;
        not reported
    moved_turn_deg : (V,) the part of ``moved_deg`` about the vertical [deg] when the support planes
        held the views (:func:`~tofmetry.reconstruct._adjust_support.moved_about_vertical`), else None
    support_plane : the term holding the views' support planes to one plane
        (:mod:`~tofmetry.reconstruct._adjust_support`): ``used``, ``note`` or its ``sigma_deg``,
        ``sigma_mm`` and the planes' largest spread from their mean at the ``start`` and the ``end``
    turn_axis : the term holding a turntable's views to one turn axis (``sigma_mm``; each view's
        ``|M_v a - a|`` at the start and the end [mm], :mod:`._adjust_circle`), None when not used
    final_state : what :func:`~tofmetry.reconstruct._calibration_pose.calibration_pose` needs of the last
        Gauss-Newton step (views, poses, depth terms, correspondences, the solved normal matrix);
        not reported
    """

    poses: np.ndarray
    depth_gain: float
    depth_gain_sigma: float
    z_ref_m: float
    iterations: int
    rms_mm: np.ndarray
    pair_counts: np.ndarray
    pair_rms_mm: np.ndarray
    moved_deg: np.ndarray
    moved_mm: np.ndarray
    converged: bool
    gain_estimated: bool = False
    gain_sigma_data: float = float("nan")
    gain_note: str = ""
    pose_sigma_deg: np.ndarray | None = None
    pose_sigma_mm: np.ndarray | None = None
    gain_sigma_systematic: float = float("nan")
    range_curve_m: np.ndarray | None = None
    range_curve_sigma_m: np.ndarray | None = None
    range_curve_sigma_data_m: np.ndarray | None = None
    range_curve_cov_m2: np.ndarray | None = None
    range_curve_half_span_m: float = float("nan")
    range_curve_prior_m: float = float("nan")
    range_curve_estimated: bool = False
    gain_refused: float = float("nan")
    gain_max_abs: float = float("nan")
    range_curve_note: str = ""
    amplitude_dk_m: float = 0.0
    amplitude_dk_sigma_m: float = float("nan")
    amplitude_dk_sigma_data_m: float = float("nan")
    amplitude_estimated: bool = False
    amplitude_note: str = "not asked for"
    amplitude_gain_correlation: float = float("nan")
    amplitude_gain_slope: float = float("nan")
    restart: dict | None = None
    tied: list | None = None
    calibration_pose: dict | None = None
    albedo: dict | None = None
    support_plane: dict | None = None
    turn_axis: dict | None = None
    moved_turn_deg: np.ndarray | None = None
    final_state: tuple | None = field(default=None, repr=False, compare=False)
    field_response: tuple | None = field(default=None, repr=False, compare=False)
    image_tilt_m: np.ndarray | None = None
    image_tilt_sigma_m: np.ndarray | None = None
    image_tilt_sigma_data_m: np.ndarray | None = None
    image_tilt_estimated: bool = False
    image_tilt_note: str = "not asked for"
    image_tilt_centre: np.ndarray | None = None

    @property
    def pose_covariance(self) -> np.ndarray | None:
        """(6 (V - 1), 6 (V - 1)) covariance of the poses' left increments from the data's noise
        (rotation vector [rad^2], translation [m^2], view 0 fixed), inflated as ``pose_sigma_deg``; None without one."""
        return None if self.final_state is None else self.final_state[11]

    def amplitude_report(self) -> dict:
        """The amplitude-bias correction ``dk`` [mm per ln unit] with its standard errors."""
        f = lambda x: round(float(x) * 1e3, 4) if np.isfinite(x) else None
        return {"estimated": bool(self.amplitude_estimated), "note": self.amplitude_note,
                "dk_mm_per_ln": f(self.amplitude_dk_m), "dk_sigma_mm_per_ln": f(self.amplitude_dk_sigma_m),
                "dk_sigma_data_mm_per_ln": f(self.amplitude_dk_sigma_data_m),
                "gain_correlation": round(float(self.amplitude_gain_correlation), 3)
                if np.isfinite(self.amplitude_gain_correlation) else None,
                "gain_per_mm_per_ln": float(self.amplitude_gain_slope) * 1e-3
                if np.isfinite(self.amplitude_gain_slope) else None}

    def range_curve_report(self) -> dict | None:
        """The range curve (coefficients, standard errors, and dz with its standard error at a few
        depths across the span, [mm]); None when not asked for."""
        if self.range_curve_m is None:
            return None
        h, zr = self.range_curve_half_span_m, self.z_ref_m
        z = zr + h * np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
        cov = self.range_curve_cov_m2 if self.range_curve_cov_m2 is not None else np.zeros((len(self.range_curve_m),) * 2)
        dz = range_curve_m(z, self.range_curve_m, zr, h)
        sd = range_curve_sigma_m(z, cov, zr, h) if len(cov) else np.zeros_like(z)
        r6 = lambda a: [round(float(x) * 1e3, 4) for x in a]
        return {"estimated": bool(self.range_curve_estimated), "note": self.range_curve_note,
                "degree": int(len(self.range_curve_m) + 1), "half_span_mm": round(float(h) * 1e3, 2),
                "prior_mm": round(float(self.range_curve_prior_m) * 1e3, 4),
                "coefficients_mm": r6(self.range_curve_m),
                "sigma_mm": None if self.range_curve_sigma_m is None else r6(self.range_curve_sigma_m),
                "sigma_data_mm": None if self.range_curve_sigma_data_m is None else r6(self.range_curve_sigma_data_m),
                "z_mm": [round(float(x) * 1e3, 1) for x in z], "dz_mm": r6(dz), "dz_sigma_mm": r6(sd)}

    def tilt_report(self) -> dict:
        """The image tilt ``(a, b)`` [mm per unit of x / z, y / z] with its standard errors."""
        r = lambda a: None if a is None else [round(float(x) * 1e3, 4) if np.isfinite(x) else None for x in a]
        return {"estimated": bool(self.image_tilt_estimated), "note": self.image_tilt_note,
                "ab_mm": r(self.image_tilt_m), "sigma_mm": r(self.image_tilt_sigma_m),
                "sigma_data_mm": r(self.image_tilt_sigma_data_m)}

    def to_dict(self, names: list[str] | None = None) -> dict:
        names = names or [str(k) for k in range(len(self.poses))]
        return {"depth_gain": float(self.depth_gain), "depth_gain_sigma": float(self.depth_gain_sigma),
                "z_ref_mm": float(self.z_ref_m * 1e3), "iterations": int(self.iterations),
                "converged": bool(self.converged), "gain_estimated": bool(self.gain_estimated),
                "gain_sigma_data": float(self.gain_sigma_data),
                "gain_sigma_systematic": float(self.gain_sigma_systematic), "gain_note": self.gain_note,
                "gain_refused": float(self.gain_refused), "gain_max_abs": float(self.gain_max_abs),
                "range_curve": self.range_curve_report(), "amplitude_bias": self.amplitude_report(),
                "rms_mm": [round(float(x), 4) for x in self.rms_mm],
                "moved_deg": {n: round(float(x), 4) for n, x in zip(names, self.moved_deg)},
                "moved_mm": {n: round(float(x), 3) for n, x in zip(names, self.moved_mm)},
                "moved_turn_deg": None if self.moved_turn_deg is None else
                {n: round(float(x), 4) for n, x in zip(names, self.moved_turn_deg)},
                "pose_sigma_deg": None if self.pose_sigma_deg is None else
                {n: round(float(x), 5) for n, x in zip(names, self.pose_sigma_deg)},
                "pose_sigma_mm": None if self.pose_sigma_mm is None else
                {n: round(float(x), 4) for n, x in zip(names, self.pose_sigma_mm)},
                "restart": self.restart, "tied": self.tied, "calibration_pose": self.calibration_pose,
                "image_tilt": self.tilt_report(),
                "albedo": self.albedo, "support_plane": self.support_plane, "turn_axis": self.turn_axis,
                "pairs": [{"source": names[i], "target": names[j], "n": int(self.pair_counts[i, j]),
                           "rms_mm": round(float(self.pair_rms_mm[i, j]), 3)}
                          for i in range(len(names)) for j in range(len(names)) if self.pair_counts[i, j] > 0]}



def keep_amplitude_if_it_explains(plain: AdjustResult, with_amplitude: AdjustResult, min_rms_drop: float) -> AdjustResult:
    """The adjustment with the amplitude-bias correction ``dk`` when it explains the views'
    disagreement, else the one without (whose ``amplitude_note`` then says why).

    ``dk`` is observed only through incidence: a point seen by two views at different incidences.
    Other errors that change with incidence or with the position in the image (the depth
    calibration's residual, mixed pixels at the silhouettes) are observed the same way, and the
    data alone then determine a wrong ``dk`` to +-0.05 mm per ln unit (measured on 20 family draws:
    its error against the sensor's true ``k`` was 1.6 mm RMS, no better than the study's fixed
    6.7). Where ``dk`` is what the views disagree about, the final robust residual RMS drops:
    1.0 % and 3.2 % on the two draws whose model error it divided by 2 and 4; elsewhere by 0-0.3 %.
    So ``dk`` is kept only when the residual drops by at least ``min_rms_drop`` (relative).

    Parameters
    ----------
    plain : the adjustment without ``dk``; with_amplitude : with it (same views and start)
    min_rms_drop : relative drop of the final residual RMS needed to keep ``dk`` (e.g. 0.005)
    """
    if not with_amplitude.amplitude_estimated:
        plain.amplitude_note = with_amplitude.amplitude_note
        plain.amplitude_dk_sigma_data_m = with_amplitude.amplitude_dk_sigma_data_m
        plain.amplitude_gain_slope = with_amplitude.amplitude_gain_slope
        return plain
    r0, r1 = float(plain.rms_mm[-1]), float(with_amplitude.rms_mm[-1])
    drop = 1.0 - r1 / r0 if r0 > 0 else 0.0
    if drop >= min_rms_drop:
        with_amplitude.amplitude_note += (f"; it lowers the residual RMS by {100 * drop:.1f} % ({r0:.3f} -> {r1:.3f} mm, "
                                          f">= {100 * min_rms_drop:.1f} %)")
        return with_amplitude
    plain.amplitude_note = (f"not applied: dk {with_amplitude.amplitude_dk_m * 1e3:+.2f} mm per ln unit would lower the "
                            f"residual RMS by {100 * drop:.1f} % only ({r0:.3f} -> {r1:.3f} mm, < {100 * min_rms_drop:.1f} %): "
                            "the views' disagreement is not the amplitude bias's")
    plain.amplitude_dk_sigma_data_m = with_amplitude.amplitude_dk_sigma_data_m
    plain.amplitude_gain_correlation = with_amplitude.amplitude_gain_correlation
    plain.amplitude_gain_slope = with_amplitude.amplitude_gain_slope
    return plain
