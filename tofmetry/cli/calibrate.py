"""CLI commands: ``calibrate intrinsics|depth|validate`` and ``correct`` (thin layer over tofmetry.calibrate)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from tofmetry.cli._common import (
    ACCEPT_IMPLAUSIBLE_HELP, BOARD_HELP, DICTIONARY_HELP, MARKER_HELP, SQUARES_HELP, console, load_intrinsics_option,
    parse_board, print_plausibility, progress, refuse_existing,
)
from tofmetry.cli._board import _print_board_run, _validate_board
from tofmetry.cli.stereo import rig_cmd, stereo_cmd

calibrate_app = typer.Typer(help="Calibrate the camera: IR intrinsics (checkerboard) and ToF depth (wall).",
                            rich_markup_mode=None, no_args_is_help=True)


# ------------------------------------------------------------------ helpers
def _fit_config(method: str, surface: str, poly_degree: int, fallback: str):
    from tofmetry.calibrate import DepthFitConfig, StudyFitConfig, SurfaceSpec
    from tofmetry.errors import InputError

    if method == "study":
        if surface not in ("spline", "poly", "none"):
            raise InputError(f"--surface must be spline, poly or none, found {surface!r}")
        return StudyFitConfig(surface=SurfaceSpec(model=surface, degree=poly_degree))
    if method != "tofmetry":
        raise InputError(f"--method must be tofmetry or study, found {method!r}")
    return DepthFitConfig(fallback=fallback)


def _outside_how(cal) -> str:
    """What a calibration does with depths outside its support (for warnings)."""
    if cal is None:
        return "they were left as measured"
    lo, hi = cal.support_range_mm
    if cal.support is None:
        return f"depths outside {lo:.0f}-{hi:.0f} mm were left uncorrected (a calibration without a support map)"
    how = {"hold": "the correction at the nearest fitted depth", "trend": "its straight-line trend",
           "unchanged": "no correction"}[cal.fallback]
    return f"they got the fallback ({how}; fitted depths {lo:.0f}-{hi:.0f} mm), which is not validated there"


def print_prediction(cal) -> None:
    """Print a calibration's own predicted error on new data (blocked validation) and its support."""
    pred = cal.prediction or {}
    interp = pred.get("interpolation") or {}
    if interp:
        n = interp.get("rms_mm", {}).get("n", 0)
        console.print(f"predicted error on new stations (blocked validation: each of {n} interior stations predicted "
                      "by a calibration fitted on the others), typical (RMS over the folds) [90 % interval]:")
        for key, what in (("central_abs_mm", "|central deviation|"), ("rms_systematic_mm", "per-pixel RMS, systematic"),
                          ("rms_mm", "per-pixel RMS, incl. noise of the stations' means"),
                          ("p95_mm", "p95 |error| (4x4 px means)")):
            v = interp.get(key)
            if v and v.get("n"):
                console.print(f"  {what:>48}: {v.get('predicted', v['median']):.2f} mm  [{v['p5']:.2f}, {v['p95']:.2f}]")
        ex = [r for r in pred.get("extrapolation", []) if r.get("fallback") == pred.get("fallback_chosen")]
        for r in ex:
            console.print(f"  extrapolation to {r['name']} ({r['center_mm']:.0f} mm, left out): central "
                          f"{r['central_mm']:+.2f} mm, RMS {r['rms_mm']:.2f} mm (fallback {r['fallback']})")
        for w in pred.get("warnings", []):
            console.print(f"  [yellow]warning:[/] {w}")
        tried = (cal.diagnostics or {}).get("tilt_not_folded")
        if pred.get("tilt_calibrated") is False and tried:
            t = tried
            console.print(f"  [yellow]not calibrated:[/] the board poses read a tilt of ({t['tilt_mm'][0]:+.2f} +- "
                          f"{t['sigma_mm'][0]:.2f}, {t['tilt_mm'][1]:+.2f} +- {t['sigma_mm'][1]:.2f}) mm per unit, "
                          f"not folded in: {t['held_out']['reason']}")
        elif pred.get("tilt_calibrated") is False:
            console.print("  [yellow]not calibrated:[/] a tilt-like (linear in x, y) deformation cannot be told from the "
                          "walls' tilt and is left in (it turns a scan's camera poses by about |tilt| / Z): fit it "
                          "with --tilt-boards on board captures")
        if pred.get("tilt"):
            print_tilt(pred["tilt"])
    if cal.support is not None:
        s = cal.support.summary()
        console.print(f"support: depths {s['range_mm'][0]:.0f}-{s['range_mm'][1]:.0f} mm over "
                      f"{100 * s['covered_fraction']:.0f} % of the image; outside it: fallback '{cal.fallback}' "
                      "(pixels counted by correct / cloud / reconstruct)")


