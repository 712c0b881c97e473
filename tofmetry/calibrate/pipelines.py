"""Calibration pipelines: dataset folders in, result objects out (the CLI and the study call these).

This is the pipeline layer: it reads datasets (``tofmetry.io``) and calls the pure estimators
of :mod:`tofmetry.calibrate`; it never prints. Progress goes through an optional
``advance()`` callable (called once per unit of work; the total is not known in advance).
Every ``*Run`` result carries what the reports need and has ``to_dict()`` (JSON-able).

* :func:`intrinsics_from_images` / :func:`write_intrinsics_report` — checkerboard intrinsics
* :func:`calibrate_depth_dataset` / :func:`write_depth_report` — depth calibration of a wall
  dataset (``stations.csv``) or a board dataset (``board.json``, board mode)
* :func:`validate_depth` / :func:`write_validation_report` — before/after on a wall dataset
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tofmetry.calibrate._intrinsics import (
    PARAMS, IntrinsicsResult, calibrate_intrinsics, cross_validate_intrinsics, detect_corners,
)
from tofmetry.calibrate._model import DepthCalibration
from tofmetry.errors import EstimationError, InputError, SensorMismatchError
from tofmetry.sensor import CameraIntrinsics

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".npy", ".jpg", ".jpeg")
#: a station whose temporal mean has fewer valid pixels than this fraction is skipped (with a note)
MIN_VALID_FRACTION = 0.01


def _adv(advance):
    return advance if advance is not None else (lambda n=1: None)


def _provenance(extra: dict | None) -> dict:
    import tofmetry

    return {"tool": f"tofmetry {tofmetry.__version__}",
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **(extra or {})}


def _save_fig(fig, path: Path) -> Path:
    """Save a matplotlib figure atomically (PNG) and close it."""
    import io

    import matplotlib.pyplot as plt

    from tofmetry.io import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())


# ============================================================================ intrinsics
@dataclass(eq=False)
class IntrinsicsRun:
    """Checkerboard intrinsics from a folder of images.

    Attributes
    ----------
    result : IntrinsicsResult (kept views; ``result.rejected_views`` the outlier views)
    names : image names with a detected board (incl. outlier views), same order as ``corners``
    rejected : image names where no board was detected
    rejected_views : outlier views (RMS above ``max(1 px, 5 x median)``), left out of the fit
    corners : list of (cols*rows, 2) float64 [px], one per ``names``
    image_size : (width, height) [px]
    cv : k-fold pose-wise held-out reprojection RMS (see ``cross_validate_intrinsics``), names of the views
    """

    result: IntrinsicsResult
    names: list
    rejected: list
    rejected_views: list
    corners: list
    image_size: tuple
    board: tuple
    square_mm: float
    cv: dict
    images_dir: str = ""
    seconds: float = float("nan")

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self.result.intrinsics

    def to_dict(self) -> dict:
        cv = dict(self.cv)
        if "views" in cv:
            cv["views"] = [self.names[i] for i in cv["views"]]
        return {**self.result.to_dict(), "images_dir": self.images_dir, "board": list(self.board),
                "square_mm": self.square_mm, "image_size": list(self.image_size), "detected": self.names,
                "rejected": self.rejected, "cross_validation": cv, "seconds": self.seconds}


def _list_images(images_dir: Path) -> list[Path]:
    if not images_dir.is_dir():
        raise InputError(f"images folder not found: {images_dir}")
    files = sorted(p for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))
    if not files:
        raise InputError(f"{images_dir}: no images ({', '.join(IMAGE_SUFFIXES)})")
    return files


def intrinsics_from_images(images_dir: Path, board: tuple[int, int], square_mm: float, *, leave_one_out: bool = True,
                           fix_k3: bool = False, advance=None, k_folds: int = 5) -> IntrinsicsRun:
    """Detect the board in every image of ``images_dir``, calibrate, reject outlier views,
    analyse stability (leave-one-out) and cross-validate (k-fold over views, held-out views'
    pose solved with the fitted intrinsics).

    Parameters
    ----------
    images_dir : folder of 16-bit IR PNG/TIFF/NPY or 8-bit colour JPEG images
    board : (cols, rows) inner corners; square_mm : square size [mm]
    advance : optional progress callable (one call per image, per leave-one-out refit, per fold)
    """
    from tofmetry.io.images import read_color_image, read_ir_image

    t0 = time.perf_counter()
    images_dir = Path(images_dir)
    cols, rows = (int(x) for x in board)
    if cols < 2 or rows < 2 or not square_mm > 0:
        raise InputError(f"board needs >= 2x2 inner corners and square_mm > 0; found {cols}x{rows}, {square_mm}")
    adv = _adv(advance)
    corners, names, rejected, size = [], [], [], None
    for f in _list_images(images_dir):
        img = read_color_image(f) if f.suffix.lower() in (".jpg", ".jpeg") else read_ir_image(f)
        s = (img.shape[1], img.shape[0])
        if size is None:
            size = s
        elif s != size:
            raise InputError(f"{f}: size {s[0]}x{s[1]} differs from the first image's {size[0]}x{size[1]}")
        c = detect_corners(img, (cols, rows))
        if c is None:
            rejected.append(f.name)
        else:
            corners.append(c)
            names.append(f.name)
        adv()
    res = calibrate_intrinsics(corners, names, (cols, rows), square_mm, size, leave_one_out=leave_one_out,
                               fix_k3=fix_k3, advance=adv)
    excl = [names.index(n) for n in res.rejected_views]
    cv = cross_validate_intrinsics(corners, (cols, rows), square_mm, size, k=k_folds, fix_k3=fix_k3, exclude=excl) \
        if len(corners) - len(excl) >= 4 else {}
    return IntrinsicsRun(res, names, rejected, list(res.rejected_views), corners, size, (cols, rows), float(square_mm),
                         cv, str(images_dir), time.perf_counter() - t0)


def write_intrinsics_report(run: IntrinsicsRun, folder: Path) -> list[Path]:
    """``intrinsics_report.json``, ``coverage.png`` and ``per_image.png`` (per-image RMS,
    rejection threshold, leave-one-out influence) in ``folder`` (created)."""
    from tofmetry.calibrate import _figures as F
    from tofmetry.io import atomic_write_json

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    res = run.result
    kept = [c for n, c in zip(run.names, run.corners) if n in set(res.used)]
    w, h = run.image_size
    out = [atomic_write_json(folder / "intrinsics_report.json", run.to_dict())]
    out.append(_save_fig(F.fig_coverage(kept, (h, w), f"Corner coverage: {len(kept)} images, {100 * res.coverage:.0f} % "
                                        f"of the area, {100 * res.cell_coverage:.0f} % of 8x8 cells"),
                         folder / "coverage.png"))
    out.append(_save_fig(F.fig_intrinsics_per_image(run), folder / "per_image.png"))
    return out


# ============================================================================ depth
@dataclass(eq=False)
class DepthRun:
    """Depth calibration of a dataset.

    Attributes
    ----------
    kind : "wall" or "board"
    calibration : DepthCalibration (save with ``tofmetry.io.calibration_file.save_calibration``)
    intrinsics, intrinsics_source : the IR/depth intrinsics used and where they came from
    sensor : sensor name
    rows : per station (wall) / per pose (board) table rows (list of dict)
    fit : fit diagnostics (wall: summary, history; board: held-out cases none / iai_shift /
        constant_refit / model, squares used, intrinsics fit)
    seconds : wall-clock time
    notes : list of str (e.g. "no intrinsics given: typical profile used", skipped stations)
    """

    kind: str
    calibration: DepthCalibration
    intrinsics: CameraIntrinsics
    intrinsics_source: str
    sensor: str
    rows: list
    fit: dict
    seconds: float
    notes: list = field(default_factory=list)
    path: str = ""
    # figure material (not serialised)
    range_points: np.ndarray | None = None
    frame_points: list | None = None
    board_result: object = None
    intrinsics_run: object = None

    @property
    def stations(self) -> list:
        """Alias of ``rows`` (per station / per pose table rows)."""
        return self.rows

    def to_dict(self) -> dict:
        return {"kind": self.kind, "dataset": self.path, "sensor": self.sensor, "intrinsics": self.intrinsics.to_dict(),
                "intrinsics_source": self.intrinsics_source, "summary": self.calibration.summary(), "rows": self.rows,
                "fit": self.fit, "seconds": self.seconds, "notes": self.notes}


def _open_wall(path: Path, intrinsics: CameraIntrinsics | None, min_stations: int):
    from tofmetry.io import WallDataset

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
    from concurrent.futures import ThreadPoolExecutor

    from tofmetry.calibrate._wall import station_statistics
    from tofmetry.io import EmptyFrameWarning

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


def calibrate_depth_dataset(path: Path, *, intrinsics: CameraIntrinsics | None = None, config=None,
                            tilted: bool = True, reference_offset_mm: float = 0.0, advance=None,
                            squares: str = "white", k_folds: int = 5, provenance: dict | None = None) -> DepthRun:
    """Fit a depth calibration on a wall dataset (``stations.csv``) or a board dataset (``board.json``).

    Parameters
    ----------
    path : dataset folder; the kind is detected from its content
    intrinsics : IR/depth intrinsics; None -> the captures' (wall) / fitted from the board corners (board)
    config : DepthFitConfig of the wall fit (default ``DepthFitConfig()``); unused in board mode
    tilted : wall mode: fit the wall's orientation per station (else perpendicular to the axis)
    reference_offset_mm : wall mode: distance from the stations' reference point forward to the optical centre
    squares, k_folds : board mode: squares used ("white" / "all") and folds of the pose-wise cross-validation
    provenance : extra provenance entries stored in the calibration (e.g. the command line)
    """
    path = Path(path)
    if (path / "board.json").is_file():
        return _calibrate_board(path, intrinsics, squares, k_folds, advance, provenance)
    if not (path / "stations.csv").is_file():
        raise InputError(f"{path}: neither a wall dataset (stations.csv) nor a board dataset (board.json)")
    from tofmetry.calibrate._fit import DepthFitConfig, fit_depth_model
    from tofmetry.calibrate._wall import wall_sample

    t0 = time.perf_counter()
    cfg = config or DepthFitConfig()
    ds, caps, intr, src, sensor, notes = _open_wall(path, intrinsics, 2)
    stats = _station_stats(caps, intr, _adv(advance))
    keep = _usable(stats, ds.stations, notes)
    samples, used = [], []
    for i in keep:
        st, s = ds.stations[i], stats[i]
        try:
            smp, _ = wall_sample(s.mean_mm, st.distance_mm - reference_offset_mm, intr, name=st.name, frontal=not tilted)
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
    res = fit_depth_model(samples, intr, cfg, sensor=sensor, provenance=prov)
    cal = res.calibration
    rows = []
    for st, row, s in zip(stations, res.samples, stats):
        sl = s.std_mm[np.isfinite(s.std_mm)]
        row["center_std_mm"] = s.center_std_mm
        row["pixel_std_median_mm"] = float(np.median(sl)) if len(sl) else float("nan")
        rows.append({"station": st.name, "distance_mm": st.distance_mm, **row})
    cal.diagnostics["samples"] = res.samples
    frame_points = [(row["center_mm"], s.frame_center_mm - st.distance_mm + reference_offset_mm)
                    for row, s, st in zip(res.samples, stats, stations)]
    return DepthRun("wall", cal, intr, src, sensor, rows, {"history": res.history, "fit_seconds": res.seconds,
                                                              "range_model": cal.diagnostics.get("range_model"),
                                                              "range_model_cv_rms_mm": cal.diagnostics.get("range_model_cv_rms_mm")},
                    time.perf_counter() - t0, notes, str(path), res.range_points, frame_points)


def _calibrate_board(path: Path, intrinsics, squares: str, k_folds: int, advance, provenance) -> DepthRun:
    from tofmetry.calibrate.board import calibrate_depth_from_board, reprojection_rms_with
    from tofmetry.io.board_dataset import BoardDataset

    t0 = time.perf_counter()
    adv = _adv(advance)
    ds = BoardDataset(path)
    if len(ds) == 0:
        raise InputError(f"{path}: no poses/ in the board dataset")
    notes: list[str] = []
    names = list(ds.names)
    poses = []
    for i in range(len(ds)):
        depth, ir, c = ds.load_poses([i])[0]
        if c is None:
            c = detect_corners(ir, ds.board.size)
            if c is None:
                notes.append(f"pose {names[i]}: no corners.json and the board was not found in the IR image: skipped")
        poses.append((depth, ir, c))
        adv()
    keep = [i for i, p in enumerate(poses) if p[2] is not None]
    names, poses = [names[i] for i in keep], [poses[i] for i in keep]
    if len(poses) < 3:
        raise EstimationError(f"{path}: only {len(poses)} poses with board corners (need >= 3)")
    size = (poses[0][0].shape[1], poses[0][0].shape[0])
    corners = [p[2] for p in poses]
    fit = calibrate_intrinsics(corners, names, ds.board.size, ds.board.square_mm, size, leave_one_out=False)
    excl = [names.index(n) for n in fit.rejected_views]
    cv = cross_validate_intrinsics(corners, ds.board.size, ds.board.square_mm, size, k=k_folds, exclude=excl)
    ifit = {"intrinsics": fit.intrinsics.to_dict(), "rms_px": fit.rms_px, "rejected_views": fit.rejected_views,
            "rejected_rms_px": fit.rejected_rms_px, "cv_rms_px": cv["rms_px"], "cv_max_px": cv["max_px"], "k": cv["k"]}
    if fit.rejected_views:
        notes.append(f"poses with inconsistent corners left out (intrinsics and depth): {', '.join(fit.rejected_views)}")
        keep = [j for j, n in enumerate(names) if n not in set(fit.rejected_views)]
        names, poses = [names[j] for j in keep], [poses[j] for j in keep]
    if intrinsics is not None:
        intr, src = intrinsics, "given"
        r = reprojection_rms_with(intr, [p[2] for p in poses], ds.board.size, ds.board.square_mm)
        ifit["given_rms_px"] = float(np.sqrt(np.mean(r ** 2)))
    else:
        intr, src = fit.intrinsics, f"fitted on the board corners ({len(fit.used)} poses, held-out {cv['rms_px']:.3f} px)"
    ds_intr = ds.intrinsics()
    if ds_intr is not None:
        r = reprojection_rms_with(ds_intr, [p[2] for p in poses], ds.board.size, ds.board.square_mm)
        ifit["dataset_intrinsics_rms_px"] = float(np.sqrt(np.mean(r ** 2)))
    shift = ds.depth_shift_mm()
    if shift is None:
        notes.append("no depth_shift.json: the 'iai constant shift' case is not evaluated")
    res = calibrate_depth_from_board(poses, ds.board.size, ds.board.square_mm, intr, squares=squares, k_folds=k_folds,
                                     iai_shift_mm=shift, sensor=ds.sensor)
    for i, why in res.skipped:
        notes.append(f"pose {names[i]} skipped: {why}")
    iai = None
    if shift is not None and ds_intr is not None:
        # iai_kinect2's own pipeline: its intrinsics (intrinsics.json of the dataset) + its constant
        # shift, each case judged against the board plane of its own intrinsics
        adv()
        theirs = calibrate_depth_from_board(poses, ds.board.size, ds.board.square_mm, ds_intr, squares=squares,
                                            k_folds=k_folds, iai_shift_mm=shift, sensor=ds.sensor)
        iai = {"none": theirs.cv["none"], "iai_shift": theirs.cv["iai_shift"]}
    prov = _provenance({"board_dataset": str(path), "intrinsics_source": src, "squares": squares,
                        "poses": [names[i] for i in res.pose_index], **(provenance or {})})
    cal = res.depth_calibration(intr, ds.sensor, prov)
    rows = [{"pose": names[i], "n_samples": int(n), "pose_rms_px": float(p), "dark_minus_white_mm": float(dw),
             **{f"held_out_rms_{c}_mm": float(v[j]) for c, v in res.cv_per_pose.items()}}
            for j, (i, n, p, dw) in enumerate(zip(res.pose_index, res.n_samples, res.pose_rms_px, res.dark_minus_white_mm))]
    fitd = {"board": {"cols": ds.board.cols, "rows": ds.board.rows, "square_mm": ds.board.square_mm},
            "squares": squares, "iai_shift_mm": shift, "intrinsics_fit": ifit, **res.summary(),
            "iai_pipeline_held_out": iai}
    return DepthRun("board", cal, intr, src, ds.sensor, rows, fitd, time.perf_counter() - t0, notes, str(path),
                    board_result=res, intrinsics_run=fit)


def write_depth_report(run: DepthRun, folder: Path) -> list[Path]:
    """``fit.json`` + wall: ``range_curve.png`` (Fig. 7a), ``std_vs_range.png`` (Fig. 7b);
    board: ``board_calibration.png`` and ``intrinsics.json`` (the intrinsics used)."""
    from tofmetry.calibrate import _figures as F
    from tofmetry.io import atomic_write_json, write_intrinsics

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = [atomic_write_json(folder / "fit.json", run.to_dict())]
    if run.kind == "wall":
        out.append(_save_fig(F.fig_range_curve(run.calibration, run.range_points, run.frame_points),
                             folder / "range_curve.png"))
        out.append(_save_fig(F.fig_std_vs_range([r["distance_mm"] for r in run.rows], [r["center_std_mm"] for r in run.rows],
                                                [r["pixel_std_median_mm"] for r in run.rows]), folder / "std_vs_range.png"))
    else:
        out.append(_save_fig(F.fig_board_calibration(run.board_result), folder / "board_calibration.png"))
        out.append(write_intrinsics(folder / "intrinsics.json", run.intrinsics, sensor=run.sensor,
                                    source=run.intrinsics_source))
    return out


# ============================================================================ validation
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
    from tofmetry.calibrate._fit import DepthFitConfig
    from tofmetry.calibrate._validate import cross_validate as _cv
    from tofmetry.calibrate._validate import evaluate_wall_station, summarize, with_surface
    from tofmetry.calibrate._wall import wall_sample

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
    from tofmetry.calibrate import _figures as F
    from tofmetry.io import atomic_write_json

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


__all__ = [
    "DepthRun", "IntrinsicsRun", "ValidationRun", "calibrate_depth_dataset", "intrinsics_from_images",
    "validate_depth", "write_depth_report", "write_intrinsics_report", "write_validation_report", "PARAMS",
]
