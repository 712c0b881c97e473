"""Validation of a depth calibration: per-station before/after metrics and cross-validation.

Metrics for a wall station at reference distance ``D`` (all [mm]):

* ``dev``: mean over the central 10x10 patch minus ``D``. Before correction the
  calibration's constant ``offset_mm`` is removed (as the study does for Fig. 7a), so the
  "before" figure shows the shape of the range error, not the mounting offset.
* ``plane_std``: std of the residuals to a robust least-squares plane (tilt free).
* ``rms``: RMS of the per-pixel error against the reference wall (anchored at ``D`` on the
  optical axis; frontal, or with the orientation fitted on the corrected data) over the
  central 90 % of the image (5 % cut on each side), offset removed before correction (it
  credits the calibration only for the shape of the error, not for the constant offset).
* ``rms_raw_before``: the same before correction *without* removing the offset: the error a
  user of the uncorrected sensor actually gets.
* ``rms_noise``: the part of these RMS figures that is the random noise of the station's
  temporal mean (RMS of the per-pixel standard error ``std / sqrt(n)``), which no calibration
  can remove; ``rms_after_systematic = sqrt(rms_after^2 - rms_noise^2)`` is what is left of the
  systematic error.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from tofmetry.calibrate._apply import apply_depth_calibration, count_outside_range
from tofmetry.calibrate._fit import DepthFitConfig, fit_depth_model
from tofmetry.calibrate._sample import DepthSample
from tofmetry.calibrate._fit_study import StudyFitConfig, fit_study_model
from tofmetry.calibrate._surface import SurfaceSpec
from tofmetry.calibrate._model import DepthCalibration
from tofmetry.calibrate._wall import central_patch, fit_plane, wall_reference
from tofmetry.sensor import CameraIntrinsics


@dataclass
class StationReport:
    """Before/after metrics of one wall station [mm] (see module docstring)."""

    name: str
    distance_mm: float
    dev_before_mm: float
    dev_after_mm: float
    plane_std_before_mm: float
    plane_std_after_mm: float
    rms_before_mm: float
    rms_after_mm: float
    n_outside_range: int
    held_out: bool = True
    rms_raw_before_mm: float = float("nan")
    rms_noise_mm: float = float("nan")

    @property
    def rms_after_systematic_mm(self) -> float:
        """Systematic part of ``rms_after_mm`` (noise of the temporal mean removed) [mm]."""
        return float(np.sqrt(max(self.rms_after_mm ** 2 - self.rms_noise_mm ** 2, 0.0)))

    def to_dict(self) -> dict:
        return asdict(self) | {"rms_after_systematic_mm": self.rms_after_systematic_mm}


def central_fraction_mask(shape: tuple[int, int], fraction: float = 0.9) -> np.ndarray:
    """(H, W) bool of the central ``fraction`` of the image in each direction."""
    h, w = shape
    m = np.zeros(shape, bool)
    dv, du = int(round(h * (1 - fraction) / 2)), int(round(w * (1 - fraction) / 2))
    m[dv:h - dv, du:w - du] = True
    return m


def evaluate_wall_station(mean_mm: np.ndarray, distance_mm: float, cal: DepthCalibration,
                          intrinsics: CameraIntrinsics | None = None, name: str = "", frontal: bool = True,
                          fraction: float = 0.9, held_out: bool = True,
                          mean_sem_mm: np.ndarray | None = None) -> tuple[StationReport, dict]:
    """Before/after metrics of one station's averaged depth.

    Parameters
    ----------
    mean_mm : (H, W) float [mm], NaN/0 invalid (temporal mean of the station)
    distance_mm : reference distance along the optical axis [mm]
    cal : DepthCalibration
    intrinsics : for the clouds (default ``cal.intrinsics``)
    frontal : reference wall perpendicular to the optical axis; else its orientation is
        fitted on the corrected cloud
    fraction : central fraction of the image used for ``rms``
    mean_sem_mm : (H, W) float [mm], optional standard error of ``mean_mm`` per pixel
        (temporal std / sqrt(n)); gives ``rms_noise_mm``

    Returns
    -------
    StationReport, and a dict of (H, W) maps: ``residual_before`` / ``residual_after``
    (plane-fit residuals) and ``error_before`` / ``error_after`` (against the reference).
    """
    intr = intrinsics or cal.intrinsics
    m = np.where(np.isfinite(mean_mm) & (mean_mm > 0), np.asarray(mean_mm, np.float64), np.nan)
    c = apply_depth_calibration(m, cal)
    c = np.where(np.isfinite(c), c, np.nan)
    off = cal.offset_mm
    sl = central_patch(m.shape, intr.cx, intr.cy)
    pf_b = fit_plane(m, intr)
    pf_a = fit_plane(c, intr)
    ref = wall_reference(intr, distance_mm, None if frontal else pf_a.normal)
    mask = central_fraction_mask(m.shape, fraction)
    eb = m - off - ref
    ea = c - ref
    rms = lambda e: float(np.sqrt(np.nanmean(e[mask] ** 2)))  # noqa: E731
    rep = StationReport(
        name=name, distance_mm=float(distance_mm),
        dev_before_mm=float(np.nanmean(m[sl]) - off - distance_mm), dev_after_mm=float(np.nanmean(c[sl]) - distance_mm),
        plane_std_before_mm=pf_b.std_mm, plane_std_after_mm=pf_a.std_mm,
        rms_before_mm=rms(eb), rms_after_mm=rms(ea),
        n_outside_range=count_outside_range(np.nan_to_num(m), cal), held_out=held_out,
        rms_raw_before_mm=rms(m - ref),
        rms_noise_mm=rms(np.where(np.isfinite(c), mean_sem_mm, np.nan)) if mean_sem_mm is not None else float("nan"),
    )
    maps = {"residual_before": pf_b.residual_mm, "residual_after": pf_a.residual_mm, "error_before": eb, "error_after": ea}
    return rep, maps


#: Methods compared by :func:`cross_validate`: tofmetry's joint model and the study's method with
#: its two surface models.
METHODS = {
    "tofmetry": lambda: DepthFitConfig(predict=False),
    "study": lambda: StudyFitConfig(surface=SurfaceSpec("spline")),
    "study-poly3": lambda: StudyFitConfig(surface=SurfaceSpec("poly", degree=3)),
}


def fit_any(samples: list[DepthSample], intrinsics: CameraIntrinsics, config, sensor: str = "unknown",
            provenance: dict | None = None):
    """Fit with tofmetry's method (:class:`DepthFitConfig`) or the study's (:class:`StudyFitConfig`)."""
    if isinstance(config, StudyFitConfig):
        return fit_study_model(samples, intrinsics, config, sensor=sensor, provenance=provenance)
    return fit_depth_model(samples, intrinsics, config, sensor=sensor, provenance=provenance)


def cross_validate(samples: list[DepthSample], distances_mm: list[float], intrinsics: CameraIntrinsics,
                   config: DepthFitConfig | StudyFitConfig | None = None, frontal: bool = True, sensor: str = "unknown",
                   advance=None) -> list[StationReport]:
    """Leave-one-station-out cross-validation on wall samples.

    Every interior station (not the first or last, which would fall outside the calibrated
    range) is held out in turn: the model is fitted on the others and evaluated on it.

    Parameters
    ----------
    samples : wall samples (see :func:`wall_sample`), in distance order
    distances_mm : their reference distances [mm]
    config : fit options: :class:`DepthFitConfig` (tofmetry, default without its own internal
        prediction) or :class:`StudyFitConfig` (the study's method), see :data:`METHODS`
    advance : optional callable run after each fold (progress)

    Returns
    -------
    list of StationReport (``held_out=True``), one per interior station.
    """
    cfg = config or DepthFitConfig(predict=False)
    out = []
    for j in range(1, len(samples) - 1):
        train = samples[:j] + samples[j + 1:]
        cal = fit_any(train, intrinsics, cfg, sensor=sensor).calibration
        rep, _ = evaluate_wall_station(samples[j].measured_mm, distances_mm[j], cal, intrinsics,
                                       name=samples[j].name, frontal=frontal)
        out.append(rep)
        if advance is not None:
            advance()
    return out


def summarize(reports: list[StationReport], max_distance_mm: float = 4000.0) -> dict:
    """Aggregate figures over stations: max |dev| after (<= max_distance), median rms ratio, etc."""
    sel = [r for r in reports if r.distance_mm <= max_distance_mm] or reports
    ratio = [r.rms_before_mm / r.rms_after_mm for r in reports if r.rms_after_mm > 0]
    raw = [r.rms_raw_before_mm / r.rms_after_mm for r in reports if r.rms_after_mm > 0 and np.isfinite(r.rms_raw_before_mm)]
    return {
        "n_stations": len(reports),
        "max_abs_dev_after_mm": float(max(abs(r.dev_after_mm) for r in sel)) if sel else float("nan"),
        "max_abs_dev_before_mm": float(max(abs(r.dev_before_mm) for r in sel)) if sel else float("nan"),
        "min_rms_reduction": float(min(ratio)) if ratio else float("nan"),
        "median_rms_reduction": float(np.median(ratio)) if ratio else float("nan"),
        "min_rms_reduction_raw": float(min(raw)) if raw else float("nan"),
        "min_rms_reduction_systematic": _min_sys(reports),
        "mean_plane_std_before_mm": float(np.mean([r.plane_std_before_mm for r in reports])) if reports else float("nan"),
        "mean_plane_std_after_mm": float(np.mean([r.plane_std_after_mm for r in reports])) if reports else float("nan"),
    }


def _min_sys(reports) -> float:
    """Smallest reduction of the systematic RMS (noise of the temporal means removed on both sides)."""
    out = []
    for r in reports:
        if np.isfinite(r.rms_noise_mm) and r.rms_after_systematic_mm > 0:
            out.append(np.sqrt(max(r.rms_before_mm ** 2 - r.rms_noise_mm ** 2, 0.0)) / r.rms_after_systematic_mm)
    return float(min(out)) if out else float("nan")