def print_tilt(t: dict) -> None:
    """The depth tilt fitted on board poses (:meth:`tofmetry.calibrate.TiltFit.to_dict`)."""
    slope = "" if not t["model"].startswith("linear") else (f", changing by ({t['slope_mm_per_m'][0]:+.2f}, "
                                                           f"{t['slope_mm_per_m'][1]:+.2f}) per m")
    console.print(f"  tilt from {t['n_views']} board poses ({t['z_span_mm'][0]:.0f}-{t['z_span_mm'][1]:.0f} mm): "
                  f"({t['tilt_mm'][0]:+.2f} +- {t['sigma_mm'][0]:.2f}, {t['tilt_mm'][1]:+.2f} +- {t['sigma_mm'][1]:.2f}) "
                  f"mm per unit of x / z, y / z at {t['z_ref_mm']:.0f} mm{slope} ({t['angle_deg_at_1m']:.2f} deg at 1 m; "
                  f"views scatter by ({t['scatter_mm'][0]:.1f}, {t['scatter_mm'][1]:.1f})); folded into the calibration"
                  + (f" at ({t['shrink'][0]:.2f}, {t['shrink'][1]:.2f}) of it (its signal-to-noise)" if t.get("shrink") else ""))
    if t.get("held_out"):
        console.print(f"  held-out check: {t['held_out']['reason']}")
    if t.get("incidence_k_mm"):
        console.print(f"  (a turned board's amplitude bias, {t['incidence_k_mm']:.1f} mm per ln(1 / cos incidence), "
                      "taken off the views' tilts)")


