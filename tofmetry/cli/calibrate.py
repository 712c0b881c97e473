"""CLI commands: ``calibrate intrinsics|depth|validate`` and ``correct`` (thin layer over tofmetry.calibrate)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from tofmetry.cli._common import console, load_intrinsics_option, progress

calibrate_app = typer.Typer(help="Calibrate the camera: IR intrinsics (checkerboard) and ToF depth (wall).",
                            no_args_is_help=True)


# ------------------------------------------------------------------ helpers
def _fit_config(surface: str, poly_degree: int, knots: str, iterations: int, range_model: str = "auto",
                modulation_mhz: str | None = None):
    from tofmetry.calibrate import DepthFitConfig, SurfaceSpec
    from tofmetry.errors import InputError

    try:
        ku, kv = (int(x) for x in knots.lower().split("x"))
    except ValueError:
        raise InputError(f"--knots must be like 6x5 (interior knots along u and v), found {knots!r}") from None
    if surface not in ("spline", "poly", "none"):
        raise InputError(f"--surface must be spline, poly or none, found {surface!r}")
    if range_model not in ("auto", "spline", "harmonic"):
        raise InputError(f"--range-model must be auto, spline or harmonic, found {range_model!r}")
    mod = None
    if modulation_mhz is not None:
        try:
            mod = tuple(float(x) for x in modulation_mhz.split(",") if x.strip())
        except ValueError:
            raise InputError(f"--modulation-mhz must be comma-separated MHz like 80,16,120, found {modulation_mhz!r}") from None
        if any(not f > 0 for f in mod):
            raise InputError(f"--modulation-mhz: frequencies must be positive, found {modulation_mhz!r}")
    return DepthFitConfig(surface=SurfaceSpec(model=surface, degree=poly_degree, knots=(ku, kv)), iterations=iterations,
                          range_model=range_model, modulation_mhz=mod)


def _report_table(reports, title: str):
    from rich.table import Table

    t = Table(title=title)
    for col in ("station", "D [mm]", "dev before", "dev after", "plane std before", "plane std after",
                "RMS raw before", "RMS before (offset removed)", "RMS after", "outside"):
        t.add_column(col, justify="right")
    for r in reports:
        t.add_row(r.name, f"{r.distance_mm:.0f}", f"{r.dev_before_mm:+.2f}", f"{r.dev_after_mm:+.2f}",
                  f"{r.plane_std_before_mm:.2f}", f"{r.plane_std_after_mm:.2f}", f"{r.rms_raw_before_mm:.2f}", f"{r.rms_before_mm:.2f}",
                  f"{r.rms_after_mm:.2f}", str(r.n_outside_range))
    return t


def _notes(notes) -> None:
    for n in notes:
        console.print(f"[yellow]note:[/] {n}")


# ------------------------------------------------------------------ intrinsics
def intrinsics_cmd(
    images_dir: Path = typer.Argument(..., help="Folder of IR (16-bit) or colour images of a checkerboard."),
    board: str = typer.Option(..., "--board", help="Inner corners COLSxROWS, e.g. 9x6."),
    square_mm: float = typer.Option(..., "--square-mm", help="Square size [mm]."),
    output: Path = typer.Option(..., "-o", "--output", help="intrinsics.json to write."),
    yaml: Optional[Path] = typer.Option(None, "--yaml", help="OpenCV YAML export (default: calib_ir.yaml next to "
                                        "the output)."),
    report: Optional[Path] = typer.Option(None, "--report", help="Folder for report JSON + figures "
                                          "(default: <output stem>_report next to the output)."),
    fix_k3: bool = typer.Option(False, "--fix-k3", help="Keep k3 = 0."),
    no_loo: bool = typer.Option(False, "--no-loo", help="Skip the leave-one-out stability analysis."),
    force: bool = typer.Option(False, "--force", help="Overwrite outputs."),
) -> None:
    """Estimate fx, fy, cx, cy, k1, k2, p1, p2, k3 from checkerboard images (outlier views rejected,
    uncertainties, leave-one-out stability, 5-fold held-out reprojection error)."""
    from rich.table import Table

    from tofmetry.calibrate import PARAMS
    from tofmetry.pipelines import intrinsics_from_images, write_intrinsics_report
    from tofmetry.errors import InputError
    from tofmetry.io import write_intrinsics
    from tofmetry.io.board_dataset import BoardSpec
    from tofmetry.io.iai_kinect2 import write_calib_ir

    spec = BoardSpec.parse(board, square_mm)
    if output.exists() and not force:
        raise InputError(f"output {output} exists; pass --force to overwrite it")
    with progress("detect corners, calibrate, leave-one-out, cross-validate", None) as adv:
        run = intrinsics_from_images(images_dir, spec.size, spec.square_mm, leave_one_out=not no_loo, fix_k3=fix_k3,
                                     advance=adv)
    res = run.result
    if run.rejected:
        console.print(f"[yellow]board not found in {len(run.rejected)} image(s), rejected:[/] {', '.join(run.rejected)}")
    t = Table(title=f"intrinsics from {len(res.used)} images (RMS {res.rms_px:.3f} px)")
    for col in ("param", "value", "std. uncertainty", "leave-one-out std", "leave-one-out range"):
        t.add_column(col, justify="right")
    vals = dict(zip(PARAMS, [res.intrinsics.fx, res.intrinsics.fy, res.intrinsics.cx, res.intrinsics.cy,
                             *res.intrinsics.distortion]))
    for p in PARAMS:
        t.add_row(p, f"{vals[p]:.5g}", f"{res.std[p]:.3g}", f"{res.loo.get(p, float('nan')):.3g}",
                  f"{res.loo_range.get(p, float('nan')):.3g}")
    console.print(t)
    worst = sorted(res.per_image_rms_px.items(), key=lambda kv: -kv[1])[:3]
    console.print("per-image RMS \\[px], worst kept: " + ", ".join(f"{k} {v:.3f}" for k, v in worst))
    if run.cv:
        console.print(f"{run.cv['k']}-fold held-out reprojection RMS: {run.cv['rms_px']:.3f} px "
                      f"(max {run.cv['max_px']:.3f} px)")
    for w in res.warnings:
        console.print(f"[yellow]warning:[/] {w}")
    write_intrinsics(output, res.intrinsics, rms_px=res.rms_px, std=res.std, n_images=len(res.used))
    ypath = yaml or output.with_name("calib_ir.yaml")
    write_calib_ir(ypath, res.intrinsics)
    rdir = report or output.with_name(f"{output.stem}_report")
    write_intrinsics_report(run, rdir)
    console.print(f"wrote {output}, {ypath} and {rdir}/")


# ------------------------------------------------------------------ depth
def depth(
    dataset: Path = typer.Argument(..., help="Wall dataset (stations.csv + one capture per station) or board "
                                   "dataset (board.json + poses/, e.g. from 'tofmetry import iai-kinect2')."),
    output: Path = typer.Option(..., "-o", "--output", help="Calibration file to write (.npz)."),
    intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="intrinsics.json (wall: overrides the "
                                              "captures'; board: used instead of fitting them on the corners)."),
    surface: str = typer.Option("spline", help="Wall: per-pixel surface model: spline, poly or none."),
    poly_degree: int = typer.Option(3, help="Wall: total degree of the polynomial surface."),
    knots: str = typer.Option("6x5", help="Wall: interior knots (u x v) of the tensor-spline surface."),
    iterations: int = typer.Option(4, help="Wall: alternations between range curve and surfaces."),
    range_model: str = typer.Option("auto", help="Wall: range-error curve: spline (the study's smoothing B-spline), "
                                    "harmonic (trend + harmonics of the modulation half wavelengths) or auto (the one "
                                    "predicting left-out stations best)."),
    modulation_mhz: Optional[str] = typer.Option(None, help="Wall: modulation frequencies [MHz], e.g. 80,16,120 "
                                                 "(default: the sensor profile's; empty string: none, spline only)."),
    tilted: bool = typer.Option(True, "--tilted/--frontal", help="Wall: fit the wall orientation (tilt) per station, "
                                "or take the wall perpendicular to the optical axis."),
    reference_offset_mm: float = typer.Option(0.0, help="Wall: known distance [mm] from the stations' reference point "
                                              "forward to the optical centre (subtracted from the distances)."),
    squares: str = typer.Option("white", "--squares", help="Board: squares used, white (dark squares read longer) or all."),
    folds: int = typer.Option(5, "--folds", help="Board: k-fold cross-validation over poses."),
    report: Optional[Path] = typer.Option(None, "--report", help="Folder for the fit report (JSON + figures)."),
    force: bool = typer.Option(False, "--force", help="Overwrite the output."),
) -> None:
    """Fit a depth calibration on a wall dataset (range B-spline + per-pixel surfaces) or, when the
    folder holds board.json, on a board dataset (board planes as reference, cross-validated over poses)."""
    import sys

    from rich.table import Table

    from tofmetry.calibrate import save_calibration
    from tofmetry.pipelines import calibrate_depth_dataset, write_depth_report
    from tofmetry.errors import InputError

    if output.exists() and not force:
        raise InputError(f"output {output} exists; pass --force to overwrite it")
    cfg = _fit_config(surface, poly_degree, knots, iterations, range_model, modulation_mhz)
    with progress(f"calibrating depth on {dataset.name}", None) as adv:
        run = calibrate_depth_dataset(dataset, intrinsics=load_intrinsics_option(intrinsics), config=cfg, tilted=tilted,
                                      reference_offset_mm=reference_offset_mm, advance=adv, squares=squares,
                                      k_folds=folds, provenance={"command": " ".join(sys.argv)})
    _notes(run.notes)
    cal = run.calibration
    save_calibration(output, cal)
    if run.kind == "wall":
        t = Table(title=f"depth calibration fit ({cal.surface_model}; intrinsics: {run.intrinsics_source})")
        for col in ("station", "D [mm]", "measured [mm]", "dev [mm]", "residual [mm]", "RMS before", "RMS after",
                    "frame std [mm]"):
            t.add_column(col, justify="right")
        for row in run.rows:
            t.add_row(row["station"], f"{row['distance_mm']:.0f}", f"{row['center_mm']:.1f}",
                      f"{row['dev_before_mm']:+.2f}", f"{row['dev_after_mm']:+.3f}", f"{row['rms_before_mm']:.2f}",
                      f"{row['rms_after_mm']:.2f}", f"{row['center_std_mm']:.2f}")
        console.print(t)
        cv = cal.diagnostics.get("range_model_cv_rms_mm", {})
        chosen = cal.diagnostics.get("range_model", "spline")
        console.print(f"range-error model: {chosen} (of {len(cv)} candidates; left-out station RMS "
                      f"{cv.get(chosen, float('nan')):.2f} mm, smoothing spline {cv.get('spline', float('nan')):.2f} mm)")
        console.print(f"offset (reference point -> optical centre + mean range bias): {cal.offset_mm:+.2f} mm; "
                      f"valid range {cal.valid_range_mm[0]:.0f}-{cal.valid_range_mm[1]:.0f} mm")
    else:
        fit = run.fit
        ifit = fit["intrinsics_fit"]
        console.print(f"board {fit['board']['cols']}x{fit['board']['rows']} inner corners, {fit['board']['square_mm']} mm; "
                      f"{fit['n_poses']} poses used, squares: {fit['squares']}")
        console.print(f"intrinsics from the corners: RMS {ifit['rms_px']:.3f} px, held-out ({ifit['k']}-fold) "
                      f"{ifit['cv_rms_px']:.3f} px; used: {run.intrinsics_source}")
        t = Table(title=f"board-plane error on held-out poses ({fit['k_folds']}-fold over poses), mm")
        for col in ("case", "mean", "std", "RMS", "P95 |e|", "n"):
            t.add_column(col, justify="right")
        labels = {"none": "none", "iai_shift": "iai shift, our intrinsics", "constant_refit": "constant (refit)",
                  "model": "tofmetry"}
        cases = [(labels[c], fit["cv_held_out"].get(c)) for c in ("none", "iai_shift", "constant_refit", "model")]
        if fit.get("iai_pipeline_held_out"):
            ip = fit["iai_pipeline_held_out"]
            cases = [("none, iai intrinsics", ip["none"]), ("iai_kinect2 (intr. + shift)", ip["iai_shift"]),
                     *cases]
        for label, st in cases:
            if st is not None:
                t.add_row(label, f"{st['mean_mm']:+.2f}", f"{st['std_mm']:.2f}", f"{st['rms_mm']:.2f}",
                          f"{st['p95_abs_mm']:.2f}", str(st["n"]))
        console.print(t)
        console.print("(cases without a note use the intrinsics above; each case is judged against the board "
                      "plane of its own intrinsics)")
    if report is not None:
        write_depth_report(run, report)
        console.print(f"report written to {report}")
    console.print(f"wrote {output} in {run.seconds:.1f} s")


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
    from tofmetry.calibrate import load_calibration
    from tofmetry.pipelines import validate_depth, write_validation_report
    from tofmetry.errors import InputError

    if output is not None and (output / "validation.json").exists() and not force:
        raise InputError(f"{output / 'validation.json'} exists; pass --force to overwrite it")
    cal = load_calibration(calibration)
    with progress(f"validating on {wall_dir.name}", None) as adv:
        run = validate_depth(wall_dir, cal, intrinsics=load_intrinsics_option(intrinsics), tilted=tilted,
                             reference_offset_mm=reference_offset_mm, cross_validate=cv, advance=adv)
    _notes(run.notes)
    console.print(_report_table(run.stations, f"validation on {wall_dir} (before -> after, mm)"))
    console.print(run.summary)
    for label, r in (run.cross_validation or {}).items():
        console.print(_report_table(r["stations"], f"leave-one-station-out, {label} surfaces"))
        console.print({label: r["summary"]})
    if output is not None:
        write_validation_report(run, output)
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
