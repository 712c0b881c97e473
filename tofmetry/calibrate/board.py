"""Board-based depth calibration: a printed chessboard or ChArUco board as the depth reference.

Method
------
1. **Grids.** Per view, the chessboard corners (given, or found in the IR image; every board
   of a view: :func:`find_boards` detects again with the found boards masked out). A ChArUco
   board (``board`` a :class:`~tofmetry.calibrate.CharucoBoard`) may be seen in part: its grid
   holds the corners detected (NaN for the others), its pose comes from them, and its samples
   come from the squares touching them (:mod:`._board_charuco`: black squares and the white
   margins around the markers, a pixel margin from every edge). Each grid's
   pose is solved with the IR/depth intrinsics (``cv2.solvePnP``) and the grid is **rejected
   when its reprojection RMS exceeds a threshold derived from the measured corner noise**
   (:func:`corner_noise_px`, :func:`grid_threshold_px`): a grid spanning two boards or a
   reflection cannot be one plane.
2. **Reference.** Depth and IR share one lens and one pixel grid, so the board plane yields a
   reference Z for every board pixel: ``Z_ref = d / (n . r)``, ``r = (x, y, 1)`` the undistorted
   ray, ``n . X = d`` the plane (:func:`board_samples`). Square boundaries and the board's edge
   are kept out (mixed pixels), so are saturated IR pixels.
3. **The pattern.** ToF depth is biased by the returned amplitude: dark squares read longer,
   by an amount that depends on their amplitude (measured on the Kinect v2 recording: -3 mm at
   high amplitude up to +60 mm at low). The correction is for bright (white) surfaces; views
   whose white squares are saturated (near the camera) enter through their dark squares, with
   the dark-square bias **measured** on the views where both parities are valid, as a function
   of the dark pixels' amplitude (:class:`DarkBias`), clamped to the amplitudes where it was
   measured. Whether those views help is decided by the blocked validation. Held-out errors are
   always judged on white squares.
4. **Model family** (:mod:`tofmetry.calibrate._board_model`): ``a(x) + s(u, v) + zeta(x) g(u, v)``
   with ``x`` the radial path length (continuous-wave ToF) or Z; a ladder of candidates from a
   constant to a range spline with per-pixel surfaces (:func:`candidate_ladder`), gated by the
   support (few views: constant and constant + gain only).
5. **Blocked validation** (:func:`blocked_folds`): contiguous blocks of views in recording
   order, bins of range, regions of the image (a region left out of the fit and predicted).
   The model is **selected on the blocked folds** (simplest candidate within one standard
   error of the best, paired over folds); random k-fold over views is reported beside,
   labelled as such.
6. **Prediction** (:func:`predict_error`): RMS, P95 of |error| and mean error on new views with
   90 % intervals, from the held-out errors of the chosen model on the blocks in recording
   order (bootstrap over views). **Support** (:func:`support_counts`): samples per 16x16 px
   image cell and 100 mm range bin.

All functions are pure (arrays in, results out); file access is in :mod:`tofmetry.io`.

Code layout: :mod:`._board_samples` (samples, board finding, grid test), :mod:`._board_support`
(error statistics, support, dark-square bias), :mod:`._board_folds` (validation designs,
candidates, predicted error), :mod:`._board_result` (the result), :mod:`._board_calibrate` (the
calibration's body); this module holds the entry points and re-exports the names.
"""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from tofmetry.calibrate._board_calibrate import _calibrate, calibrate_intrinsics_on_grids
from tofmetry.calibrate._board_folds import blocked_folds, candidate_ladder, predict_error, region_folds
from tofmetry.calibrate._board_model import BoardDepthModel, ModelSpec, fit_board_model, to_depth_calibration
from tofmetry.calibrate._board_model import RANGE_VARIABLES  # noqa: F401  (re-exported: board.X as before the split)
from tofmetry.calibrate._board_pose import (
    board_inner, board_object_points, check_corners, is_charuco, reprojection_rms_with, seen_corners, solve_board_pose,
)
from tofmetry.calibrate._board_result import BoardCalibrationResult
from tofmetry.calibrate._board_samples import (
    BoardSamples, GridScreen, board_samples, collect_grids, corner_noise_px, find_boards, grid_threshold_px,
    screen_grids,
)
from tofmetry.calibrate._board_samples import (  # noqa: F401  (re-exported: board.X as before the split)
    GRID_ALLOWANCE, IR_SATURATION, MIN_CORNER_NOISE_PX,
)
from tofmetry.calibrate._board_support import (
    DarkBias, constant_shift_calibration, core_correction, error_stats, fit_dark_bias, outside_support,
    support_counts,
)
from tofmetry.calibrate._corners import detect_corners, normalize_ir
from tofmetry.calibrate._lens_cv import cross_validate_intrinsics
from tofmetry.calibrate._lens_fit import calibrate_intrinsics
from tofmetry.errors import EstimationError
from tofmetry.sensor.intrinsics import CameraIntrinsics

