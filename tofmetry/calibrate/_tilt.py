"""The depth error linear in the image position, measured on board poses, for a wall calibration.

A wall's orientation is not known to a fraction of a degree, so a wall calibration fits it per
station (``free_tilt``) and cannot tell a depth error ``a x + b y`` (``x = X / Z``, ``y = Y / Z``
the undistorted normalised ray) from a tilted wall. Such an error is harmless to the shape of a
single view, but it turns every view's points by about ``(a, b) / Z`` rad in the camera's own frame,
and the views of a scan cannot show it (it is consistent among them): left in, the camera poses of
a scan come out turned by it. Measured on the family of ``bench/robustness`` (2026-11-29): a rocker
arm whose sensor carries 9 / 13 mm per unit of x / y ends 0.57 deg off when its joint fit starts
at the true poses, 0.03 deg with noise alone.

A board seen by the IR camera fixes its plane's orientation independently of the depth
(:func:`~tofmetry.calibrate._board_pose.solve_board_pose`: depth and IR share one lens), so the
board samples of the IR intrinsics captures measure it. Per view, the depth already corrected by
the wall calibration is compared with the board plane on the white squares, and
``e = c_k + t_x x + t_y y`` is fitted (an offset per view: the pose's distance and the residual
range error). The per-view tilts scatter by the board pose's own rotation error (about Z times
its angle) and by the calibration's per-pixel residual under the board. They also carry the
amplitude-related bias a turned board adds: a white wall is seen frontally, a board turned by
35 deg returns less light where its incidence is larger, and ToF depth reads longer there
(``k ln(1 / cos(incidence))``, the study's amplitude effect), which tilts each view by ``k G``
(``G``: the slope of ``ln(1 / cos)`` over the board, known from its plane). On family sensors it
biased the mean of the views by 2.6-3.7 mm per unit (0.15-0.2 deg at 1 m) until this term was
fitted. The sensor's tilt is then the views' model ``t_v = t0 [+ t1 (Z_v - z_ref)] [+ k G_v]``, the
terms chosen by leave-one-view-out prediction; the standard error comes from the views' scatter
about it (:class:`TiltFit`). Views kept out of the fit, in contiguous blocks of the recording,
must confirm it (:func:`held_out_check`) before it is folded in.

:func:`with_depth_tilt` folds the tilt into the calibration's per-pixel surfaces (held constant
outside the boards' distances) and marks the calibration ``tilt_calibrated``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from tofmetry.calibrate._board_samples import BoardSamples
from tofmetry.calibrate._model import DepthCalibration
from tofmetry.calibrate._tilt_check import _fit_models, _predict, held_out_check
from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor import CameraIntrinsics

#: fewest usable views for a tilt, and fewest white-square pixels of a view
MIN_VIEWS, MIN_PIXELS = 4, 100
#: views spanning at least this many mm in distance may give a tilt linear in the distance
MIN_SPAN_LINEAR_MM = 300.0
#: a view's tilt is gross only beyond 4 robust sigma and beyond this [mm per unit] (0.11 deg at 1 m)
GROSS_FLOOR_MM = 2.0
#: systematic part of the tilt's standard error [mm per unit], added in quadrature to what the
#: views' scatter gives. Measured on 70 simulated family sensors (draws 29-31, 16 checkerboard
#: captures each), against the tilt the walls leave (the least-squares plane over the image of the
#: sensor's whole per-pixel deformation at the fit's distance; re-measured 2026-11-29 after the
#: first count took the deformation's explicit tilt term alone): the fit was off by 0.95 / 1.26 mm
#: per unit RMS (x / y) while the scatter claimed 0.2-0.7 (errors 3.2 / 2.8 of it, RMS; 70 / 66 %
#: within 2 sigma); with 1.2 added, 0.70 / 0.92 and 99 / 94 % within 2 sigma (draws 32 and 33, 40
#: other sensors: 0.60 / 0.83 and 0.41 / 0.30, all within 2 sigma). A real sensor may need more:
#: the held-out check judges each fit.
SYSTEMATIC_MM = 1.2


@dataclass(frozen=True)
class TiltFit:
    """A depth error linear in the image position, ``t(Z) = t0 + t1 (Z - z_ref)`` per axis.

    Attributes
    ----------
    tilt_mm : (2,) ``t0`` [mm per unit of x / z and of y / z] at ``z_ref_mm``
    slope_mm_per_m : (2,) ``t1`` [mm per unit per m of distance] (zeros for the constant model)
    sigma_mm : (2,) standard error of ``t0`` [mm per unit]: the views' scatter and
        :data:`SYSTEMATIC_MM` in quadrature
    z_ref_mm : distance where ``t0`` holds [mm] (the views' mean)
    z_span_mm : (2,) distances of the views [mm]; outside, ``t`` is held at the nearest end
    model : ``"constant"`` or ``"linear in distance"``, either with ``" + incidence"``
    per_view_mm : (V, 2) each view's own tilt [mm per unit]; view_z_mm : (V,) its median board depth [mm]
    view_names : (V,) names of the views used
    scatter_mm : (2,) RMS of the per-view tilts about the model [mm per unit]
    cv_rms_mm : dict model -> leave-one-view-out RMS of the per-view tilts [mm per unit]
    skipped : list of (name, reason) of the views not used
    incidence_k_mm : the white board's amplitude-related bias per unit of ``ln(1 / cos(incidence))``
        [mm] taken off the views' tilts (0 unless the model says ``+ incidence``)
    held_out : the check on views kept out of the fit, as :func:`held_out_check` returns it
        (``confirmed``, ``contradicted``, ``reason``, the held-out board-plane errors, the share
        carried, a bound)
    """

    tilt_mm: np.ndarray
    slope_mm_per_m: np.ndarray
    sigma_mm: np.ndarray
    z_ref_mm: float
    z_span_mm: tuple[float, float]
    model: str
    per_view_mm: np.ndarray
    view_z_mm: np.ndarray
    view_names: tuple
    scatter_mm: np.ndarray
    cv_rms_mm: dict
    skipped: list
    incidence_k_mm: float = 0.0
    held_out: dict = field(default_factory=dict)

    @property
    def confirmed(self) -> bool:
        """Whether views kept out of its fit lower their board-plane error with it (:func:`held_out_check`)."""
        return bool(self.held_out.get("confirmed", False))

    @property
    def foldable(self) -> bool:
        """Whether the tilt may be folded into a calibration: the held-out check ran and views kept
        out of its fit do not contradict it (:func:`held_out_check`)."""
        return self.held_out.get("rms_mm") is not None and self.held_out.get("contradicted") is False

    @property
    def shrink(self) -> np.ndarray:
        """(2,) share of the fit folded in, per axis: ``t0^2 / (t0^2 + sigma^2)``, the least-squares
        (Wiener) weight of a tilt as large as its fit says, measured with that standard error.

        Why: a fit within a few sigma of zero is as likely noise as tilt, and folded whole it puts
        its error into the calibration. Measured against the tilt the walls leave (2026-11-29; the
        plane over the image of the sensor's whole simulated deformation): on 50 family sensors of
        draws 31-32 the tilt left after the fold was 1.02 / 1.32 mm per unit RMS (x / y; p90 of its
        size 2.9, 11 above 2 mm per unit) with the whole fit folded when the held-out check confirmed
        it and nothing otherwise, 0.83 / 1.17 (p90 2.1, 6 above 2) with every uncontradicted fit
        folded shrunk; on 20 sensors of draw 33, not used to choose it, 0.98 / 0.84 (p90 2.2, 3)
        against 0.93 / 0.56 (p90 1.4, 1)."""
        t2 = np.square(np.asarray(self.tilt_mm, np.float64))
        return t2 / np.maximum(t2 + np.square(np.asarray(self.sigma_mm, np.float64)), 1e-12)

    def at(self, z_mm) -> np.ndarray:
        """(..., 2) tilt [mm per unit] at distances ``z_mm`` (held outside ``z_span_mm``)."""
        z = np.clip(np.asarray(z_mm, np.float64), *self.z_span_mm)
        return self.tilt_mm + np.multiply.outer(z - self.z_ref_mm, self.slope_mm_per_m * 1e-3)

    def angle_deg(self, z_mm: float) -> float:
        """Rotation [deg] the tilt gives a view's points at distance ``z_mm``: ``|t| / Z``."""
        return float(np.degrees(np.linalg.norm(self.at(z_mm)) / z_mm))

    def to_dict(self) -> dict:
        r = lambda a, n=3: [round(float(x), n) for x in np.ravel(a)]
        return {"tilt_mm": r(self.tilt_mm), "slope_mm_per_m": r(self.slope_mm_per_m), "sigma_mm": r(self.sigma_mm),
                "z_ref_mm": round(self.z_ref_mm, 1), "z_span_mm": r(self.z_span_mm, 1), "model": self.model,
                "n_views": int(len(self.view_z_mm)), "scatter_mm": r(self.scatter_mm),
                "cv_rms_mm": {k: round(float(v), 3) for k, v in self.cv_rms_mm.items()},
                "incidence_k_mm": round(float(self.incidence_k_mm), 3),
                "angle_deg_at_1m": round(self.angle_deg(1000.0), 4), "skipped": [list(s) for s in self.skipped],
                "shrink": r(self.shrink), "held_out": dict(self.held_out)}


def view_tilt(s: BoardSamples, rays: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """One view's ``e = c + t_x x + t_y y`` on its white squares (two Huber-like passes: pixels beyond
    3 robust sigma dropped), and the same fit of ``g = ln(1 / cos(incidence))`` over the same pixels.

    ``g`` is what the board's tilt adds to a white surface's amplitude-related bias (``k g``: a
    white wall is seen frontally, a board turned by 35 deg returns ``cos`` of its incidence); its
    slope over the board, ``G``, lets :func:`fit_depth_tilt` separate that bias from the tilt.

    Parameters
    ----------
    s : the view's board samples, ``measured_mm`` already corrected by the calibration [mm]
    rays : (H, W, 2) undistorted normalised rays of the intrinsics

    Returns
    -------
    (t (2,) [mm per unit], median board depth [mm], (N, 3) the kept pixels' ``x``, ``y`` and error
    ``e`` against the board plane [mm], G (2,) [per unit]).
    """
    w = s.select("white")
    if len(w.u) < MIN_PIXELS:
        raise EstimationError(f"{len(w.u)} white-square pixels (at least {MIN_PIXELS})")
    xy = rays[w.v, w.u]
    e = w.measured_mm - w.reference_mm
    A = np.column_stack([np.ones(len(e)), xy[:, 0], xy[:, 1]])
    keep = np.isfinite(e)
    for _ in range(3):
        coef = np.linalg.lstsq(A[keep], e[keep], rcond=None)[0]
        r = e - A @ coef
        sig = 1.4826 * np.median(np.abs(r[keep])) + 1e-6
        keep = np.isfinite(e) & (np.abs(r) <= 3 * sig)
    span = np.ptp(xy[keep], axis=0)
    if np.any(span < 0.05):
        raise EstimationError(f"the board spans too little of the image ({span[0]:.2f} x {span[1]:.2f} in x / z, y / z)")
    # the board plane from its reference points (exactly on it), its normal, each pixel's incidence
    ray3 = np.column_stack([xy, np.ones(len(xy))])
    P = ray3 * w.reference_mm[:, None]
    n = np.linalg.svd(P - P.mean(0), full_matrices=False)[2][-1]
    cos_i = np.abs(ray3 @ n) / np.linalg.norm(ray3, axis=1)
    g = np.log(1.0 / np.clip(cos_i, 0.05, 1.0))
    G = np.linalg.lstsq(A[keep], g[keep], rcond=None)[0][1:]
    return coef[1:], float(np.median(w.reference_mm)), np.column_stack([xy[keep], e[keep]]), G


def fit_depth_tilt(samples: list[BoardSamples], intr: CameraIntrinsics, names: list[str] | None = None) -> TiltFit:
    """The depth error linear in the image position from board views (module docstring).

    Parameters
    ----------
    samples : per view, the board samples (:func:`~tofmetry.calibrate.board.board_samples`) of
        the depth **corrected by the calibration** the tilt is for (or raw depth, to measure the
        sensor's own tilt) [mm]
    intr : IR/depth intrinsics (the rays ``x = X / Z``, ``y = Y / Z``)
    names : view names (default ``view000`` ...)

    Returns
    -------
    TiltFit

    Raises
    ------
    EstimationError : fewer than 4 usable views.
    """
    names = list(names) if names is not None else [f"view{k:03d}" for k in range(len(samples))]
    if len(names) != len(samples):
        raise InputError(f"fit_depth_tilt: {len(names)} names for {len(samples)} views")
    rays = intr.ray_table(True)
    tilts, zs, grads, pix, used, skipped = [], [], [], [], [], []
    for n, s in zip(names, samples):
        try:
            t, z, px, G = view_tilt(s, rays)
        except EstimationError as exc:
            skipped.append((n, str(exc)))
            continue
        tilts.append(t)
        zs.append(z)
        grads.append(G)
        pix.append(px)
        used.append(n)
    if len(tilts) < MIN_VIEWS:
        raise EstimationError(f"fit_depth_tilt: {len(tilts)} usable board views, at least {MIN_VIEWS} needed"
                              + (f" (skipped: {'; '.join(f'{a}: {b}' for a, b in skipped[:5])})" if skipped else ""))
    T, Z, Gr = np.array(tilts), np.array(zs), np.array(grads)
    V = len(T)
    can_linear = bool(np.ptp(Z) >= MIN_SPAN_LINEAR_MM and V >= 6)
    # gross per-view tilts (a board pose off): beyond 4 robust sigma (at least GROSS_FLOOR_MM) of the
    # views' trend, dropped
    dev = T - _predict(_fit_models(T, Z, Gr, can_linear, V >= 6), Z, Gr)
    dev = dev - np.median(dev, 0)
    mad = np.maximum(1.4826 * np.median(np.abs(dev), 0), GROSS_FLOOR_MM / 4)
    ok = np.all(np.abs(dev) <= 4 * mad, axis=1)
    for k in np.flatnonzero(~ok):
        skipped.append((used[k], f"its tilt ({T[k, 0]:+.1f}, {T[k, 1]:+.1f}) mm is beyond 4 robust sigma of the views'"))
    if ok.sum() >= MIN_VIEWS:
        T, Z, Gr = T[ok], Z[ok], Gr[ok]
        used, pix = [u for u, o in zip(used, ok) if o], [p for p, o in zip(pix, ok) if o]
        V = len(T)
    candidates = {"constant": (False, False)}
    if V >= 6:
        candidates["constant + incidence"] = (False, True)
    if can_linear:
        candidates["linear in distance"] = (True, False)
        candidates["linear in distance + incidence"] = (True, True)
    cv, fits = {}, {}
    for name, (lin, inc) in candidates.items():
        err = []
        for k in range(V):
            keep = np.arange(V) != k
            m = _fit_models(T[keep], Z[keep], Gr[keep], lin, inc)
            err.append(T[k] - _predict(m, Z[k:k + 1], Gr[k:k + 1])[0])
        m = _fit_models(T, Z, Gr, lin, inc)
        # a darker return reads longer on a ToF camera (the study's amplitude effect): a negative k
        # is not that bias but the views' scatter, so such a candidate is not taken
        if m[3] < 0:
            name += " (k < 0, not taken)"
        else:
            fits[name] = m
        cv[name] = float(np.sqrt(np.mean(np.square(err))))
    model = min(fits, key=cv.get)
    lin, inc = candidates[model]
    m = fits[model]
    res = T - _predict(m, Z, Gr)
    n_par = 2 * (1 + lin) + inc
    dof = max(2 * V - n_par, 1)
    scatter = np.sqrt(np.sum(res ** 2, 0) / (dof / 2))
    # standard error of t0 from the model's own normal matrix and that scatter (the incidence term
    # shares the views with it)
    zr = m[2]
    cols = [np.ones(V)] + ([Z - zr] if lin else [])
    sig = []
    for a in range(2):
        A = np.column_stack(cols + ([Gr[:, a]] if inc else []))
        cov = np.linalg.pinv(A.T @ A) * scatter[a] ** 2
        sig.append(np.sqrt(cov[0, 0]))
    # a bias the views share (the calibration's per-pixel residual under the boards, the incidence
    # model) does not show in their scatter: added in quadrature
    sig = np.hypot(np.array(sig), SYSTEMATIC_MM)
    check = held_out_check(T, Z, Gr, pix, lin, inc, m[0], sig)
    return TiltFit(np.asarray(m[0], float), np.asarray(m[1], float) * 1e3, sig, zr,
                   (float(Z.min()), float(Z.max())), model, T, Z, tuple(used), scatter, cv, skipped, m[3], check)


def with_depth_tilt(cal: DepthCalibration, fit: TiltFit) -> DepthCalibration:
    """``cal`` with the tilt removed by its per-pixel surfaces (``S += w t(node) . (x, y)``, ``w`` the
    fit's :attr:`~TiltFit.shrink` per axis: the correction ``d - S`` then takes ``w t . (x, y)`` off)
    and marked ``tilt_calibrated`` (its prediction and diagnostics carry the fit, :meth:`TiltFit.to_dict`).

    Raises
    ------
    InputError : the calibration already has a tilt folded in.
    """
    if (cal.diagnostics or {}).get("tilt"):
        raise InputError("with_depth_tilt: this calibration already has a tilt from boards "
                         f"({cal.diagnostics['tilt'].get('tilt_mm')} mm per unit); start from the wall calibration")
    rays = cal.intrinsics.ray_table(True)
    t = fit.at(cal.node_mm) * fit.shrink  # (K, 2)
    surf = cal.surfaces.astype(np.float64) + (t[:, 0, None, None] * rays[None, ..., 0]
                                              + t[:, 1, None, None] * rays[None, ..., 1])
    info = fit.to_dict()
    pred = dict(cal.prediction or {})
    if pred:
        pred["tilt_calibrated"] = True
        pred["tilt"] = info
    return replace(cal, surfaces=surf.astype(np.float32), prediction=pred,
                   diagnostics={**(cal.diagnostics or {}), "tilt_calibrated": True, "tilt": info})
