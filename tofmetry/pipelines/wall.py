"""Wall-mode depth calibration pipeline: ``stations.csv`` + one capture per station in, a
:class:`~tofmetry.pipelines.depth_run.DepthRun` out."""

from __future__ import annotations

import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from tofmetry.calibrate import DepthFitConfig, StudyFitConfig, fit_any, station_statistics, wall_sample
from tofmetry.errors import EstimationError, SensorMismatchError
from tofmetry.io import EmptyFrameWarning, WallDataset
from tofmetry.pipelines._common import _adv, _provenance
from tofmetry.pipelines.depth_run import DepthRun
from tofmetry.pipelines.plausibility import check_correction, check_station, enforce
from tofmetry.sensor import CameraIntrinsics

#: a station whose temporal mean has fewer valid pixels than this fraction is skipped (with a note)
MIN_VALID_FRACTION = 0.01


def _open_wall(path: Path, intrinsics: CameraIntrinsics | None, min_stations: int):
    ds = WallDataset(path, min_stations=min_stations)
    caps = [st.open() for st in ds.stations]
    intr, src = caps[0].intrinsics(intrinsics)
    sensor = caps[0].sensor
    for st, cap in zip(ds.stations, caps):
        if cap.shape != intr.shape:
            raise SensorMismatchError(f"{st.path}: depth is {cap.shape[1]}x{cap.shape[0]}, "
                                      f"intrinsics ({src}) are {intr.width}x{intr.height}")
        if cap.sensor != sensor:
            raise SensorMismatchError(f"{st.path}: sensor {cap.sensor!r} differs from {caps[0].path} ({sensor!r})")
    notes = []
    if intrinsics is None and caps[0].meta.intrinsics is None:
        notes.append(f"no intrinsics given and none in the captures: {src} used")
    return ds, caps, intr, src, sensor, notes


def _station_stats(caps, intr, advance):
    """Stream each capture into StationStats (two PNG-decoding threads, frames in order)."""
    stats = []
    # all-zero frames (a station beyond the sensor's range) are reported per station by _usable
    with warnings.catch_warnings(), ThreadPoolExecutor(2) as pool:
        warnings.simplefilter("ignore", EmptyFrameWarning)
        for cap in caps:
            frames = pool.map(cap.depth, range(len(cap)))
            stats.append(station_statistics(frames, cap.shape, intr.cx, intr.cy, advance=advance))
    return stats


def _usable(stats, stations, notes) -> list[int]:
    keep = []
    for i, (st, s) in enumerate(zip(stations, stats)):
        frac = float(np.isfinite(s.mean_mm).mean())
        if frac < MIN_VALID_FRACTION:
            notes.append(f"station {st.name} ({st.distance_mm:.0f} mm) skipped: only {100 * frac:.2f} % valid pixels "
                         "(out of the sensor's range?)")
        else:
            keep.append(i)
    return keep


def station_findings(stations, stats, reference_offset_mm: float) -> list[str]:
    """Plausibility of each station's stated distance against the central depth the sensor measured
    (:func:`~tofmetry.pipelines.plausibility.check_station`)."""
    out = []
    for st, s in zip(stations, stats):
        f = s.frame_center_mm[np.isfinite(s.frame_center_mm)]
        out += check_station(st.name, st.distance_mm - reference_offset_mm, float(np.median(f)) if f.size else np.nan)
    return out


