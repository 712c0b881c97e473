"""Depth calibration from (measured, reference) samples: the joint model, chosen and judged by
blocked validation, with its support and its own predicted error.

A :class:`DepthSample` is one averaged depth image with a per-pixel reference depth where it
is known (a wall at a known distance, a board plane from PnP...). Coverage may be partial.
:func:`fit_depth_model`:

1. averages each sample over cells and weights them by the noise of their mean
   (:func:`tofmetry.calibrate._joint.block_cells`);
2. chooses the model by blocked validation (:func:`tofmetry.calibrate._joint_fit.select_spec`):
   range error along the ray or in Z, roughness, number of surface nodes;
3. fits it on all samples (:mod:`tofmetry.calibrate._joint`);
4. predicts its own error on new data from the same blocked folds: every interior sample
   left out and predicted from the others (interpolation), the nearest and the farthest apart
   (extrapolation), which also chooses the fallback outside the support
   (:mod:`tofmetry.calibrate._prediction`);
5. records the support: which depths were fitted at each image cell
   (:class:`~tofmetry.calibrate._support.CalibrationSupport`).

The study's own method (smoothing spline of the central deviations + one surface per
station) is kept as a baseline in :mod:`tofmetry.calibrate._fit_study`.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from tofmetry.calibrate._joint import Cells, JointSpec, Layout, block_cells, unusable_cells
from tofmetry.calibrate._joint_fit import JointFit, blocked_folds, fit_joint, select_spec
from tofmetry.calibrate._model import DepthCalibration
from tofmetry.calibrate._prediction import before_after, prediction_record, range_coverage
from tofmetry.calibrate._sample import DepthSample
from tofmetry.calibrate._support import CalibrationSupport
from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor import CameraIntrinsics


@dataclass(frozen=True)
class DepthFitConfig:
    """Options of :func:`fit_depth_model`.

    Attributes
    ----------
    spec : JointSpec or None, the model; None = chosen by blocked validation
    block : cell size [px] of the averaging before the fit (None: width / 64, at least 2)
    robust : one Huber reweighting (when ``spec`` is given; the selection always does it)
    support_cell_px, support_bin_mm : resolution of the support map
    fallback : ``"auto"`` (chosen on the extrapolation folds), ``"hold"`` or ``"trend"``
    predict : run the blocked validation that predicts the calibration's error
    """

    spec: JointSpec | None = None
    block: int | None = None
    robust: bool = True
    support_cell_px: int = 16
    support_bin_mm: float = 100.0
    fallback: str = "auto"
    predict: bool = True

    def __post_init__(self) -> None:
        if self.fallback not in ("auto", "hold", "trend"):
            raise InputError(f"fallback must be 'auto', 'hold' or 'trend', found {self.fallback!r}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["spec"] = asdict(self.spec) if self.spec is not None else None
        return d


@dataclass(eq=False)
class DepthCalibrationResult:
    """Result of :func:`fit_depth_model`.

    Attributes
    ----------
    calibration : DepthCalibration (with support, fallback and prediction)
    samples : list of dict per sample: name, center_mm, and its in-fit metrics before / after
        (see :mod:`tofmetry.calibrate._prediction`)
    range_points : (M, 2) float64 [mm] (measured central distance, central deviation)
    spec : the JointSpec used; tried : list of (label, CV score) of the candidates
    prediction : dict, the predicted error (also in ``calibration.prediction``)
    seconds : float
    skipped : list of (name, reason) of the samples left out of the fit
    """

    calibration: DepthCalibration
    samples: list
    range_points: np.ndarray
    spec: JointSpec
    tried: list
    prediction: dict
    seconds: float
    history: list = field(default_factory=list)
    skipped: list = field(default_factory=list)


def model_calibration(layout: Layout, theta: np.ndarray, intrinsics: CameraIntrinsics, data_mm: tuple, *,
                      sensor: str = "unknown", support: CalibrationSupport | None = None, fallback: str = "unchanged",
                      trend: tuple = (0.0, 0.0), provenance: dict | None = None, diagnostics: dict | None = None,
                      prediction: dict | None = None) -> DepthCalibration:
    """The fitted joint model as a :class:`DepthCalibration` (exact, no refit).

    ``data_mm``: (lo, hi) measured depths [mm] spanned by the samples (range of ``R``).
    """
    spec = layout.spec
    c0 = float(theta[0])
    wcoef = np.asarray(theta[1:1 + layout.n_w], float)
    lo, hi = float(data_mm[0]), float(data_mm[1])
    ray = {}
    if spec.variable == "z":  # W of Z is a range curve in Z (gamma = 0)
        knots, coeffs, deg = layout.t_w, wcoef + c0, 3
        rdata = np.array([layout.t_w[3], layout.t_w[-4]])
    else:
        knots, coeffs, deg = np.array([lo, lo, hi, hi]), np.array([c0, c0]), 1
        rdata = np.array([lo, hi])
        ray = {"ray_knots": layout.t_w, "ray_coeffs": wcoef, "ray_gamma": spec.gamma,
               "ray_data_mm": np.array([layout.t_w[3], layout.t_w[-4]])}
    grid = np.linspace(lo, hi, 256)  # the constant part: mean correction on the axis (rho = 1, S = 0)
    offset = c0 + float(np.mean(layout.w_spline(theta)(np.clip(grid, layout.t_w[3], layout.t_w[-4]))))
    return DepthCalibration(
        sensor=sensor, intrinsics=intrinsics, range_knots=knots, range_coeffs=coeffs, range_degree=deg,
        range_data_mm=rdata, valid_range_mm=np.array([1.0, 65535.0]), node_mm=layout.nodes,
        surfaces=layout.surfaces(theta).astype(np.float32), offset_mm=offset, surface_model=spec.label,
        provenance=dict(provenance or {}), diagnostics=dict(diagnostics or {}), support=support,
        fallback=fallback, trend_mm=trend, prediction=dict(prediction or {}), **ray,
    )


def _trend(cal: DepthCalibration, lo: float, hi: float) -> tuple[float, float]:
    """Straight line ``a + b d`` through the correction on the optical axis over ``[lo, hi]``."""
    d = np.linspace(lo, hi, 200)
    c = cal.range_error(d) + cal.ray_error(d)
    b, a = np.polyfit(d, c, 1)
    return float(a), float(b)


def _centers(samples: list[DepthSample], intr: CameraIntrinsics) -> np.ndarray:
    h, w = intr.shape
    v0, u0 = int(round(intr.cy)), int(round(intr.cx))
    out = []
    for s in samples:
        m = np.asarray(s.measured_mm, float)
        ok = np.isfinite(m) & (m > 0) & np.isfinite(np.asarray(s.reference_mm, float))
        patch = ok[max(v0 - 10, 0):v0 + 10, max(u0 - 10, 0):u0 + 10]
        vals = m[max(v0 - 10, 0):v0 + 10, max(u0 - 10, 0):u0 + 10][patch]
        out.append(float(np.median(vals)) if vals.size >= 20 else float(np.median(m[ok])))
    return np.array(out)


def _support(samples: list[DepthSample], idx, intr: CameraIntrinsics, cfg: DepthFitConfig) -> CalibrationSupport:
    us, vs, zs = [], [], []
    vv, uu = np.mgrid[0:intr.height, 0:intr.width]
    for j in idx:
        s = samples[j]
        m = np.asarray(s.measured_mm, float)
        ok = np.isfinite(m) & (m > 0) & np.isfinite(np.asarray(s.reference_mm, float))
        if s.weight is not None:
            ok &= np.asarray(s.weight) > 0
        us.append(uu[ok])
        vs.append(vv[ok])
        zs.append(m[ok])
    return CalibrationSupport.from_samples(np.concatenate(us), np.concatenate(vs), np.concatenate(zs), intr.shape,
                                           cell_px=cfg.support_cell_px, bin_mm=cfg.support_bin_mm)


def _evaluate(cal: DepthCalibration, s: DepthSample, rays: np.ndarray, cxy: tuple) -> dict:
    m = np.asarray(s.measured_mm, float)
    corr, _ = cal.correction(np.nan_to_num(m))
    with np.errstate(invalid="ignore"):
        c = np.where(np.isfinite(m) & (m > 0), m - corr, np.nan)
    return before_after(m, c, s.reference_mm, rays, cxy, s.sem_mm, s.free_tilt)


def fit_depth_model(samples: list[DepthSample], intrinsics: CameraIntrinsics, config: DepthFitConfig | None = None,
                    sensor: str = "unknown", provenance: dict | None = None, advance=None) -> DepthCalibrationResult:
    """Fit, validate and describe a depth calibration (see the module docstring).

    Parameters
    ----------
    samples : list of DepthSample, at least 2 at distinct distances, (H, W) = intrinsics.shape
    intrinsics : CameraIntrinsics (stored in the calibration; its rays define ``rho``)
    config : DepthFitConfig
    sensor : sensor profile name stored in the calibration
    advance : optional progress callable (one call per candidate model and per fold)

    Returns
    -------
    DepthCalibrationResult

    Raises
    ------
    InputError
        Fewer than 2 samples, wrong shapes.
    EstimationError
        A sample without enough valid pixels with a reference.
    """
    t0 = time.perf_counter()
    cfg = config or DepthFitConfig()
    if len(samples) < 2:
        raise InputError(f"depth calibration needs at least 2 samples (stations or poses), found {len(samples)}")
    shape = intrinsics.shape
    for j, s in enumerate(samples):
        for what, a in (("measured", s.measured_mm), ("reference", s.reference_mm)):
            if np.shape(a) != shape:
                raise InputError(f"sample {s.name or j!r}: {what} is {np.shape(a)}, expected {shape} (intrinsics)")
    names = [s.name or f"sample{j}" for j, s in enumerate(samples)]
    rays = intrinsics.ray_table()
    cxy = (intrinsics.cx, intrinsics.cy)
    adv = advance or (lambda n=1: None)
    with threadpool_limits(1, user_api="blas"):
        block = cfg.block or max(2, int(round(shape[1] / 64)))
        cells = [_cells(s, rays, block, n) for s, n in zip(samples, names)]
        bad = unusable_cells(cells)
        skipped = [(names[j], why) for j, why in bad.items()]
        if bad:
            keep = [j for j in range(len(samples)) if j not in bad]
            if len(keep) < 2:
                raise EstimationError("depth calibration: fewer than 2 usable samples; "
                                      + "; ".join(f"{n}: {w}" for n, w in skipped))
            samples, names, cells = [samples[j] for j in keep], [names[j] for j in keep], [cells[j] for j in keep]
        centers = _centers(samples, intrinsics)
        if len(np.unique(np.round(centers, -1))) < 2:
            raise InputError("depth calibration needs samples at 2 or more distinct distances (10 mm apart)")
        if cfg.spec is None:
            spec, tried, weights = select_spec(cells, shape, cxy, centers, advance=adv)
            fit = fit_joint(cells, spec, shape, cxy, centers, weights=weights, robust=False)
        else:
            spec, tried = cfg.spec, []
            fit = fit_joint(cells, spec, shape, cxy, centers, robust=cfg.robust)
        lo, hi = float(centers.min()), float(centers.max())
        base = model_calibration(fit.layout, fit.theta, intrinsics, (lo, hi), sensor=sensor)
        interp, extrap = blocked_folds(centers) if cfg.predict else ([], [])
        interp_rows = _fold_rows(fit, interp, samples, names, centers, intrinsics, rays, cxy, adv)
        extrap_rows, fallback = _extrapolation(fit, extrap, samples, names, centers, intrinsics, rays, cxy, cfg, adv)
        support = _support(samples, range(len(samples)), intrinsics, cfg)
        trend = _trend(base, lo, hi)
        note = ("blocked leave-one-out over distances: each interior station predicted by a calibration fitted on "
                "all the others (interpolation); the nearest and the farthest apart (extrapolation)")
        coverage = range_coverage([s.reference_mm for s in samples], rays, spec.variable)
        pred = prediction_record(interp_rows, extrap_rows, note, coverage=coverage) \
            if interp_rows or extrap_rows else {}
        if pred:
            pred["fallback_chosen"] = fallback
            pred["tilt_calibrated"] = not any(s.free_tilt for s in samples)
        table = []
        for j, s in enumerate(samples):
            row = {"name": names[j], "center_mm": float(centers[j])} | _evaluate(base, s, rays, cxy)
            table.append(row)
    cal = model_calibration(
        fit.layout, fit.theta, intrinsics, (lo, hi), sensor=sensor, support=support, fallback=fallback, trend=trend,
        provenance={**(provenance or {}), "config": cfg.to_dict(), "samples": names},
        diagnostics={"samples": table, "model": spec.label, "spec": asdict(spec), "skipped_samples": skipped,
                     "candidates": [(t.spec.label, float(t.score)) for t in tried],
                     "tilt_calibrated": not any(s.free_tilt for s in samples)},
        prediction=pred)
    rp = np.array([[r["center_mm"], r["central_before_mm"]] for r in table])
    return DepthCalibrationResult(cal, table, rp, spec, [(t.spec.label, t.score) for t in tried], pred,
                                  time.perf_counter() - t0, skipped=skipped)


def _cells(s: DepthSample, rays: np.ndarray, block: int, name: str) -> Cells:
    m = np.asarray(s.measured_mm, float)
    r = np.asarray(s.reference_mm, float)
    w = np.ones(m.shape) if s.weight is None else np.asarray(s.weight, float)
    return block_cells(m, r, w, None if s.sem_mm is None else np.asarray(s.sem_mm, float), rays, block,
                       s.free_tilt, name)


def _fold_rows(fit: JointFit, folds, samples, names, centers, intr, rays, cxy, adv) -> list[dict]:
    rows = []
    lo, hi = float(centers.min()), float(centers.max())
    for f in folds:
        th = fit.refit_without(f)
        cal = model_calibration(fit.layout, th, intr, (lo, hi))
        for j in f:
            rows.append({"name": names[j], "center_mm": float(centers[j])} | _evaluate(cal, samples[j], rays, cxy))
        adv()
    return rows


def _extrapolation(fit: JointFit, folds, samples, names, centers, intr, rays, cxy, cfg, adv):
    """Rows of the extrapolation folds under each fallback, and the fallback chosen."""
    rows, score = [], {"hold": [], "trend": []}
    for f in folds:
        keep = [j for j in range(len(samples)) if j not in f]
        if len(np.unique(np.round(centers[keep], -1))) < 2:
            continue
        th = fit.refit_without(f)
        lo, hi = float(centers[keep].min()), float(centers[keep].max())
        sup = _support(samples, keep, intr, cfg)
        base = model_calibration(fit.layout, th, intr, (lo, hi))
        trend = _trend(base, lo, hi)
        for fb in ("hold", "trend"):
            cal = model_calibration(fit.layout, th, intr, (lo, hi), support=sup, fallback=fb, trend=trend)
            for j in f:
                r = _evaluate(cal, samples[j], rays, cxy)
                rows.append({"name": names[j], "center_mm": float(centers[j]), "fallback": fb} | r)
                score[fb].append(r["rms_mm"])
        adv()
    if cfg.fallback != "auto":
        return rows, cfg.fallback
    if score["hold"] and np.nanmean(score["trend"]) < np.nanmean(score["hold"]):
        return rows, "trend"
    return rows, "hold"
