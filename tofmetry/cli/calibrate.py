"""CLI commands: ``calibrate intrinsics|depth|validate`` and ``correct`` (thin layer over tofmetry.calibrate)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from tofmetry.cli._common import console, load_intrinsics_option, progress

calibrate_app = typer.Typer(help="Calibrate the camera: IR intrinsics (checkerboard) and ToF depth (wall).",
                            no_args_is_help=True)


# ------------------------------------------------------------------ helpers
def _save_fig(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _load_wall(wall_dir: Path, intrinsics: Optional[Path], min_stations: int = 2, what: str = "wall", given=None):
    """Stream every station of a wall dataset into statistics.

    ``given``: CameraIntrinsics to use instead of ``--intrinsics`` / the captures' (validation).
    Returns (dataset, intrinsics, source, sensor, [StationStats]).
    """
    import numpy as np

    from tofmetry.calibrate import station_statistics
    from tofmetry.errors import SensorMismatchError
    from tofmetry.io import WallDataset

    ds = WallDataset(wall_dir, min_stations=min_stations)
    override = given if given is not None else load_intrinsics_option(intrinsics)
    caps = [st.open() for st in ds.stations]
    intr, src = caps[0].intrinsics(override)
    sensor = caps[0].sensor
    for st, cap in zip(ds.stations, caps):
        if cap.shape != intr.shape:
            raise SensorMismatchError(f"{st.path}: depth is {cap.shape[1]}x{cap.shape[0]}, "
                                      f"intrinsics ({src}) are {intr.width}x{intr.height}")
        if cap.sensor != sensor:
            raise SensorMismatchError(f"{st.path}: sensor {cap.sensor!r} differs from {caps[0].path} ({sensor!r})")
    if override is None and caps[0].meta.intrinsics is None:
        console.print(f"[yellow]note:[/] no --intrinsics and none in the captures: using the {src}")
    stats = []
    from concurrent.futures import ThreadPoolExecutor

    with progress(f"reading {what} stations", sum(len(c) for c in caps)) as adv, ThreadPoolExecutor(2) as pool:
        for cap in caps:
            # PNG decoding releases the GIL: two reader threads, frames consumed in order
            frames = pool.map(cap.depth, range(len(cap)))
            stats.append(station_statistics(frames, cap.shape, intr.cx, intr.cy, advance=adv))
    del np
    return ds, intr, src, sensor, stats


def _fit_config(surface: str, poly_degree: int, knots: str, iterations: int):
    from tofmetry.calibrate import DepthFitConfig, SurfaceSpec
    from tofmetry.errors import InputError

    try:
        ku, kv = (int(x) for x in knots.lower().split("x"))
    except ValueError:
        raise InputError(f"--knots must be like 6x5 (interior knots along u and v), found {knots!r}") from None
    if surface not in ("spline", "poly", "none"):
        raise InputError(f"--surface must be spline, poly or none, found {surface!r}")
    return DepthFitConfig(surface=SurfaceSpec(model=surface, degree=poly_degree, knots=(ku, kv)), iterations=iterations)


def _report_table(reports, title: str):
    from rich.table import Table

    t = Table(title=title)
    for col in ("station", "D [mm]", "dev before", "dev after", "plane std before", "plane std after",
                "RMS before", "RMS after", "outside"):
        t.add_column(col, justify="right")
    for r in reports:
        t.add_row(r.name, f"{r.distance_mm:.0f}", f"{r.dev_before_mm:+.2f}", f"{r.dev_after_mm:+.2f}",
                  f"{r.plane_std_before_mm:.2f}", f"{r.plane_std_after_mm:.2f}", f"{r.rms_before_mm:.2f}",
                  f"{r.rms_after_mm:.2f}", str(r.n_outside_range))
    return t


# ------------------------------------------------------------------ intrinsics
_IMG_SUFFIXES = (".png", ".tif", ".tiff", ".npy", ".jpg", ".jpeg")


def _write_calib_yaml(path: Path, intr) -> Path:
    try:
        from tofmetry.io.iai_kinect2 import write_calib_ir
    except ImportError:  # fallback: OpenCV's own !!opencv-matrix YAML
        import cv2
        import numpy as np

        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        fs.write("cameraMatrix", intr.K)
        fs.write("distortionCoefficients", np.asarray(intr.dist_array, float).reshape(1, 5))
        fs.write("rotation", np.eye(3))
        fs.write("projection", np.hstack([intr.K, np.zeros((3, 1))]))
        fs.release()
        return path
    return write_calib_ir(path, intr)


def intrinsics_cmd(
    images_dir: Path = typer.Argument(..., help="Folder of IR (16-bit) or colour images of a checkerboard."),
    board: str = typer.Option(..., "--board", help="Inner corners COLSxROWS, e.g. 9x6."),
    square_mm: float = typer.Option(..., "--square-mm", help="Square size [mm]."),
    output: Path = typer.Option(..., "-o", "--output", help="intrinsics.json to write."),
    yaml: Optional[Path] = typer.Option(None, "--yaml", help="OpenCV YAML export (default: calib_ir.yaml next to "
                                        "the output)."),
    report: Optional[Path] = typer.Option(None, "--report", help="Folder for report JSON + coverage map "
                                          "(default: <output stem>_report next to the output)."),
    fix_k3: bool = typer.Option(False, "--fix-k3", help="Keep k3 = 0."),
    no_loo: bool = typer.Option(False, "--no-loo", help="Skip the leave-one-out stability analysis."),
    force: bool = typer.Option(False, "--force", help="Overwrite outputs."),
) -> None:
    """Estimate fx, fy, cx, cy, k1, k2, p1, p2, k3 from checkerboard images (with uncertainties and stability)."""
    from rich.table import Table

    from tofmetry.calibrate import _figures as F
    from tofmetry.calibrate._intrinsics import PARAMS, calibrate_intrinsics, detect_corners, normalize_ir
    from tofmetry.errors import InputError
    from tofmetry.io import atomic_write_json, write_intrinsics
    from tofmetry.io.images import read_color_image, read_ir_image

    try:
        cols, rows = (int(x) for x in board.lower().split("x"))
    except ValueError:
        raise InputError(f"--board must be COLSxROWS (inner corners), e.g. 9x6; found {board!r}") from None
    if cols < 2 or rows < 2 or not square_mm > 0:
        raise InputError(f"--board needs >= 2x2 inner corners and --square-mm > 0; found {board}, {square_mm}")
    if output.exists() and not force:
        raise InputError(f"output {output} exists; pass --force to overwrite it")
    if not images_dir.is_dir():
        raise InputError(f"images folder not found: {images_dir}")
    files = sorted(p for p in images_dir.iterdir() if p.suffix.lower() in _IMG_SUFFIXES and not p.name.startswith("."))
    if not files:
        raise InputError(f"{images_dir}: no images ({', '.join(_IMG_SUFFIXES)})")
    corners, names, rejected, size = [], [], [], None
    with progress("detecting corners", len(files)) as adv:
        for f in files:
            img = read_color_image(f) if f.suffix.lower() in (".jpg", ".jpeg") else read_ir_image(f)
            s = (img.shape[1], img.shape[0])
            if size is None:
                size = s
            elif s != size:
                raise InputError(f"{f}: size {s[0]}x{s[1]} differs from the first image's {size[0]}x{size[1]}")
            c = detect_corners(normalize_ir(img), (cols, rows))
            if c is None:
                rejected.append(f.name)
            else:
                corners.append(c)
                names.append(f.name)
            adv()
    if rejected:
        console.print(f"[yellow]board not found in {len(rejected)} image(s), rejected:[/] {', '.join(rejected)}")
    with progress("leave-one-out refits", 0 if no_loo else len(corners)) as adv:
        res = calibrate_intrinsics(corners, names, (cols, rows), square_mm, size, leave_one_out=not no_loo,
                                   fix_k3=fix_k3, advance=adv)
    t = Table(title=f"intrinsics from {len(names)} images (RMS {res.rms_px:.3f} px)")
    for col in ("param", "value", "std. uncertainty", "leave-one-out std", "leave-one-out range"):
        t.add_column(col, justify="right")
    vals = dict(zip(PARAMS, [res.intrinsics.fx, res.intrinsics.fy, res.intrinsics.cx, res.intrinsics.cy,
                             *res.intrinsics.distortion]))
    for p in PARAMS:
        t.add_row(p, f"{vals[p]:.5g}", f"{res.std[p]:.3g}", f"{res.loo.get(p, float('nan')):.3g}",
                  f"{res.loo_range.get(p, float('nan')):.3g}")
    console.print(t)
    worst = sorted(res.per_image_rms_px.items(), key=lambda kv: -kv[1])[:3]
    console.print("per-image RMS [px], worst: " + ", ".join(f"{k} {v:.3f}" for k, v in worst))
    for w in res.warnings:
        console.print(f"[yellow]warning:[/] {w}")
    write_intrinsics(output, res.intrinsics, rms_px=res.rms_px, std=res.std, n_images=len(names))
    ypath = yaml or output.with_name("calib_ir.yaml")
    _write_calib_yaml(ypath, res.intrinsics)
    rdir = report or output.with_name(f"{output.stem}_report")
    rdir.mkdir(parents=True, exist_ok=True)
    atomic_write_json(rdir / "intrinsics_report.json", {**res.to_dict(), "rejected": rejected,
                                                        "board": [cols, rows], "square_mm": square_mm})
    _save_fig(F.fig_coverage(corners, (size[1], size[0]),
                             f"Corner coverage: {len(names)} images, {100 * res.coverage:.0f} % of the area, "
                             f"{100 * res.cell_coverage:.0f} % of 8x8 cells"),
              rdir / "coverage.png")
    console.print(f"wrote {output}, {ypath} and {rdir}/")


# ------------------------------------------------------------------ depth
def depth(
    wall_dir: Path = typer.Argument(..., help="Wall dataset (stations.csv + one capture per station)."),
    output: Path = typer.Option(..., "-o", "--output", help="Calibration file to write (.npz)."),
    intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="intrinsics.json (overrides the captures')."),
    surface: str = typer.Option("spline", help="Per-pixel surface model: spline, poly or none."),
    poly_degree: int = typer.Option(3, help="Total degree of the polynomial surface."),
    knots: str = typer.Option("6x5", help="Interior knots (u x v) of the tensor-spline surface."),
    iterations: int = typer.Option(4, help="Alternations between range curve and surfaces."),
    tilted: bool = typer.Option(True, "--tilted/--frontal", help="Fit the wall orientation (tilt) per station, "
                                "or take the wall perpendicular to the optical axis."),
    reference_offset_mm: float = typer.Option(0.0, help="Known distance [mm] from the stations' reference point "
                                              "forward to the optical centre (subtracted from the distances)."),
    report: Optional[Path] = typer.Option(None, "--report", help="Folder for the fit report (JSON + figures)."),
    force: bool = typer.Option(False, "--force", help="Overwrite the output."),
) -> None:
    """Fit a depth calibration (range B-spline + per-pixel surfaces) on a wall dataset."""
    import sys
    import time

    import numpy as np

    import tofmetry
    from tofmetry.calibrate import fit_depth_model, save_calibration, wall_sample
    from tofmetry.errors import InputError

    if output.exists() and not force:
        raise InputError(f"output {output} exists; pass --force to overwrite it")
    t0 = time.perf_counter()
    cfg = _fit_config(surface, poly_degree, knots, iterations)
    ds, intr, src, sensor, stats = _load_wall(wall_dir, intrinsics)
    samples = []
    for st, s in zip(ds.stations, stats):
        smp, _ = wall_sample(s.mean_mm, st.distance_mm - reference_offset_mm, intr, name=st.name, frontal=not tilted)
        samples.append(smp)
    prov = {"tool": f"tofmetry {tofmetry.__version__}", "command": " ".join(sys.argv),
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "wall_dataset": str(wall_dir),
            "intrinsics_source": src, "reference_offset_mm": reference_offset_mm, "tilted": tilted,
            "stations": [{"name": st.name, "distance_mm": st.distance_mm, "n_frames": s.n_frames}
                         for st, s in zip(ds.stations, stats)]}
    res = fit_depth_model(samples, intr, cfg, sensor=sensor, provenance=prov)
    cal = res.calibration
    for row, s in zip(res.samples, stats):
        sl_std = s.std_mm[~np.isnan(s.std_mm)]
        row["center_std_mm"] = s.center_std_mm
        row["pixel_std_median_mm"] = float(np.median(sl_std)) if len(sl_std) else float("nan")
    cal.diagnostics["samples"] = res.samples
    save_calibration(output, cal)
    from rich.table import Table

    t = Table(title=f"depth calibration fit ({cal.surface_model}; intrinsics: {src})")
    for col in ("station", "D [mm]", "measured [mm]", "dev [mm]", "residual [mm]", "RMS before", "RMS after",
                "frame std [mm]"):
        t.add_column(col, justify="right")
    for st, row in zip(ds.stations, res.samples):
        t.add_row(st.name, f"{st.distance_mm:.0f}", f"{row['center_mm']:.1f}", f"{row['dev_before_mm']:+.2f}",
                  f"{row['dev_after_mm']:+.3f}", f"{row['rms_before_mm']:.2f}", f"{row['rms_after_mm']:.2f}",
                  f"{row['center_std_mm']:.2f}")
    console.print(t)
    console.print(f"offset (reference point -> optical centre + mean range bias): {cal.offset_mm:+.2f} mm; "
                  f"valid range {cal.valid_range_mm[0]:.0f}-{cal.valid_range_mm[1]:.0f} mm")
    if report is not None:
        from tofmetry.calibrate import _figures as F
        from tofmetry.io import atomic_write_json

        report.mkdir(parents=True, exist_ok=True)
        fr = [(row["center_mm"], s.frame_center_mm - st.distance_mm + reference_offset_mm)
              for row, s, st in zip(res.samples, stats, ds.stations)]
        _save_fig(F.fig_range_curve(cal, res.range_points, fr), report / "range_curve.png")
        _save_fig(F.fig_std_vs_range([st.distance_mm for st in ds.stations], [s.center_std_mm for s in stats],
                                     [r["pixel_std_median_mm"] for r in res.samples]), report / "std_vs_range.png")
        atomic_write_json(report / "fit.json", {"summary": cal.summary(), "samples": res.samples,
                                                "history": res.history, "seconds": res.seconds})
        console.print(f"report written to {report}")
    console.print(f"wrote {output} in {time.perf_counter() - t0:.1f} s")


# ------------------------------------------------------------------ validate
def validate(
    wall_dir: Path = typer.Argument(..., help="Wall dataset to validate on (ideally not used for the fit)."),
    calibration: Path = typer.Option(..., "--calibration", help="Calibration file (.npz)."),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="Folder for validation.json and figures."),
    intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="intrinsics.json for the clouds "
                                              "(default: the calibration's)."),
    cv: bool = typer.Option(False, "--cv", help="Also run leave-one-station-out cross-validation on WALL_DIR "
                            "(spline and polynomial surfaces)."),
    tilted: bool = typer.Option(False, "--tilted/--frontal", help="Reference wall orientation fitted on the "
                                "corrected cloud, or perpendicular to the optical axis."),
    reference_offset_mm: float = typer.Option(0.0, help="Same meaning as for 'calibrate depth'."),
    force: bool = typer.Option(False, "--force", help="Overwrite the output folder's files."),
) -> None:
    """Before/after metrics per station of a wall dataset (plus optional cross-validation)."""
    import numpy as np

    from tofmetry.calibrate import load_calibration
    from tofmetry.calibrate._validate import cross_validate, evaluate_wall_station, summarize, with_surface
    from tofmetry.errors import InputError

    if output is not None and (output / "validation.json").exists() and not force:
        raise InputError(f"{output / 'validation.json'} exists; pass --force to overwrite it")
    cal = load_calibration(calibration)
    ov = load_intrinsics_option(intrinsics)
    intr = ov or cal.intrinsics
    ds, _, _, sensor, stats = _load_wall(wall_dir, None, min_stations=1, what="validation", given=intr)
    cal.check_compatible(sensor=sensor, shape=stats[0].mean_mm.shape)
    reports, maps = [], []
    same_data = str(Path(cal.provenance.get("wall_dataset", "")).resolve()) == str(wall_dir.resolve())
    fit_names = set(cal.provenance.get("samples", [])) if same_data else set()
    if same_data:
        console.print("[yellow]note:[/] validating on the calibration's own training data (not held out); "
                      "use --cv for leave-one-station-out figures")
    for st, s in zip(ds.stations, stats):
        rep, mp = evaluate_wall_station(s.mean_mm, st.distance_mm - reference_offset_mm, cal, intr, name=st.name,
                                        frontal=not tilted, held_out=st.name not in fit_names)
        reports.append(rep)
        maps.append(mp)
    console.print(_report_table(reports, f"validation on {wall_dir} (before -> after, mm)"))
    summ = summarize(reports)
    console.print(summ)
    result = {"calibration": str(calibration), "wall_dataset": str(wall_dir), "stations": [r.to_dict() for r in reports],
              "summary": summ}
    if cv:
        from tofmetry.calibrate import DepthFitConfig, wall_sample

        samples = [wall_sample(s.mean_mm, st.distance_mm - reference_offset_mm, intr, name=st.name)[0]
                   for st, s in zip(ds.stations, stats)]
        dists = [st.distance_mm - reference_offset_mm for st in ds.stations]
        result["cross_validation"] = {}
        base = DepthFitConfig()
        for label, cfg in (("spline", with_surface(base, "spline")), ("poly3", with_surface(base, "poly", degree=3))):
            with progress(f"leave-one-station-out ({label})", max(len(samples) - 2, 0)) as adv:
                cvr = cross_validate(samples, dists, intr, cfg, frontal=not tilted, sensor=sensor, advance=adv)
            console.print(_report_table(cvr, f"leave-one-station-out, {label} surfaces"))
            result["cross_validation"][label] = {"stations": [r.to_dict() for r in cvr], "summary": summarize(cvr)}
            console.print({label: summarize(cvr)})
    if output is not None:
        from tofmetry.calibrate import _figures as F
        from tofmetry.io import atomic_write_json

        output.mkdir(parents=True, exist_ok=True)
        atomic_write_json(output / "validation.json", result)
        _save_fig(F.fig_validation(reports), output / "validation.png")
        # held-out stations at their measured central distance (the x axis of the curve)
        held = [(r.distance_mm + r.dev_before_mm + cal.offset_mm, r.dev_before_mm) for r in reports]
        pts = np.array([[r["center_mm"], r["dev_before_mm"]] for r in cal.diagnostics.get("samples", [])]) \
            if cal.diagnostics.get("samples") else np.zeros((0, 2))
        _save_fig(F.fig_range_curve(cal, pts, held_out=held),
                  output / "range_curve.png")
        _save_fig(F.fig_std_vs_range([st.distance_mm for st in ds.stations], [s.center_std_mm for s in stats]),
                  output / "std_vs_range.png")
        for st, mp in zip(ds.stations, maps):
            _save_fig(F.fig_residual_maps(mp["residual_before"], mp["residual_after"],
                                          f"Plane-fit residuals at {st.distance_mm / 1000:.3f} m ({st.name})"),
                      output / f"residuals_{st.name}.png")
        console.print(f"validation written to {output}")


# ------------------------------------------------------------------ correct
def correct(
    capture: Path = typer.Argument(..., help="Capture folder to correct."),
    calibration: Path = typer.Option(..., "--calibration", help="Calibration file (.npz)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output capture folder."),
    float32: bool = typer.Option(False, "--float32", help="Write float32 .npy depth frames instead of uint16 PNG."),
    force: bool = typer.Option(False, "--force", help="Replace an existing output folder."),
) -> None:
    """Apply a depth calibration to every frame of a capture (same format out)."""
    import numpy as np

    from tofmetry.calibrate import apply_depth_calibration, count_outside_range, load_calibration
    from tofmetry.errors import InputError
    from tofmetry.io import Capture, CaptureMeta, atomic_dir, atomic_write_bytes, atomic_write_json
    from tofmetry.io.images import write_png16

    cap = Capture(capture)
    if output.resolve() == capture.resolve():
        raise InputError("output must differ from the input capture (inputs are never overwritten)")
    cal = load_calibration(calibration)
    cal.check_compatible(sensor=cap.sensor, shape=cap.shape)
    outside = 0
    with atomic_dir(output, force=force) as tmp:
        meta = CaptureMeta(sensor=cap.sensor, depth_unit_mm=1.0, intrinsics=cal.intrinsics,
                           timestamps_s=cap.meta.timestamps_s,
                           extra={**(cap.meta.extra or {}), "depth_calibration": str(calibration),
                                  "corrected_from": str(capture)})
        atomic_write_json(tmp / "capture.json", meta.to_dict())
        (tmp / "depth").mkdir()
        with progress("correcting frames", len(cap)) as adv:
            for i in range(len(cap)):
                d = cap.depth(i)
                outside += count_outside_range(d, cal)
                c = apply_depth_calibration(d, cal)
                if float32:
                    import io

                    buf = io.BytesIO()
                    np.save(buf, np.where(d > 0, c, 0).astype(np.float32))
                    atomic_write_bytes(tmp / "depth" / f"{i:06d}.npy", buf.getvalue())
                else:
                    q = np.where(d > 0, np.clip(np.rint(c), 1, 65535), 0).astype(np.uint16)
                    write_png16(tmp / "depth" / f"{i:06d}.png", q)
                adv()
        import shutil

        for sub in ("ir", "color"):
            if (capture / sub).is_dir():
                shutil.copytree(capture / sub, tmp / sub)
    if outside:
        n = len(cap) * cap.shape[0] * cap.shape[1]
        console.print(f"[yellow]warning:[/] {outside} valid depth samples ({100 * outside / n:.2f} % of all pixels) "
                      f"outside the calibrated range {cal.valid_range_mm[0]:.0f}-{cal.valid_range_mm[1]:.0f} mm "
                      "were left uncorrected")
    console.print(f"wrote {len(cap)} corrected frames to {output}")


def register(app: typer.Typer) -> None:
    """Add ``calibrate`` (group) and ``correct``."""
    calibrate_app.command("intrinsics")(intrinsics_cmd)
    calibrate_app.command("depth")(depth)
    calibrate_app.command("validate")(validate)
    app.add_typer(calibrate_app, name="calibrate")
    app.command("correct")(correct)