def print_prediction_check(check: dict) -> None:
    """Print the calibration's predicted error beside what the held-out stations measured."""
    from rich.table import Table

    if not check or check.get("verdict") == "no prediction":
        return
    t = Table(title="the calibration's own prediction vs held-out stations (tilt removed; RMS over stations, mm)")
    for col in ("metric", "predicted", "90 % interval", "measured", "ratio", "in interval", "verdict"):
        t.add_column(col, justify="right")
    names = {"central_abs_mm": "|central deviation|", "rms_mm": "per-pixel RMS", "rms_systematic_mm": "RMS, systematic",
             "p95_mm": "p95 |error|"}
    for key, label in names.items():
        c = check.get(key)
        if c:
            t.add_row(label, f"{c['predicted']:.2f}", f"{c['interval'][0]:.2f}-{c['interval'][1]:.2f}",
                      f"{c['measured']:.2f}", f"{c['ratio']:.2f}", f"{100 * c['in_interval']:.0f} %", c["verdict"])
    console.print(t)
    if check["verdict"] == "fails":
        console.print("[red]the calibration's prediction fails on these stations: its measured error exceeds twice the "
                      "prediction (other conditions than the calibration's? recalibrate, or trust the measured figures)[/]")


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
    images_dir: Path = typer.Argument(..., help="Folder of checkerboard images: 8- or 16-bit grey (PNG, BMP, TIFF, "
                                      "PGM, ...), greyscale stored as colour (BMP, JPEG) or .npy."),
    board: str = typer.Option(..., "--board", help=BOARD_HELP),
    square_mm: float = typer.Option(..., "--square-mm", help="Square size [mm]."),
    output: Path = typer.Option(..., "-o", "--output", help="intrinsics.json to write."),
    squares: str = typer.Option("13x10", "--squares", help=SQUARES_HELP),
    marker_mm: float = typer.Option(56.0, "--marker-mm", help=MARKER_HELP),
    dictionary: str = typer.Option("DICT_4X4_100", "--dictionary", help=DICTIONARY_HELP),
    yaml: Optional[Path] = typer.Option(None, "--yaml", help="OpenCV YAML export (default: calib_ir.yaml next to "
                                        "the output)."),
    report: Optional[Path] = typer.Option(None, "--report", help="Folder for report JSON + figures "
                                          "(default: <output stem>_report next to the output)."),
    fix_k3: bool = typer.Option(False, "--fix-k3", help="Keep k3 = 0."),
    no_loo: bool = typer.Option(False, "--no-loo", help="Skip the leave-one-out stability analysis."),
    force: bool = typer.Option(False, "--force", help="Overwrite outputs (the JSON, the YAML and the report)."),
    accept_implausible: bool = typer.Option(False, "--accept-implausible", help=ACCEPT_IMPLAUSIBLE_HELP),
) -> None:
    """Estimate fx, fy, cx, cy, k1, k2, p1, p2, k3 from checkerboard or ChArUco images (outlier views rejected,
    uncertainties, predicted ray error over the whole image, uncovered image corners, leave-one-out
    stability, 5-fold held-out reprojection error)."""
    from rich.table import Table

    from tofmetry.calibrate import PARAMS
    from tofmetry.pipelines import intrinsics_from_images, write_intrinsics_report
    from tofmetry.io import write_intrinsics
    from tofmetry.io.iai_kinect2 import write_calib_ir

    spec, charuco = parse_board(board, square_mm, squares, marker_mm, dictionary)
    ypath = yaml or output.with_name("calib_ir.yaml")
    rdir = report or output.with_name(f"{output.stem}_report")
    refuse_existing([output, ypath, rdir], force)
    with progress("detect corners, calibrate, leave-one-out, cross-validate", None) as adv:
        run = intrinsics_from_images(images_dir, spec.size, spec.square_mm, leave_one_out=not no_loo, fix_k3=fix_k3,
                                     advance=adv, accept_implausible=accept_implausible, charuco=charuco)
    res = run.result
    if run.rejected:
        why = getattr(run, "rejected_reasons", {})
        console.print(f"[yellow]{len(run.rejected)} image(s) not used:[/] "
                      + ", ".join(f"{n} ({why.get(n, 'board not found')})" for n in run.rejected))
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
    if res.predicted_ray is not None:
        pr = res.predicted_ray
        console.print(f"predicted ray error (from the parameter covariance, full image): RMS {pr.rms_px:.3f} px, "
                      f"p90 {pr.p90_px:.3f} px, image corners up to {pr.corners_max_px:.3f} px")
    for w in res.warnings:
        console.print(f"[yellow]warning:[/] {w}")
    print_plausibility(run.plausibility)
    write_intrinsics(output, res.intrinsics, rms_px=res.rms_px, std=res.std, n_images=len(res.used),
                     plausibility=run.plausibility)
    write_calib_ir(ypath, res.intrinsics)
    write_intrinsics_report(run, rdir)
    console.print(f"wrote {output}, {ypath} and {rdir}/")