# intrinsics helpers live in tofmetry.calibrate and are re-exported here for convenience.
__all__ = [
    "BoardCalibrationResult", "BoardDepthModel", "BoardSamples", "DarkBias", "GridScreen", "ModelSpec",
    "blocked_folds", "board_inner", "board_object_points", "board_samples", "calibrate_intrinsics_on_grids",
    "is_charuco", "seen_corners", "calibrate_depth_from_board", "calibrate_intrinsics",
    "candidate_ladder", "check_corners", "collect_grids", "constant_shift_calibration", "core_correction",
    "corner_noise_px", "cross_validate_intrinsics", "detect_corners", "error_stats", "evaluate_views", "find_boards",
    "fit_board_model", "fit_dark_bias", "grid_threshold_px", "normalize_ir", "outside_support", "predict_error",
    "region_folds", "reprojection_rms_with", "screen_grids", "solve_board_pose", "support_counts",
    "to_depth_calibration",
]


def calibrate_depth_from_board(poses: list, board, square_mm: float,
                               intrinsics: CameraIntrinsics | None = None, *, names: list[str] | None = None,
                               seed: int = 0, sensor: str = "kinect_v2", min_samples: int = 200,
                               candidates: list[ModelSpec] | None = None, use_dark_views: bool | str = "auto",
                               max_boards: int = 4, max_samples_per_view: int = 600, k_folds: int = 5,
                               sample_kwargs: dict | None = None, advance=None) -> BoardCalibrationResult:
    """Board-based depth calibration with blocked validation and model selection.

    Parameters
    ----------
    poses : list of ``(depth (H,W) uint16 mm, ir (H,W), corners)`` in recording order; corners:
        (cols*rows, 2) [px], a list of such grids (several boards), or None (every board found
        in the IR image). ChArUco: one grid by corner id, NaN where a corner was not seen.
    board : (cols, rows) inner corners of a checkerboard, or a ChArUco board (partial views);
        square_mm : square size [mm].
    intrinsics : IR/depth intrinsics, **used as given**. None: fitted on the corners of these
        views (said in ``intrinsics_source``); needs at least 3 grids.
    names : view names (default ``view000`` ...).
    candidates : model ladder (default :func:`candidate_ladder`, gated by the support).
    use_dark_views : True / False / "auto" for views whose white squares are saturated: auto uses
        them unless, on the blocked folds, they make the held-out error worse by more than one
        standard error (paired over folds).
    min_samples : views with fewer usable pixels are skipped.
    max_samples_per_view : pixels per view used in the fits (random, fixed seed): views weigh
        about equally (a near board's thousands of pixels share one pose error), and the
        validation fits and the final fit follow the same procedure.
    k_folds : folds of the random and time-blocked designs.
    advance : optional progress callable.

    Returns
    -------
    BoardCalibrationResult

    Raises
    ------
    EstimationError : no usable view, or no intrinsics given and fewer than 3 grids to fit them.
    """
    # hundreds of small dense solves: one BLAS thread (threads thrash on a busy machine, 10-100x)
    with threadpool_limits(1, user_api="blas"):
        return _calibrate(poses, board, square_mm, intrinsics, names, seed, sensor, min_samples, candidates,
                          use_dark_views, max_boards, max_samples_per_view, k_folds, sample_kwargs, advance)

