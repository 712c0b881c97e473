"""Study stages of section 4: IR intrinsics, depth calibration, validation on held-out data.

They call :mod:`tofmetry.pipelines` — the same functions as ``tofmetry calibrate ...``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tofmetry.calibrate import StudyFitConfig, SurfaceSpec
from tofmetry.io import atomic_write_json, read_json, write_intrinsics
from tofmetry.io.board_dataset import BoardSpec
from tofmetry.pipelines import (
    calibrate_depth_dataset, intrinsics_from_images, save_calibration, validate_depth, write_depth_report,
    write_intrinsics_report, write_validation_report,
)
from tofmetry.pipelines.depth_tilt import tilt_from_boards
from tofmetry.study.stage import StageOutcome, StudyContext
from tofmetry.study.stages_real import TILT_BOARDS


def _implausible(record: dict | None) -> list[str]:
    """Report paragraphs for implausible findings that ``--accept-implausible`` let through."""
    if not record or not record.get("accepted"):
        return []
    return [f"IMPLAUSIBLE, accepted with --accept-implausible: {f}" for f in record.get("findings", [])]


def _figs(paths, prefix: str = "") -> list[tuple[str, Path]]:
    return [(prefix + Path(p).stem.replace("_", " "), Path(p)) for p in paths if str(p).endswith(".png")]


def stage_intrinsics(ctx: StudyContext, out: StageOutcome) -> None:
    """Brown model of the IR camera from checkerboard images, with stability analysis (§4.1)."""
    folder = ctx.input("checkerboard", "IR images of a planar checkerboard")
    c = ctx.config.intrinsics
    board, square = BoardSpec.parse(c.board, c.square_mm).size, c.square_mm
    bj = folder / "board.json"
    if bj.is_file():  # the board's own description wins over the config default
        b = read_json(bj, "board.json")
        board, square = (int(b["cols"]), int(b["rows"])), float(b["square_mm"])
    run = intrinsics_from_images(folder, board, square, leave_one_out=True, accept_implausible=ctx.accept_implausible)
    res = run.result
    d = ctx.stage_dir("intrinsics")
    write_intrinsics(d / "intrinsics.json", res.intrinsics, rms_px=res.rms_px, std=res.std)
    out.figures = _figs(write_intrinsics_report(run, d))
    ctx.intrinsics = res.intrinsics
    ctx.intrinsics_source = f"calibrated from {len(res.used)} checkerboard images"
    i = res.intrinsics
    vals = {"fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy, "k1": i.distortion[0], "k2": i.distortion[1],
            "p1": i.distortion[2], "p2": i.distortion[3], "k3": i.distortion[4]}
    spread = [res.loo_range.get(p, float("nan")) for p in ("fx", "fy", "cx", "cy")]
    out.data = {"intrinsics": i.to_dict(), "rms_px": res.rms_px, "std": res.std, "loo_std": res.loo,
                "loo_range": res.loo_range, "loo_max_spread_px": float(np.nanmax(spread)) if res.loo_range else None,
                "n_images_used": len(res.used), "rejected": list(run.rejected) + list(getattr(run, "rejected_views", [])),
                "flagged": res.flagged, "coverage": res.coverage, "warnings": res.warnings,
                "cross_validation": getattr(run, "cv", None), "plausibility": run.plausibility}
    out.tables.append((f"Brown model of the IR camera ({len(res.used)} images, reprojection RMS {res.rms_px:.3f} px)",
                       ["parameter", "value", "std. uncertainty", "leave-one-out std", "leave-one-out range"],
                       [[p, v, res.std.get(p, float("nan")), res.loo.get(p, float("nan")), res.loo_range.get(p, float("nan"))]
                        for p, v in vals.items()]))
    if out.data["rejected"]:
        out.paragraphs.append(f"Images rejected: {', '.join(map(str, out.data['rejected']))}.")
    if res.flagged:
        out.paragraphs.append(f"Images whose removal moves a parameter beyond its uncertainty: {', '.join(res.flagged)}.")
    out.paragraphs += res.warnings
    out.paragraphs += _implausible(run.plausibility)
    cv = out.data["cross_validation"]
    if cv:
        out.paragraphs.append("Pose-wise cross-validation (reprojection error on images left out of the fit): "
                              + ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in cv.items()
                                          if not isinstance(v, (list, dict))) + ".")


def _dev_range(rows: list[dict], key: str, max_mm: float) -> list[float] | None:
    vals = [r[key] for r in rows if key in r and r.get("distance_mm", 0) <= max_mm and np.isfinite(r[key])]
    return [float(min(vals)), float(max(vals))] if vals else None


def _tilt_paragraph(tilt) -> str:
    """The depth tilt fitted on board captures, in words (:func:`tofmetry.pipelines.depth_tilt.tilt_from_boards`)."""
    f = tilt.fit
    head = (f"Depth tilt (an error linear in the image position, which walls of unknown orientation cannot show), "
            f"from {len(f.view_z_mm)} board captures at {f.z_span_mm[0]:.0f}-{f.z_span_mm[1]:.0f} mm: "
            f"({f.tilt_mm[0]:+.2f} +- {f.sigma_mm[0]:.2f}, {f.tilt_mm[1]:+.2f} +- {f.sigma_mm[1]:.2f}) mm per unit of "
            f"x / z, y / z ({f.model}); ")
    return head + ("folded into the calibration: " if tilt.folded else "not folded in: ") + f.held_out["reason"] + "."


def stage_depth(ctx: StudyContext, out: StageOutcome) -> None:
    """Range-error B-spline + per-pixel deformation surfaces from the wall stations (§4.2),
    validated on held-out stations never used for fitting (beyond §4.3)."""
    wall = ctx.input("wall", "a wall dataset: stations.csv + one capture per station")
    d = ctx.stage_dir("depth")
    dc = ctx.config.depth
    run = calibrate_depth_dataset(wall, intrinsics=ctx.intrinsics, reference_offset_mm=dc.reference_offset_mm,
                                  accept_implausible=ctx.accept_implausible)
    tilt = None
    boards = ctx.data_dir / TILT_BOARDS
    if (boards / "board.json").is_file():  # the depth tilt the walls cannot show, from board captures
        tilt = tilt_from_boards(boards, run.calibration)
        run.calibration = tilt.calibration
    cal = run.calibration
    save_calibration(d / "calibration.npz", cal)
    ctx.calibration_path = d / "calibration.npz"
    out.figures = _figs(write_depth_report(run, d / "fit"), "fit: ")
    rows = run.stations
    src = ctx.intrinsics_source if ctx.intrinsics is not None else run.intrinsics_source
    out.data = {"kind": run.kind, "intrinsics_source": src, "offset_mm": cal.offset_mm,
                "valid_range_mm": list(cal.valid_range_mm), "surface_model": cal.surface_model,
                "fit_seconds": run.seconds, "notes": list(run.notes), "stations": rows, "plausibility": run.plausibility}
    out.paragraphs.append(
        f"Fitted on {len(rows)} stations ({run.kind}); intrinsics: {src}. The stations' distances were reduced by "
        f"the mount's known {dc.reference_offset_mm:g} mm (reference point → optical centre); the remaining constant, "
        f"absorbed by the range curve, is {cal.offset_mm:+.1f} mm. "
        f"Corrected range {cal.valid_range_mm[0]:.0f}–{cal.valid_range_mm[1]:.0f} mm; surfaces: {cal.surface_model}.")
    out.paragraphs += list(run.notes)
    out.paragraphs += _implausible(run.plausibility)
    if tilt is not None:
        out.data["tilt"] = tilt.to_dict()
        out.paragraphs.append(_tilt_paragraph(tilt))
    else:
        out.paragraphs.append("The depth tilt (an error linear in the image position, which walls of unknown "
                              "orientation cannot show) was not calibrated: no tilt-boards/ captures (board.json + poses/ with depth).")
    # training stations (in-sample, the study's own validation)
    tr = validate_depth(wall, cal, intrinsics=ctx.intrinsics, cross_validate=dc.cross_validate,
                        cv_methods=tuple(dc.cv_methods), reference_offset_mm=dc.reference_offset_mm)
    out.data["training"] = tr.summary
    before = [r.dev_before_mm for r in tr.stations if r.distance_mm <= dc.max_fit_distance_mm]
    if before:
        out.data["central_dev_before_mm"] = [float(min(before)), float(max(before))]
    write_validation_report(tr, d / "training")
    if tr.cross_validation:
        out.data["cross_validation"] = {k: v.get("summary", v) if isinstance(v, dict) else v
                                        for k, v in tr.cross_validation.items()}
    # held-out stations
    held = ctx.data_dir / "wall-validation"
    if held.exists():
        va = validate_depth(held, cal, intrinsics=ctx.intrinsics, reference_offset_mm=dc.reference_offset_mm)
        figs = write_validation_report(va, d / "validation")
        out.figures += _figs(figs, "held-out: ")
        s = va.summary
        out.data["heldout"] = s
        # the calibration's own predicted error (blocked validation) beside the held-out stations
        chk = va.prediction_check
        out.data["prediction"] = (cal.prediction or {}).get("interpolation", {})
        out.data["prediction_check"] = chk
        out.data["prediction_warnings"] = list((cal.prediction or {}).get("warnings", []))
        if chk and chk.get("verdict") != "no prediction":
            names = {"central_abs_mm": "|central deviation|", "rms_mm": "per-pixel RMS",
                     "rms_systematic_mm": "per-pixel RMS, systematic part", "p95_mm": "p95 |error| (4x4 px means)"}
            out.tables.append(("The calibration's own predicted error (blocked validation on its training stations) "
                               "vs the held-out stations (tilt removed, RMS over stations) [mm]",
                               ["metric", "predicted", "90 % interval", "measured", "measured / predicted", "verdict"],
                               [[label, c["predicted"], f"{c['interval'][0]:.2f}–{c['interval'][1]:.2f}", c["measured"],
                                 c["ratio"], c["verdict"]] for key, label in names.items() if (c := chk.get(key))]))
        sel = [r for r in va.stations if r.distance_mm <= 4000]
        out.data["heldout_central_after_max_mm"] = float(max(abs(r.dev_after_mm) for r in sel)) if sel else None
        out.data["plane_std_before_mm"] = [float(min(r.plane_std_before_mm for r in va.stations)),
                                           float(max(r.plane_std_before_mm for r in va.stations))]
        out.data["plane_std_after_mm"] = [float(min(r.plane_std_after_mm for r in va.stations)),
                                          float(max(r.plane_std_after_mm for r in va.stations))]
        out.tables.append(("Held-out stations (never fitted): before → after correction [mm]",
                           ["station", "distance [m]", "central dev before", "after", "plane std before", "after",
                            "per-pixel RMS (central 90 %) before, raw", "before, offset removed", "after",
                            "noise of the temporal mean", "after, systematic part",
                            "reduction (raw)", "reduction (offset removed)"],
                           [[r.name, r.distance_mm / 1000, r.dev_before_mm, r.dev_after_mm, r.plane_std_before_mm,
                             r.plane_std_after_mm, r.rms_raw_before_mm, r.rms_before_mm, r.rms_after_mm,
                             r.rms_noise_mm, r.rms_after_systematic_mm,
                             r.rms_raw_before_mm / r.rms_after_mm if r.rms_after_mm > 0 else float("nan"),
                             r.rms_before_mm / r.rms_after_mm if r.rms_after_mm > 0 else float("nan")]
                            for r in va.stations]))
        if dc.compare_polynomial and run.kind == "wall":
            poly = calibrate_depth_dataset(wall, intrinsics=ctx.intrinsics, reference_offset_mm=dc.reference_offset_mm,
                                           config=StudyFitConfig(surface=SurfaceSpec(model="poly", degree=3)),
                                           accept_implausible=ctx.accept_implausible)
            vp = validate_depth(held, poly.calibration, intrinsics=ctx.intrinsics, reference_offset_mm=dc.reference_offset_mm)
            out.data["heldout_poly3"] = vp.summary
            rows = []
            for label, v in (("tofmetry (range error along the ray + surfaces)", va),
                             ("the study's method (range spline + cubic polynomial per station)", vp)):
                after = [r.rms_after_mm for r in v.stations]
                rows.append([label, float(np.median(after)), float(max(after)), v.summary["median_rms_reduction"],
                             v.summary["min_rms_reduction"], v.summary["max_abs_dev_after_mm"]])
            out.tables.append(("tofmetry vs the study's method on the held-out stations",
                               ["method", "median RMS after [mm]", "max RMS after [mm]", "median reduction",
                                "min reduction", "max |central dev| after [mm]"], rows))
    else:
        out.paragraphs.append("No wall-validation/ folder: only leave-one-station-out cross-validation is reported.")
    if tr.cross_validation:
        rows_cv = []
        for label, v in tr.cross_validation.items():
            s = v.get("summary", {}) if isinstance(v, dict) else {}
            rows_cv.append([label, s.get("max_abs_dev_after_mm", float("nan")), s.get("median_rms_reduction", float("nan")),
                            s.get("min_rms_reduction", float("nan"))])
        out.tables.append(("Leave-one-station-out cross-validation (surface model comparison)",
                           ["surfaces", "max |central dev| after [mm]", "median RMS reduction", "min RMS reduction"], rows_cv))
    atomic_write_json(d / "result.json", out.data)