# ------------------------------------------------------------------ depth
def depth(
    dataset: Path = typer.Argument(..., help="Wall dataset (stations.csv + one capture per station) or board "
                                   "dataset (board.json + poses/, e.g. from 'tofmetry import iai-kinect2')."),
    output: Path = typer.Option(..., "-o", "--output", help="Calibration file to write (.npz)."),
    intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", help="intrinsics.json (wall: overrides the "
                                              "captures'; board: used instead of fitting them on the corners)."),
    method: str = typer.Option("tofmetry", help="Wall: tofmetry (range error along the ray + per-pixel surfaces, "
                               "chosen and judged by blocked validation) or study (the study's range spline + one "
                               "surface per station, a baseline)."),
    fallback: str = typer.Option("auto", help="Wall, tofmetry: outside the fitted depths: hold (the correction at "
                                 "the nearest fitted depth), trend (a straight line in depth) or auto (the one that "
                                 "predicted the left-out nearest and farthest stations better)."),
    surface: str = typer.Option("spline", help="Wall, study method: per-pixel surface model: spline, poly or none."),
    poly_degree: int = typer.Option(3, help="Wall, study method: total degree of the polynomial surface."),
    tilted: bool = typer.Option(True, "--tilted/--frontal", help="Wall: fit the wall orientation (tilt) per station, "
                                "or take the wall perpendicular to the optical axis."),
    reference_offset_mm: float = typer.Option(0.0, help="Wall: known distance [mm] from the stations' reference point "
                                              "forward to the optical centre (subtracted from the distances)."),
    squares: str = typer.Option("auto", "--squares", help="Board: views whose white squares saturate enter through "
                                "their dark squares (dark squares read longer: their bias is measured vs amplitude): "
                                "auto (unless they make the blocked held-out error worse by more than one standard "
                                "error), white (never) or dark (always)."),
    folds: int = typer.Option(5, "--folds", help="Board: blocks of poses in recording order (and random folds, "
                              "reported beside) of the validation."),
    train_poses: Optional[str] = typer.Option(None, "--train-poses", help="Board: poses to fit on, e.g. 0-49 "
                                              "(names or numbers, ranges, commas; default: all but the judged)."),
    judge_poses: Optional[str] = typer.Option(None, "--judge-poses", help="Board: poses held out of every fit "
                                              "(intrinsics included) and judged with the written calibration, e.g. 50-69."),
    board: Optional[str] = typer.Option(None, "--board", help="Board: the board instead of the dataset's board.json: "
                                        "inner corners COLSxROWS, e.g. 9x6, or 'charuco' (with --charuco-squares, "
                                        "--marker-mm, --dictionary); with --square-mm."),
    square_mm: Optional[float] = typer.Option(None, "--square-mm", help="Board, with --board: square size [mm]."),
    charuco_squares: str = typer.Option("13x10", "--charuco-squares", help="Board, --board charuco: squares "
                                        "COLSxROWS (not inner corners; --squares is the square choice above)."),
    marker_mm: float = typer.Option(56.0, "--marker-mm", help="Board, --board charuco: " + MARKER_HELP),
    dictionary: str = typer.Option("DICT_4X4_100", "--dictionary", help="Board, --board charuco: " + DICTIONARY_HELP),
    tilt_boards: Optional[Path] = typer.Option(None, "--tilt-boards", help="Wall: a board dataset (board.json + "
                                               "poses/, e.g. the IR intrinsics captures) on which the depth error "
                                               "linear in the image position, which walls of unknown orientation cannot "
                                               "show, is fitted and folded into the calibration."),
    report: Optional[Path] = typer.Option(None, "--report", help="Folder for the fit report (JSON + figures)."),
    force: bool = typer.Option(False, "--force", help="Overwrite the output (and the report's files)."),
    accept_implausible: bool = typer.Option(False, "--accept-implausible", help=ACCEPT_IMPLAUSIBLE_HELP),
) -> None:
    """Fit a depth calibration on a wall dataset (range B-spline + per-pixel surfaces) or, when the
    folder holds board.json, on a board dataset (board planes as reference, cross-validated over poses;
    a checkerboard or a ChArUco board, whose views may show part of it)."""
    import sys

    from rich.table import Table

    from tofmetry.pipelines import save_calibration
    from tofmetry.pipelines import calibrate_depth_dataset, write_depth_report
    from tofmetry.errors import InputError

    refuse_existing([output, report], force)
    cfg = _fit_config(method, surface, poly_degree, fallback)
    board_arg = None
    if board is not None:
        spec, charuco = parse_board(board, square_mm, charuco_squares, marker_mm, dictionary)
        board_arg = charuco if charuco is not None else spec
    if tilt_boards is not None and (dataset / "board.json").is_file():
        raise InputError(f"--tilt-boards completes a wall calibration; {dataset} is a board dataset, whose board "
                         "planes already fix the tilt")
    with progress(f"calibrating depth on {dataset.name}", None) as adv:
        if (dataset / "board.json").is_file():
            from tofmetry.pipelines.board import calibrate_board

            run = calibrate_board(dataset, load_intrinsics_option(intrinsics), squares, folds, adv,
                                  {"command": " ".join(sys.argv)}, train_poses=train_poses, judge_poses=judge_poses,
                                  accept_implausible=accept_implausible, board=board_arg)
        elif train_poses is not None or judge_poses is not None or board is not None:
            raise InputError("--train-poses / --judge-poses / --board apply to board datasets (board.json) only")
        else:
            run = calibrate_depth_dataset(dataset, intrinsics=load_intrinsics_option(intrinsics), config=cfg,
                                          tilted=tilted, reference_offset_mm=reference_offset_mm, advance=adv,
                                          squares=squares, k_folds=folds, provenance={"command": " ".join(sys.argv)},
                                          accept_implausible=accept_implausible)
        if tilt_boards is not None:
            from tofmetry.pipelines.depth_tilt import tilt_from_boards

            tr = tilt_from_boards(tilt_boards, run.calibration, advance=adv)
            run.calibration = tr.calibration
            run.fit["tilt"] = tr.to_dict()
            run.notes += [f"tilt boards: {n}" for n in tr.notes]
    _notes(run.notes)
    print_plausibility(run.plausibility)
    cal = run.calibration
    save_calibration(output, cal)
    if run.kind == "wall":
        t = Table(title=f"depth calibration fit, in sample (intrinsics: {run.intrinsics_source})")
        for col in ("station", "D [mm]", "measured [mm]", "central dev before", "after", "RMS before (offset removed)",
                    "RMS after", "frame std [mm]"):
            t.add_column(col, justify="right")
        for row in run.rows:
            t.add_row(row["station"], f"{row['distance_mm']:.0f}", f"{row['center_mm']:.1f}",
                      f"{row.get('central_before_mm', row.get('dev_before_mm', float('nan'))):+.2f}",
                      f"{row.get('central_mm', row.get('dev_after_mm', float('nan'))):+.3f}",
                      f"{row['rms_before_mm']:.2f}", f"{row.get('rms_mm', row.get('rms_after_mm', float('nan'))):.2f}",
                      f"{row['center_std_mm']:.2f}")
        console.print(t)
        console.print(f"model: {cal.diagnostics.get('model', cal.surface_model)}")
        console.print(f"offset (reference point -> optical centre + mean range bias): {cal.offset_mm:+.2f} mm")
        print_prediction(cal)
    else:
        _print_board_run(run)
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
                            "(tofmetry's method and the study's)."),
    tilted: bool = typer.Option(False, "--tilted/--frontal", help="Reference wall orientation fitted on the "
                                "corrected cloud, or perpendicular to the optical axis."),
    reference_offset_mm: float = typer.Option(0.0, help="Same meaning as for 'calibrate depth'."),
    poses: Optional[str] = typer.Option(None, "--poses", help="Board dataset: the poses to judge, e.g. 50-69 "
                                        "(default: all; they should be poses the calibration never saw)."),
    force: bool = typer.Option(False, "--force", help="Overwrite the output folder's files."),
) -> None:
    """Before/after metrics per station of a wall dataset (plus optional cross-validation), or per
    pose of a board dataset (board.json: white squares against the board planes)."""
    from tofmetry.pipelines import load_calibration
    from tofmetry.pipelines import validate_depth, write_validation_report

    refuse_existing([output], force)
    cal = load_calibration(calibration)
    if (wall_dir / "board.json").is_file():
        _validate_board(wall_dir, cal, poses, load_intrinsics_option(intrinsics), output)
        return
    with progress(f"validating on {wall_dir.name}", None) as adv:
        run = validate_depth(wall_dir, cal, intrinsics=load_intrinsics_option(intrinsics), tilted=tilted,
                             reference_offset_mm=reference_offset_mm, cross_validate=cv, advance=adv)
    _notes(run.notes)
    console.print(_report_table(run.stations, f"validation on {wall_dir} (before -> after, mm)"))
    console.print(run.summary)
    print_prediction_check(run.prediction_check)
    for label, r in (run.cross_validation or {}).items():
        console.print(_report_table(r["stations"], f"leave-one-station-out, method {label}"))
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
    accept_implausible: bool = typer.Option(False, "--accept-implausible", help=ACCEPT_IMPLAUSIBLE_HELP),
) -> None:
    """Apply a depth calibration to every frame of a capture (same format out)."""
    from tofmetry.io import Capture
    from tofmetry.pipelines.correct import correct_capture

    cap = Capture(capture)
    with progress("correcting frames", len(cap)) as adv:
        run = correct_capture(cap, calibration, output, float32=float32, force=force, advance=adv,
                              accept_implausible=accept_implausible)
    print_plausibility(run.plausibility)
    if run.outside_range:
        console.print(f"[yellow]warning:[/] {run.outside_range} valid depth samples ({100 * run.outside_share:.2f} % of "
                      f"all pixels) lie outside the calibration's support; {_outside_how(run.calibration)}")
    console.print(f"wrote {run.n_frames} corrected frames to {output}")


def register(app: typer.Typer) -> None:
    """Add ``calibrate`` (group) and ``correct``."""
    calibrate_app.command("intrinsics")(intrinsics_cmd)
    calibrate_app.command("depth")(depth)
    calibrate_app.command("validate")(validate)
    calibrate_app.command("stereo")(stereo_cmd)
    calibrate_app.command("rig")(rig_cmd)
    app.add_typer(calibrate_app, name="calibrate")
    app.command("correct")(correct)
