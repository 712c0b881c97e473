"""Validation pipeline: a calibration and a wall dataset in, a :class:`ValidationRun` out."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.calibrate import DepthCalibration, DepthFitConfig, evaluate_wall_station, summarize, wall_sample, with_surface
from tofmetry.calibrate import cross_validate as _cv
from tofmetry.calibrate import figures as F
from tofmetry.io import atomic_write_json
from tofmetry.errors import EstimationError, InputError
from tofmetry.pipelines._common import _adv, _save_fig
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
    cross_validation : {"spline": ..., "poly3": ...} leave-one-station-out results or None
    """

    stations: list
    summary: dict
    maps: list
    cross_validation: dict | None
    calibration: DepthCalibration
    dataset: str = ""
    center_std_mm: list = field(default_factory=list)
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        cv = None
        if self.cross_validation is not None:
            cv = {k: {"stations": [r.to_dict() for r in v["stations"]], "summary": v["summary"]}
                  for k, v in self.cross_validation.items()}
        return {"calibration_provenance": self.calibration.provenance, "wall_dataset": self.dataset,
                "stations": [r.to_dict() for r in self.stations], "summary": self.summary, "cross_validation": cv,
                "notes": self.notes}


def validate_depth(path: Path, cal: DepthCalibration, *, intrinsics: CameraIntrinsics | None = None, tilted: bool = False,
                   reference_offset_mm: float = 0.0, cross_validate: bool = False,
                   cv_surfaces: tuple[str, ...] = ("spline", "poly3"), advance=None) -> ValidationRun:
    """Per-station before/after metrics of ``cal`` on the wall dataset ``path`` (stations the
    calibration was fitted on are marked not held out), plus optional leave-one-station-out
    cross-validation of the wall fit on ``path`` for the surface models ``cv_surfaces``
    ("spline": tensor-product spline, "poly3": the study's cubic polynomial). Each model costs one
    refit per station."""
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
    reports, maps = [], []
    for st, s in zip(stations, stats):
        rep, mp = evaluate_wall_station(s.mean_mm, st.distance_mm - reference_offset_mm, cal, intr, name=st.name,
                                        frontal=not tilted, held_out=st.name not in fit_names,
                                        mean_sem_mm=s.std_mm / np.sqrt(max(s.n_frames, 1)))
        reports.append(rep)
        maps.append(mp)
    cvres = None
    if cross_validate:
        samples = [wall_sample(s.mean_mm, st.distance_mm - reference_offset_mm, intr, name=st.name)[0]
                   for st, s in zip(stations, stats)]
        dists = [st.distance_mm - reference_offset_mm for st in stations]
        cvres = {}
        base = DepthFitConfig()
        models = {"spline": with_surface(base, "spline"), "poly3": with_surface(base, "poly", degree=3)}
        unknown = [m for m in cv_surfaces if m not in models]
        if unknown:
            raise InputError(f"cv_surfaces: unknown surface model(s) {unknown}; choose from {sorted(models)}")
        for label in cv_surfaces:
            cfg = models[label]
            r = _cv(samples, dists, intr, cfg, frontal=not tilted, sensor=sensor, advance=adv)
            cvres[label] = {"stations": r, "summary": summarize(r)}
    return ValidationRun(reports, summarize(reports), maps, cvres, cal, str(path), [s.center_std_mm for s in stats], notes)


def write_validation_report(run: ValidationRun, folder: Path) -> list[Path]:
    """``validation.json``, ``validation.png``, ``range_curve.png`` (held-out stations on the
    fitted curve), ``std_vs_range.png`` and ``residuals_<station>.png`` in ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cal = run.calibration
    out = [atomic_write_json(folder / "validation.json", run.to_dict())]
    out.append(_save_fig(F.fig_validation(run.stations), folder / "validation.png"))
    held = [(r.distance_mm + r.dev_before_mm + cal.offset_mm, r.dev_before_mm) for r in run.stations]
    smp = cal.diagnostics.get("samples") or []
    pts = np.array([[r["center_mm"], r["dev_before_mm"]] for r in smp]) if smp else np.zeros((0, 2))
    out.append(_save_fig(F.fig_range_curve(cal, pts, held_out=held), folder / "range_curve.png"))
    out.append(_save_fig(F.fig_std_vs_range([r.distance_mm for r in run.stations], run.center_std_mm),
                         folder / "std_vs_range.png"))
    for r, mp in zip(run.stations, run.maps):
        out.append(_save_fig(F.fig_residual_maps(mp["residual_before"], mp["residual_after"],
                                                 f"Plane-fit residuals at {r.distance_mm / 1000:.3f} m ({r.name})"),
                             folder / f"residuals_{r.name}.png"))
    return out
