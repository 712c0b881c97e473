"""Board-mode depth calibration pipeline (``board.json`` datasets).

``calibrate_board(path, ...)``: the dataset's poses (or the ``train_poses`` among them) are
calibrated by :func:`tofmetry.calibrate.board.calibrate_depth_from_board` (blocked validation,
model selection, prediction, support); ``judge_poses``, which the fit never sees, are then
corrected with the resulting ``DepthCalibration`` exactly as a user would apply it and
compared with: no correction, the dataset's iai_kinect2 ``depthShift`` (with its own
intrinsics and with the ones used here) and the best constant fitted on the training poses.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np

from tofmetry.calibrate import CharucoBoard, cross_validate_intrinsics
from tofmetry.calibrate.board import (
    board_inner, collect_grids, calibrate_depth_from_board, core_correction, error_stats, evaluate_views, is_charuco,
    seen_corners,
)
from tofmetry.errors import EstimationError, InputError
from tofmetry.io.board_dataset import BoardDataset, BoardSpec
from tofmetry.pipelines._common import _adv, _provenance
from tofmetry.pipelines.depth_run import DepthRun
from tofmetry.pipelines.plausibility import check_correction, check_intrinsics, enforce

SQUARES = ("auto", "white", "dark")


def parse_pose_selection(spec: str | None, names: list[str], what: str = "--train-poses") -> list[int] | None:
    """Indices of the poses named by ``spec`` (None -> None).

    ``spec``: comma-separated items, each a pose name or number (``12``, ``0012``) or an
    inclusive range (``0-49``, ``0000-0049``). Numbers match the pose names' numeric value when
    every name is a number (iai_kinect2's ``0000`` ...), else the poses' positions (0-based).

    Raises
    ------
    InputError : an item names no pose (naming ``what`` and the item).
    """
    if spec is None:
        return None
    numeric = all(n.isdigit() for n in names)
    key = {int(n): i for i, n in enumerate(names)} if numeric else {i: i for i in range(len(names))}
    by_name = {n: i for i, n in enumerate(names)}
    out: list[int] = []
    for item in (x.strip() for x in str(spec).split(",")):
        if not item:
            continue
        if item in by_name:
            out.append(by_name[item])
            continue
        m = re.fullmatch(r"(\d+)\s*-\s*(\d+)|(\d+)", item)
        if not m:
            raise InputError(f"{what}: {item!r} is neither a pose name nor a number or range like 0-49")
        lo, hi = (int(m.group(1)), int(m.group(2))) if m.group(1) else (int(m.group(3)), int(m.group(3)))
        if hi < lo:
            raise InputError(f"{what}: empty range {item!r}")
        found = [key[k] for k in range(lo, hi + 1) if k in key]
        if not found:
            raise InputError(f"{what}: {item!r} matches no pose (poses: {names[0]} .. {names[-1]})")
        out.extend(found)
    if not out:
        raise InputError(f"{what}: no pose selected by {spec!r}")
    return sorted(set(out))


def resolve_board(ds: BoardDataset, board=None) -> tuple:
    """The board of a dataset: ``(board, square_mm, description)`` with ``board`` as
    :mod:`tofmetry.calibrate.board` takes it (``(cols, rows)`` inner corners, or a
    :class:`~tofmetry.calibrate.CharucoBoard`) and a JSON-able ``description`` (``cols``, ``rows``
    inner corners and ``square_mm``; a ChArUco board's own fields and ``"type": "charuco"`` besides).

    Parameters
    ----------
    ds : the dataset (its ``board.json``)
    board : None (the dataset's board), a ``BoardSpec`` (checkerboard) or a ``CharucoBoard``: given,
        it replaces the dataset's
    """
    if board is None:
        board = CharucoBoard.from_dict(ds.charuco) if ds.charuco is not None else ds.board
    if isinstance(board, CharucoBoard):
        cols, rows = board.inner
        return board, float(board.square_mm), {**board.to_dict(), "cols": cols, "rows": rows}
    if isinstance(board, BoardSpec):
        return board.size, float(board.square_mm), {"cols": board.cols, "rows": board.rows, "square_mm": board.square_mm}
    raise InputError(f"board: expected a BoardSpec or a CharucoBoard, found {type(board).__name__}")


def _cv_intrinsics(grids: list, board, square_mm: float, size: tuple[int, int], k: int) -> dict:
    """k-fold held-out reprojection of intrinsics fitted on board grids (ChArUco: seen corners)."""
    if not is_charuco(board):
        return cross_validate_intrinsics(grids, board, square_mm, size, k=k)
    so = [seen_corners(c, board, square_mm) for c in grids]
    return cross_validate_intrinsics([c for _, c in so], board_inner(board), square_mm, size, k=k,
                                     object_points=[o for o, _ in so])


def calibrate_board(path: Path, intrinsics, squares: str = "auto", k_folds: int = 5, advance=None, provenance=None,
                    *, train_poses: str | None = None, judge_poses: str | None = None,
                   accept_implausible: bool = False, board=None) -> DepthRun:
    """Board-based depth calibration of a board dataset.

    Parameters
    ----------
    path : board dataset folder (``board.json`` + ``poses/``): a checkerboard, or a ChArUco board
        (``"type": "charuco"``; views that see part of the board count).
    board : None (``board.json``'s), or a ``BoardSpec`` / ``CharucoBoard`` used instead (:func:`resolve_board`).
    intrinsics : IR/depth intrinsics, used as given; None: fitted on the training poses' corners
        (said in the run's ``intrinsics_source``), or, with too few corner grids, the dataset's
        ``intrinsics.json``.
    squares : "auto" (views with saturated white squares enter through their dark squares unless
        they make the blocked held-out error worse by more than one standard error), "white"
        (never), "dark" (always); "all" is read as "auto".
    k_folds : folds of the time-blocked and random validation designs.
    train_poses, judge_poses : pose selections (:func:`parse_pose_selection`); judged poses are
        never seen by any fit (intrinsics included).
    accept_implausible : keep a result that fails a plausibility gate (intrinsics fitted here: the
        checks of :func:`~tofmetry.pipelines.plausibility.check_intrinsics`; the size of the depth
        correction) instead of raising :class:`~tofmetry.errors.ImplausibleResultError`.
    """
    t0 = time.perf_counter()
    adv = _adv(advance)
    squares = "auto" if squares == "all" else squares
    if squares not in SQUARES:
        raise InputError(f"--squares must be one of {SQUARES}, found {squares!r}")
    ds = BoardDataset(path)
    if len(ds) == 0:
        raise InputError(f"{path}: no poses/ in the board dataset")
    names = list(ds.names)
    judge = parse_pose_selection(judge_poses, names, "--judge-poses") or []
    train = parse_pose_selection(train_poses, names, "--train-poses")
    if train is None:
        train = [i for i in range(len(names)) if i not in set(judge)]
    overlap = sorted(set(train) & set(judge))
    if overlap:
        raise InputError(f"--train-poses and --judge-poses overlap: {', '.join(names[i] for i in overlap[:10])}")
    if not train:
        raise InputError(f"{path}: no training pose left")
    notes: list[str] = []
    poses = ds.load_poses(train)
    adv()
    board, sq, board_desc = resolve_board(ds, board)
    ds_intr = ds.intrinsics()
    intr, src = intrinsics, "given"
    if intr is None:
        n_grids = sum(len(g) for g in collect_grids(poses, board)[0])
        if n_grids < 3:
            if ds_intr is None:
                raise EstimationError(f"{path}: no intrinsics given and only {n_grids} board grid(s) in the training poses "
                                      "to fit them on (need >= 3); pass --intrinsics")
            intr, src = ds_intr, "the dataset's intrinsics.json (too few board grids to fit them)"
            notes.append(f"no intrinsics given and only {n_grids} board grid(s): the dataset's intrinsics.json is used")
    use_dark = {"auto": "auto", "white": False, "dark": True}[squares]
    res = calibrate_depth_from_board(poses, board, sq, intr, names=[names[i] for i in train], sensor=ds.sensor,
                                     use_dark_views=use_dark, k_folds=k_folds, advance=adv)
    if intr is None:
        src = res.intrinsics_source
    intr = res.intrinsics
    notes += res.notes
    for i, why in res.skipped:
        notes.append(f"pose {names[train[i]]} skipped: {why}")
    # intrinsics: held-out reprojection error when they were fitted here (and enough views for it)
    ifit = {"source": src}
    if res.intrinsics_fit is not None:
        ifit.update({"intrinsics": intr.to_dict(), "rms_px": res.intrinsics_fit["rms_px"],
                     "rejected_views": res.intrinsics_fit["rejected_views"]})
        grids = [c for g in res.grids for c in g]     # the grids that passed the reprojection test
        if len(grids) >= 2 * k_folds:
            cv = _cv_intrinsics(grids, board, sq, (intr.width, intr.height), k_folds)
            ifit.update({"cv_rms_px": cv["rms_px"], "cv_max_px": cv["max_px"], "k": cv["k"]})
        else:
            notes.append(f"only {len(grids)} corner grids: no cross-validation of the fitted intrinsics")
    ifit["corner_noise_px"] = res.grid_screen["corner_noise_px"]
    ifit["grid_threshold_px"] = res.grid_screen["threshold_px"]
    shift = ds.depth_shift_mm()
    prov = _provenance({"board_dataset": str(path), "intrinsics_source": src, "squares": squares,
                        "train_poses": [names[train[j]] for j in res.pose_index],
                        **(provenance or {})})
    cal = res.depth_calibration(intr, ds.sensor, prov)
    findings = check_intrinsics(intr, res.intrinsics_fit["rms_px"], ds.sensor if ds.sensor != "unknown" else None) \
        if res.intrinsics_fit is not None else []
    gate = enforce(findings + check_correction(cal), f"the board depth calibration of {path}", accept_implausible)
    cal.provenance["plausibility"] = gate
    adv()
    # iai_kinect2's constant on the training poses (it was fitted by iai on this recording: not held out)
    iai_train = None
    if shift is not None:
        cases = {"none": None, "iai_shift": lambda u, v, z: np.full(len(u), shift)}
        iai_train = {"ours": evaluate_views(poses, board, sq, intr, cases)["cases"]}
        if ds_intr is not None:
            iai_train["iai_intrinsics"] = evaluate_views(poses, board, sq, ds_intr, cases)["cases"]
    else:
        notes.append("no depth_shift.json: the 'iai constant shift' case is not evaluated")
    # judged poses
    judged = None
    if judge:
        jposes = ds.load_poses(judge)
        jn = [names[i] for i in judge]
        sigma = res.grid_screen["corner_noise_px"]
        const = res.constant_mm
        cases = {"none": None,
                 "constant": lambda u, v, z: np.full(len(u), const),
                 "tofmetry": lambda u, v, z: core_correction(cal, u, v, z)}
        if shift is not None:
            cases["iai_shift_our_intrinsics"] = lambda u, v, z: np.full(len(u), shift)
        ev = evaluate_views(jposes, board, sq, intr, cases, names=jn, sigma_px=sigma, support=res.support,
                            model=res.model, valid_range_mm=tuple(cal.valid_range_mm))
        table = dict(ev["cases"])
        if shift is not None and ds_intr is not None:
            ev2 = evaluate_views(jposes, board, sq, ds_intr, {"none": None,
                                 "iai_shift": lambda u, v, z: np.full(len(u), shift)}, names=jn, sigma_px=sigma)
            table["none_iai_intrinsics"] = ev2["cases"]["none"]
            table["iai_kinect2"] = ev2["cases"]["iai_shift"]
        pred = res.predict(ev["n_views"]) if ev["n_views"] else {}
        meas = table["tofmetry"]
        inside = {k: bool(pred[f"{k}_interval"][0] <= meas[k] <= pred[f"{k}_interval"][1])
                  for k in ("rms_mm", "p95_abs_mm", "mean_mm")} if pred and meas["n"] else {}
        judged = {"poses": jn, "n_views": ev["n_views"], "n_samples": ev["n_samples"], "cases": table,
                  "per_view": ev["per_view"], "skipped": ev["skipped"], "outside": ev["outside"],
                  "prediction": pred, "measured_within_prediction": inside,
                  "squares": "white squares of the judged poses, against the board plane of each case's intrinsics"}
        for n, why in ev["skipped"]:
            notes.append(f"judged pose {n} not judged: {why}")
        adv()
    rows = []
    for r in res.views:
        row = {"pose": r["name"], "status": r["status"], "n_white": r.get("n_white", 0), "n_dark": r.get("n_dark", 0),
               "n_used": r.get("n_used", 0), "n_grids": r["n_grids"], "n_corners": r.get("n_corners", 0),
               "pose_rms_px": r["grid_rms_px"],
               "z_median_mm": r.get("z_median_mm", float("nan")),
               "dark_minus_white_mm": r.get("dark_minus_white_mm", float("nan"))}
        for c, v in r.get("held_out_rms_mm", {}).items():
            row[f"held_out_rms_{c}_mm"] = v
        if r.get("reason"):
            row["reason"] = r["reason"]
        rows.append(row)
    fitd = {"board": board_desc,
            "squares": squares, "iai_shift_mm": shift, "intrinsics_fit": ifit, **res.summary(),
            "iai_on_training_poses": iai_train, "judged": judged,
            "train_poses": [names[i] for i in train], "judge_poses": [names[i] for i in judge], "plausibility": gate,
            # the arrays themselves: run.board_result.samples (u, v, z_mm) and .support (counts, edges)
            "support_counts": {"counts_shape": list(res.support["counts"].shape), "cell_px": res.support["cell_px"],
                               "bin_mm": res.support["bin_mm"], "z_edges_mm": res.support["z_edges_mm"].tolist(),
                               "n_samples": int(res.support["counts"].sum()),
                               "cells_covered": int(np.sum(res.support["counts"].sum(axis=2) > 0))}}
    if judged is None and res.prediction:
        notes.append("no poses held out (--judge-poses): the predicted error comes from the blocked validation only")
    return DepthRun("board", cal, intr, src, ds.sensor, rows, fitd, time.perf_counter() - t0, notes, str(path),
                    board_result=res, intrinsics_run=res.intrinsics_fit)


def judged_table(fit: dict) -> list[tuple[str, dict]]:
    """(label, error stats) rows of the judged-pose comparison of a board run's ``fit`` (for printing)."""
    j = fit.get("judged") or {}
    c = j.get("cases", {})
    labels = [("none_iai_intrinsics", "none (iai intrinsics)"), ("none", "none (intrinsics used)"),
              ("iai_kinect2", "iai_kinect2 depthShift (iai intrinsics)"),
              ("iai_shift_our_intrinsics", "iai_kinect2 depthShift (intrinsics used)"),
              ("constant", "best constant (training poses)"), ("tofmetry", "tofmetry")]
    return [(lab, c[k]) for k, lab in labels if k in c]




def validate_board(path: Path, calibration, *, poses: str | None = None, intrinsics=None, board=None) -> dict:
    """Judge a saved depth calibration on the poses of a board dataset (none of which it should
    have seen): white squares, against the board plane of the calibration's intrinsics.

    Parameters
    ----------
    path : board dataset folder.
    calibration : DepthCalibration (e.g. ``load_calibration(cal.npz)``).
    poses : pose selection (:func:`parse_pose_selection`), default all.
    intrinsics : intrinsics of the board planes (default: the calibration's).
    board : None (``board.json``'s board) or one used instead (:func:`resolve_board`).

    Returns
    -------
    dict: ``cases`` {"none", "calibration"} -> error stats [mm], ``per_view``, ``poses``,
    ``skipped``, ``n_views`` and, when the calibration carries a board calibration's prediction,
    ``prediction_of_the_calibration`` (for the stored number of new poses nearest to the number
    judged: 1, 5, 10, 20 or 50) and whether each measured value lies inside its 90 % interval.
    """
    ds = BoardDataset(path)
    names = list(ds.names)
    idx = parse_pose_selection(poses, names, "--poses") or list(range(len(names)))
    intr = intrinsics or calibration.intrinsics
    bd, sq, _ = resolve_board(ds, board)
    ev = evaluate_views(ds.load_poses(idx), bd, sq, intr,
                        {"none": None, "calibration": lambda u, v, z: core_correction(calibration, u, v, z)},
                        names=[names[i] for i in idx], valid_range_mm=tuple(calibration.valid_range_mm))
    out = {"dataset": str(path), "poses": [names[i] for i in idx], "cases": ev["cases"], "per_view": ev["per_view"],
           "skipped": ev["skipped"], "n_views": ev["n_views"], "outside": ev["outside"]}
    diag = calibration.diagnostics or {}
    pred = diag.get("predicted_error")
    by_n = diag.get("predicted_error_for_n_views") or {}
    if by_n and ev["n_views"]:
        pred = by_n[min(by_n, key=lambda n: abs(int(n) - ev["n_views"]))]
    if pred:
        out["prediction_of_the_calibration"] = pred
        m = ev["cases"]["calibration"]
        out["measured_within_prediction"] = {k: bool(pred[f"{k}_interval"][0] <= m[k] <= pred[f"{k}_interval"][1])
                                             for k in ("rms_mm", "p95_abs_mm", "mean_mm") if f"{k}_interval" in pred}
    return out


__all__ = ["calibrate_board", "error_stats", "judged_table", "parse_pose_selection", "validate_board"]