def calibrate_wall(path: Path, *, intrinsics: CameraIntrinsics | None = None, config=None, tilted: bool = True,
                   reference_offset_mm: float = 0.0, advance=None, provenance: dict | None = None,
                   accept_implausible: bool = False) -> DepthRun:
    """Depth calibration of a wall dataset (``stations.csv``); see :func:`tofmetry.pipelines.calibrate_depth_dataset`.

    ``config``: :class:`~tofmetry.calibrate.DepthFitConfig` (tofmetry's method, the default) or
    :class:`~tofmetry.calibrate.StudyFitConfig` (the study's method, a baseline).

    Plausibility gates (:mod:`tofmetry.pipelines.plausibility`): before the fit, every station's
    stated distance against its measured central depth; after it, the size of the correction.
    Either raises :class:`~tofmetry.errors.ImplausibleResultError` unless ``accept_implausible``;
    the run's and the calibration's ``plausibility`` record what was found and accepted.
    """
    path = Path(path)
    t0 = time.perf_counter()
    cfg = config or DepthFitConfig()
    ds, caps, intr, src, sensor, notes = _open_wall(path, intrinsics, 2)
    stats = _station_stats(caps, intr, _adv(advance))
    keep = _usable(stats, ds.stations, notes)
    what = f"the depth calibration of {path}"
    findings = station_findings([ds.stations[i] for i in keep], [stats[i] for i in keep], reference_offset_mm)
    enforce(findings, what, accept_implausible)
    samples, used = [], []
    for i in keep:
        st, s = ds.stations[i], stats[i]
        try:
            smp, _ = wall_sample(s.mean_mm, st.distance_mm - reference_offset_mm, intr, name=st.name, frontal=not tilted,
                                 sem_mm=s.std_mm / np.sqrt(max(s.n_frames, 1)), valid_fraction=s.valid_fraction)
        except EstimationError as exc:
            notes.append(f"station {st.name} ({st.distance_mm:.0f} mm) skipped: {exc}")
            continue
        samples.append(smp)
        used.append(i)
    if len(samples) < 2:
        raise EstimationError(f"{path}: only {len(samples)} usable station(s), at least 2 needed; " + "; ".join(notes))
    stations = [ds.stations[i] for i in used]
    stats = [stats[i] for i in used]
    prov = _provenance({"wall_dataset": str(path), "intrinsics_source": src, "reference_offset_mm": reference_offset_mm,
                        "tilted": tilted, "stations": [{"name": st.name, "distance_mm": st.distance_mm,
                                                        "n_frames": s.n_frames} for st, s in zip(stations, stats)],
                        **(provenance or {})})
    res = fit_any(samples, intr, cfg, sensor=sensor, provenance=prov)
    cal = res.calibration
    gate = enforce(findings + check_correction(cal), what, accept_implausible)
    cal.provenance["plausibility"] = gate
    for name, why in getattr(res, "skipped", []):  # samples the fit could not use
        notes.append(f"station {name} left out of the fit: {why}")
    fitted = {row["name"] for row in res.samples}
    kept = [k for k, st in enumerate(stations) if st.name in fitted]
    stations, stats = [stations[k] for k in kept], [stats[k] for k in kept]
    rows = []
    for st, row, s in zip(stations, res.samples, stats):
        sl = s.std_mm[np.isfinite(s.std_mm)]
        row["center_std_mm"] = s.center_std_mm
        row["pixel_std_median_mm"] = float(np.median(sl)) if len(sl) else float("nan")
        rows.append({"station": st.name, "distance_mm": st.distance_mm, **row})
    cal.diagnostics["samples"] = res.samples
    frame_points = [(row["center_mm"], s.frame_center_mm - st.distance_mm + reference_offset_mm)
                    for row, s, st in zip(res.samples, stats, stations)]
    fit = {"fit_seconds": res.seconds, "model": cal.diagnostics.get("model"),
           "method": "study" if isinstance(cfg, StudyFitConfig) else "tofmetry",
           "candidates": cal.diagnostics.get("candidates", []), "prediction": cal.prediction,
           "support": cal.support.summary() if cal.support is not None else None,
           "tilt_calibrated": cal.diagnostics.get("tilt_calibrated", not tilted), "plausibility": gate}
    return DepthRun("wall", cal, intr, src, sensor, rows, fit, time.perf_counter() - t0, notes, str(path),
                    res.range_points, frame_points)




