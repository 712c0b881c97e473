"""Board-mode depth calibration pipeline (``board.json`` datasets)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tofmetry.calibrate import calibrate_intrinsics, cross_validate_intrinsics, detect_corners, reprojection_rms_with
from tofmetry.calibrate.board import calibrate_depth_from_board
from tofmetry.errors import EstimationError, InputError
from tofmetry.io.board_dataset import BoardDataset
from tofmetry.pipelines._common import _adv, _provenance
from tofmetry.pipelines.depth_run import DepthRun


def calibrate_board(path: Path, intrinsics, squares: str, k_folds: int, advance, provenance) -> DepthRun:
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

