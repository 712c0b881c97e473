"""The study's depth-calibration method, kept as a baseline to compare with (study §4.2-4.3).

tofmetry's own method is :func:`tofmetry.calibrate.fit_depth_model`. This one reproduces
what the study did by hand, on the same :class:`~tofmetry.calibrate._fit.DepthSample` input:
a range curve of the central deviations and one surface per station. It alternates (``config.iterations`` times) between

1. the range curve ``R``: for each sample, the mean of ``measured - reference - S`` over the
   ``center_pixels`` valid pixels nearest the principal point, against the median measured
   distance there; a cubic smoothing spline (GCV-chosen smoothing unless given) of these;
2. the surfaces ``S_k``: the residual ``measured - reference - R(measured)`` (R taken at each
   pixel's *own* measured distance) of the samples at node ``k`` (hat weights in distance
   when nodes are given), fitted by a smooth surface and shifted so that it averages to zero
   over a disc of ``center_radius_px`` around the principal point (the range curve owns
   the level there, so neither term absorbs the other's residual).

Gross outliers (|residual| > max(outlier_k * robust sigma, outlier_floor_mm)) are removed
between iterations.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from tofmetry.calibrate._sample import DepthSample
from tofmetry.calibrate._model import DepthCalibration, _node_weights
from tofmetry.calibrate._range import fit_range_curve
from tofmetry.calibrate._surface import SurfaceSpec, fit_surface
from tofmetry.errors import EstimationError, InputError
from tofmetry.sensor import CameraIntrinsics


@dataclass(frozen=True)
class StudyFitConfig:
    """Options of :func:`fit_study_model` (the study's method; ``surface=SurfaceSpec("poly", 3)``
    is the study's cubic polynomial, the default a tensor spline)."""

    surface: SurfaceSpec = field(default_factory=SurfaceSpec)
    center_pixels: int = 100          # pixels nearest the principal point for the range data
    center_radius_px: float = 6.0     # disc on which each surface is forced to zero mean
    range_smoothing: float | None = None  # make_smoothing_spline lam; None = GCV
    range_margin_mm: float = 50.0     # corrected range = data range +- margin (R clamped there)
    nodes_mm: tuple[float, ...] | None = None  # surface nodes; None = one per distinct sample distance
    node_merge_mm: float = 1.0        # samples closer than this share a node
    iterations: int = 4
    outlier_k: float = 5.0
    outlier_floor_mm: float = 3.0

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(eq=False)
class StudyFitResult:
    """Result of :func:`fit_study_model`.

    Attributes
    ----------
    calibration : DepthCalibration
    samples : list of dict, per sample: name, center_mm, dev_before_mm, dev_after_mm (central
        pixels), rms_before_mm (after removing the offset), rms_after_mm, n_valid, n_outliers
    range_points : (M, 2) float64 [mm] (measured central distance, central deviation - S)
    history : list of float, max change of the range data per iteration [mm]
    seconds : float
    """

    calibration: DepthCalibration
    samples: list
    range_points: np.ndarray
    history: list
    seconds: float


def _center_order(shape, cx, cy) -> np.ndarray:
    h, w = shape
    v, u = np.mgrid[0:h, 0:w]
    return np.argsort(((u - cx) ** 2 + (v - cy) ** 2).ravel(), kind="stable")


def _nodes_from(centers: np.ndarray, merge_mm: float) -> np.ndarray:
    c = np.sort(centers)
    groups = [[c[0]]]
    for v in c[1:]:
        if v - groups[-1][-1] < merge_mm:
            groups[-1].append(v)
        else:
            groups.append([v])
    return np.array([np.mean(g) for g in groups])


def fit_study_model(samples: list[DepthSample], intrinsics: CameraIntrinsics, config: StudyFitConfig | None = None,
                    sensor: str = "unknown", provenance: dict | None = None) -> StudyFitResult:
    """Fit range curve + per-pixel surfaces to calibration samples.

    Parameters
    ----------
    samples : list of DepthSample, at least 2 at distinct distances, (H, W) = intrinsics.shape
    intrinsics : CameraIntrinsics (stored in the calibration; cx, cy define the centre)
    config : DepthFitConfig
    sensor : sensor profile name stored in the calibration

    Returns
    -------
    StudyFitResult

    Raises
    ------
    InputError
        Fewer than 2 samples, wrong shapes.
    EstimationError
        A sample without enough valid pixels near the centre or for its surface.
    """
    t0 = time.perf_counter()
    cfg = config or StudyFitConfig()
    if len(samples) < 2:
        raise InputError(f"depth calibration needs at least 2 samples (stations), found {len(samples)}")
    shape = intrinsics.shape
    cx, cy = intrinsics.cx, intrinsics.cy
    order = _center_order(shape, cx, cy)
    v, u = np.mgrid[0:shape[0], 0:shape[1]]
    disc = ((u - cx) ** 2 + (v - cy) ** 2) <= cfg.center_radius_px ** 2
    if not disc.any():
        raise InputError(f"center_radius_px={cfg.center_radius_px} selects no pixel")

    meas, err, wts, cidx, centers = [], [], [], [], []
    for j, s in enumerate(samples):
        name = s.name or f"sample{j}"
        m = np.asarray(s.measured_mm, np.float64)
        r = np.asarray(s.reference_mm, np.float64)
        if m.shape != shape or r.shape != shape:
            raise InputError(f"sample {name!r}: measured {m.shape} / reference {r.shape}, expected {shape} (intrinsics)")
        wgt = np.ones(shape) if s.weight is None else np.asarray(s.weight, np.float64)
        ok = np.isfinite(m) & (m > 0) & np.isfinite(r) & (wgt > 0)
        e = np.where(ok, m - r, np.nan)
        ci = order[ok.ravel()[order]][: cfg.center_pixels]
        if len(ci) < min(cfg.center_pixels, 10):
            raise EstimationError(f"sample {name!r}: only {len(ci)} valid pixels with a known reference")
        meas.append(np.where(ok, m, np.nan))
        err.append(e)
        wts.append(np.where(ok, wgt, 0.0))
        cidx.append(ci)
        centers.append(float(np.median(m.ravel()[ci])))
    centers = np.array(centers)
    names = [s.name or f"sample{j}" for j, s in enumerate(samples)]
    nodes = np.array(sorted(cfg.nodes_mm), float) if cfg.nodes_mm else _nodes_from(centers, cfg.node_merge_mm)
    if len(np.unique(centers.round(3))) < 2:
        raise InputError("depth calibration needs samples at 2 or more distinct distances")
    k0, k1, hw = _node_weights(nodes, centers)
    n_nodes = len(nodes)
    surfaces = np.zeros((n_nodes, *shape))
    bad = [np.zeros(shape, bool) for _ in samples]
    history: list[float] = []
    prev_y = None
    spline = None
    for _it in range(max(1, cfg.iterations)):
        # 1. range data: central deviation minus the current surface at that distance
        y = np.empty(len(samples))
        for j in range(len(samples)):
            s_j = (1 - hw[j]) * surfaces[k0[j]] + hw[j] * surfaces[k1[j]]
            ci = cidx[j]
            ww = wts[j].ravel()[ci] * ~bad[j].ravel()[ci]
            y[j] = np.sum((err[j].ravel()[ci] - s_j.ravel()[ci]) * ww) / max(ww.sum(), 1e-12)
        spline = fit_range_curve(centers, y, cfg.range_smoothing, cfg.node_merge_mm)
        history.append(float(np.max(np.abs(y - prev_y))) if prev_y is not None else float("nan"))
        prev_y = y
        if cfg.surface.model == "none":
            break
        # 2. surfaces from residuals with R at each pixel's own measured distance
        lo, hi = centers.min(), centers.max()
        grid = np.arange(np.floor(lo), np.ceil(hi) + 1.0)
        rgrid = spline(grid)  # R tabulated every mm, interpolated (error << 0.01 mm)
        acc = np.zeros((n_nodes, *shape))
        wacc = np.zeros((n_nodes, *shape))
        resid = []
        for j in range(len(samples)):
            rj = err[j] - np.interp(np.nan_to_num(meas[j], nan=lo), grid, rgrid)
            wj = np.where(bad[j], 0.0, wts[j])
            rz = np.nan_to_num(rj)
            resid.append(rj)
            for k, h in ((k0[j], 1 - hw[j]), (k1[j], hw[j])):
                if h > 0:
                    acc[k] += h * wj * rz
                    wacc[k] += h * wj
        for k in range(n_nodes):
            if not (wacc[k] > 0).any():
                raise EstimationError(f"no sample data near surface node {nodes[k]:.0f} mm")
            with np.errstate(invalid="ignore", divide="ignore"):
                vals = np.where(wacc[k] > 0, acc[k] / wacc[k], 0.0)
            sk = fit_surface(vals, wacc[k], cfg.surface, cx, cy)
            surfaces[k] = sk - sk[disc].mean()
        # 3. gross outliers against the full model
        for j in range(len(samples)):
            s_j = (1 - hw[j]) * surfaces[k0[j]] + hw[j] * surfaces[k1[j]]
            e = resid[j] - s_j
            fin = np.isfinite(e)
            med = np.median(e[fin])
            sig = 1.4826 * np.median(np.abs(e[fin] - med))
            bad[j] = fin & (np.abs(e - med) > max(cfg.outlier_k * sig, cfg.outlier_floor_mm))

    data_lo, data_hi = float(centers.min()), float(centers.max())
    grid = np.linspace(data_lo, data_hi, 512)
    offset = float(np.mean(spline(grid)))
    vr = (max(1.0, data_lo - cfg.range_margin_mm), min(65535.0, data_hi + cfg.range_margin_mm))
    cal = DepthCalibration(
        sensor=sensor, intrinsics=intrinsics, range_knots=spline.t, range_coeffs=spline.c, range_degree=spline.k,
        range_data_mm=np.array([data_lo, data_hi]), valid_range_mm=np.array(vr), node_mm=nodes,
        surfaces=surfaces.astype(np.float32), offset_mm=offset, surface_model=cfg.surface.label,
        provenance={**(provenance or {}), "config": cfg.to_dict(), "samples": names},
    )
    table = []
    for j in range(len(samples)):
        s_j = (1 - hw[j]) * surfaces[k0[j]] + hw[j] * surfaces[k1[j]]
        after = err[j] - cal.range_error(np.nan_to_num(meas[j], nan=data_lo)) - s_j
        ci = cidx[j]
        good = np.isfinite(after) & ~bad[j]
        table.append({
            "name": names[j], "center_mm": centers[j],
            "dev_before_mm": float(np.nanmean(err[j].ravel()[ci])),
            "dev_after_mm": float(np.nanmean(after.ravel()[ci])),
            "rms_before_mm": float(np.sqrt(np.mean((err[j][good] - offset) ** 2))),
            "rms_after_mm": float(np.sqrt(np.mean(after[good] ** 2))),
            "n_valid": int(good.sum()), "n_outliers": int(bad[j].sum()),
        })
    cal.diagnostics.update({"samples": table, "offset_mm": offset, "history": history,
                            "model": f"study: smoothing spline + {cfg.surface.label} per station"})
    return StudyFitResult(
        calibration=cal, samples=table, range_points=np.column_stack([centers, prev_y]), history=history,
        seconds=time.perf_counter() - t0,
    )