# ----------------------------------------------------------------------------- judging
def evaluate_views(poses: list, board, square_mm: float, intr: CameraIntrinsics,
                   corrections: dict, *, names: list[str] | None = None, sigma_px: float | None = None,
                   support: dict | None = None, model: BoardDepthModel | None = None,
                   valid_range_mm: tuple[float, float] | None = None, sample_kwargs: dict | None = None) -> dict:
    """Error of corrected depth against the board plane on views no fit has seen (white squares).

    Parameters
    ----------
    poses : list of ``(depth, ir, corners)`` (corners as in :func:`calibrate_depth_from_board`).
    intr : intrinsics giving the board planes (each case is judged against the planes of the
        intrinsics it comes with).
    corrections : {case name: callable ``(u, v, z_mm) -> correction [mm]`` or None (= none)}.
    sigma_px : corner noise for the grid test (default: measured on these views).
    support : :func:`support_counts` of a fit: judged samples outside it are counted
        (``outside["cell_and_range_bin"]``: no training sample in the same 16 px cell and 100 mm
        bin; ``outside["image_cell"]``: none in the same cell at any range).
    model : the fitted model: samples whose range variable lies outside its training range
        (where ``a`` is clamped) are counted in ``outside["range"]``.
    valid_range_mm : a DepthCalibration's valid range: samples outside it are left uncorrected
        by the calibration, counted in ``outside["uncorrected"]``.

    Returns
    -------
    dict: ``cases`` {name: error stats}, ``per_view`` list of dict (name, n, mean and RMS per
    case), ``outside`` {kind: count}, ``n_samples``, ``n_views``, ``skipped`` [(name, reason)],
    ``errors`` {name: (N,)} and ``view_ids`` (N,) (for predictions / figures).
    """
    sample_kwargs = sample_kwargs or {}
    names = list(names) if names is not None else [f"view{i:03d}" for i in range(len(poses))]
    grids, _ = collect_grids(poses, board)
    allg = [c for g in grids for c in g]
    scr = screen_grids(allg, board, square_mm, intr, sigma_px=sigma_px) if allg else None
    errs = {c: [] for c in corrections}
    ids, per_view, skipped = [], [], []
    outside = {"cell_and_range_bin": 0, "image_cell": 0, "range": 0, "uncorrected": 0}
    pos = 0
    for i, g in enumerate(grids):
        parts = []
        for c in g:
            ok = bool(scr.accepted[pos])
            pos += 1
            if not ok:
                continue
            try:
                parts.append(board_samples(poses[i][0], poses[i][1], c, board, square_mm, intr, **sample_kwargs))
            except EstimationError:
                pass
        s = BoardSamples.concat(parts).select("white") if parts else None
        if s is None or len(s.u) < 20:
            skipped.append((names[i], "no accepted board grid" if not parts else "white squares saturated"))
            continue
        row = {"name": names[i], "n": len(s.u), "z_median_mm": float(np.median(s.measured_mm))}
        e0 = s.measured_mm - s.reference_mm
        for cname, f in corrections.items():
            e = e0 if f is None else e0 + f(s.u, s.v, s.measured_mm)
            errs[cname].append(e)
            row[f"mean_{cname}_mm"] = float(np.mean(e))
            row[f"rms_{cname}_mm"] = float(np.sqrt(np.mean(e ** 2)))
        if support is not None:
            n_out = int(outside_support(support, s.u, s.v, s.measured_mm).sum())
            cells = support["counts"].sum(axis=2)
            iu = np.clip(np.searchsorted(support["u_edges"], s.u, side="right") - 1, 0, cells.shape[1] - 1)
            iv = np.clip(np.searchsorted(support["v_edges"], s.v, side="right") - 1, 0, cells.shape[0] - 1)
            row["n_outside_support"] = n_out
            outside["cell_and_range_bin"] += n_out
            outside["image_cell"] += int(np.sum(cells[iv, iu] == 0))
        if model is not None:
            x = model.range_value(s.u, s.v, s.measured_mm)
            lo, hi = model.x_support_mm
            outside["range"] += int(np.sum((x < lo) | (x > hi)))
        if valid_range_mm is not None:
            outside["uncorrected"] += int(np.sum((s.measured_mm < valid_range_mm[0]) | (s.measured_mm > valid_range_mm[1])))
        ids.append(np.full(len(s.u), i))
        per_view.append(row)
    cat = {c: np.concatenate(v) if v else np.zeros(0) for c, v in errs.items()}
    return {"cases": {c: error_stats(v) for c, v in cat.items()}, "per_view": per_view, "outside": outside,
            "n_samples": int(sum(r["n"] for r in per_view)), "n_views": len(per_view),
            "skipped": skipped, "errors": cat, "view_ids": np.concatenate(ids) if ids else np.zeros(0, int)}
