"""Validation pipeline: a calibration and a wall dataset in, a :class:`ValidationRun` out."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.calibrate import (
    METHODS, DepthCalibration, before_after, check_prediction, evaluate_wall_station, summarize, wall_reference,
    wall_sample,
)
from tofmetry.calibrate import cross_validate as _cv
from tofmetry.calibrate import figures as F
from tofmetry.io import atomic_write_json
from tofmetry.errors import EstimationError, InputError
from tofmetry._shared.figures import save_png
from tofmetry.pipelines._common import _adv
from tofmetry.pipelines.wall import _open_wall, _station_stats, _usable
from tofmetry.sensor import CameraIntrinsics


@dataclass(eq=False)
class ValidationRun:
    """Before/after evaluation of a depth calibration on a wall dataset.

    Attributes
    ----------
    stations : list of StationReport
    summary : dict (see ``tofmetry.calibrate.summarize``)
    maps : per station dict of (H, W) residual maps [mm] (``residual_before``, ``residual_after``)
    cross_validation : {method: {"stations", "summary"}} leave-one-station-out results per method
        ("tofmetry", "study", "study-poly3") or None
    metrics : per station the metrics of the calibration's own prediction (tilt removed, see
        ``tofmetry.calibrate.before_after``)
    prediction_check : the calibration's predicted error against the held-out stations
        (``tofmetry.calibrate.check_prediction``); empty without a prediction or held-out stations
    """

    stations: list
    summary: dict
    maps: list
    cross_validation: dict | None
    calibration: DepthCalibration
    dataset: str = ""
    center_std_mm: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    metrics: list = field(default_factory=list)
    prediction_check: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        cv = None
        if self.cross_validation is not None:
            cv = {k: {"stations": [r.to_dict() for r in v["stations"]], "summary": v["summary"]}
                  for k, v in self.cross_validation.items()}
        return {"calibration_provenance": self.calibration.provenance, "wall_dataset": self.dataset,
                "stations": [r.to_dict() for r in self.stations], "summary": self.summary, "cross_validation": cv,
                "metrics": self.metrics, "prediction": self.calibration.prediction,
                "prediction_check": self.prediction_check, "notes": self.notes}


def validate_depth(path: Path, cal: DepthCalibration, *, intrinsics: CameraIntrinsics | None = None, tilted: bool = False,
                   reference_offset_mm: float = 0.0, cross_validate: bool = False,
                   cv_methods: tuple[str, ...] = ("tofmetry", "study"), advance=None) -> ValidationRun:
    """Per-station before/after metrics of ``cal`` on the wall dataset ``path`` (stations the
    calibration was fitted on are marked not held out), plus optional leave-one-station-out
    cross-validation of the wall fit on ``path`` for the methods ``cv_methods`` ("tofmetry": the
    joint model; "study": the study's range spline + a tensor spline per station; "study-poly3":
    the same with the study's cubic polynomial). Each method costs one refit per station."""
    path = Path(path)
    intr = intrinsics or cal.intrinsics
    ds, caps, intr, _src, sensor, notes = _open_wall(path, intr, 1)
    cal.check_compatible(sensor=sensor, shape=intr.shape)
    adv = _adv(advance)
    stats = _station_stats(caps, intr, adv)
    keep = _usable(stats, ds.stations, notes)
    stations, stats = [ds.stations[i] for i in keep], [stats[i] for i in keep]
    if not stations:
        raise EstimationError(f"{path}: no station with valid depth; " + "; ".join(notes))
    same = str(Path(cal.provenance.get("wall_dataset", "")).resolve()) == str(path.resolve())
    fit_names = set(cal.provenance.get("samples", [])) if same else set()
    if same:
        notes.append("validating on the calibration's own training data (not held out); "
                     "use cross-validation for held-out figures")
    reports, maps, metrics = [], [], []
    rays = intr.ray_table()
    for st, s in zip(stations, stats):
        dist = st.distance_mm - reference_offset_mm
        sem = s.std_mm / np.sqrt(max(s.n_frames, 1))
        rep, mp = evaluate_wall_station(s.mean_mm, dist, cal, intr, name=st.name, frontal=not tilted,
                                        held_out=st.name not in fit_names, mean_sem_mm=sem)
        reports.append(rep)
        maps.append(mp)
        corr, _ = cal.correction(np.nan_to_num(s.mean_mm))
        metrics.append({"name": st.name, "distance_mm": dist, "held_out": rep.held_out}
                       | before_after(s.mean_mm, s.mean_mm - corr, wall_reference(intr, dist), rays, (intr.cx, intr.cy),
                                      sem, True))
    held = [m for m in metrics if m["held_out"]]
    check = check_prediction(cal.prediction, held) if held and cal.prediction else {}
    cvres = None
    if cross_validate:
        samples = [wall_sample(s.mean_mm, st.distance_mm - reference_offset_mm, intr, name=st.name, frontal=not tilted,
                               sem_mm=s.std_mm / np.sqrt(max(s.n_frames, 1)))[0]
                   for st, s in zip(stations, stats)]
        dists = [st.distance_mm - reference_offset_mm for st in stations]
        cvres = {}
        unknown = [m for m in cv_methods if m not in METHODS]
        if unknown:
            raise InputError(f"cv_methods: unknown method(s) {unknown}; choose from {sorted(METHODS)}")
        for label in cv_methods:
            r = _cv(samples, dists, intr, METHODS[label](), frontal=not tilted, sensor=sensor, advance=adv)
            cvres[label] = {"stations": r, "summary": summarize(r)}
    return ValidationRun(reports, summarize(reports), maps, cvres, cal, str(path), [s.center_std_mm for s in stats], notes,
                         metrics, check)


def write_validation_report(run: ValidationRun, folder: Path) -> list[Path]:
    """``validation.json``, ``validation.png``, ``range_curve.png`` (held-out stations on the
    fitted curve), ``std_vs_range.png`` and ``residuals_<station>.png`` in ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cal = run.calibration
    out = [atomic_write_json(folder / "validation.json", run.to_dict())]
    out.append(save_png(F.fig_validation(run.stations), folder / "validation.png"))
    held = [(r.distance_mm + r.dev_before_mm + cal.offset_mm, r.dev_before_mm) for r in run.stations]
    smp = cal.diagnostics.get("samples") or []
    pts = np.array([[r["center_mm"], r.get("central_before_mm", r.get("dev_before_mm"))] for r in smp]) \
        if smp else np.zeros((0, 2))
    out.append(save_png(F.fig_range_curve(cal, pts, held_out=held), folder / "range_curve.png"))
    out.append(save_png(F.fig_std_vs_range([r.distance_mm for r in run.stations], run.center_std_mm),
                         folder / "std_vs_range.png"))
    for r, mp in zip(run.stations, run.maps):
        out.append(save_png(F.fig_residual_maps(mp["residual_before"], mp["residual_after"],
                                                 f"Plane-fit residuals at {r.distance_mm / 1000:.3f} m ({r.name})"),
                             folder / f"residuals_{r.name}.png"))
    return out
