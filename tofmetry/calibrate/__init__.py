"""Calibration: IR intrinsics (checkerboard) and ToF depth calibration (range curve + per-pixel surfaces).

* :mod:`._model` — :class:`DepthCalibration` (the model, see its module docstring)
* :mod:`._apply` — fused numba correction kernels + numpy reference
* :mod:`._backproject` — streaming correction + undistorted back-projection (:class:`FrameCorrector`)
* :mod:`._fit` — tofmetry's depth calibration from :class:`DepthSample` (wall, board...):
  the joint model of :mod:`._joint` chosen by blocked validation (:mod:`._joint_fit`), its
  predicted error (:mod:`._prediction`) and support (:mod:`._support`)
* :mod:`._fit_study` — the study's method (range spline + one surface per station), a baseline
* :mod:`._surface` — smooth surfaces over the image (polynomial / tensor spline), for the baseline
* :mod:`._wall` — wall mode: station statistics, plane fit, wall samples
* :mod:`._tilt` — the depth error linear in the image position, from board poses, for a wall calibration;
  :mod:`._tilt_check` — its view model and the check on views kept out of the fit
* :mod:`._flat_support` — the range error a flat support shows in a scan's views (what the wall
  stations left between them), :func:`flat_support_curve`
* :mod:`._validate` — before/after evaluation, leave-one-station-out cross-validation
* IR lens calibration (study §4.1): :mod:`._corners` (find the grid, refine and check every
  corner; the X-junction fit in :mod:`._corner_fit`), :mod:`._board_pose` (object points, board
  pose), :mod:`._lens_fit` (Brown model, outlier views, covariance, coverage), :mod:`._lens_cv` (cross-validation),
  :mod:`._ray_error` (judging a lens by ray error, predicted ray error)
* IR–colour extrinsics: :mod:`._stereo` (``cv2.stereoCalibrate``, jackknife uncertainty, held-out pairs);
  rigs of sensors seeing a common board: :mod:`._rig`
* :mod:`.board` — board-based depth calibration (board planes as the reference)
* pipelines (folders in, results out) live in :mod:`tofmetry.pipelines`
* :mod:`.figures` — study-style figures (Figs. 7a/7b/8/9, validation, corner coverage)
* :mod:`._model_arrays` — the model as header + arrays for the file (:mod:`tofmetry.io.calibration_file`);
  ``tofmetry.pipelines.load_calibration`` / ``save_calibration`` read and write it

Where there is no data: every calibration carries its support (the depths fitted at each image
cell). Outside it a conservative fallback applies (the correction held at the nearest supported
depth, or a straight line in depth, whichever predicted the left-out nearest and farthest
stations better) and the pixels concerned are counted; no curve is extrapolated.
"""

# depth model, kernels, file mapping
from tofmetry.calibrate._model import DepthCalibration
from tofmetry.calibrate._support import CalibrationSupport
from tofmetry.calibrate._apply import apply_depth_calibration, apply_depth_calibration_reference, count_outside_range
from tofmetry.calibrate._backproject import FrameCorrector, correct_and_backproject
from tofmetry.calibrate._model_arrays import calibration_from_arrays, calibration_to_arrays
# depth calibration: tofmetry's method, its validation, the study's baseline
from tofmetry.calibrate._sample import DepthSample
from tofmetry.calibrate._joint import JointSpec
from tofmetry.calibrate._fit import DepthCalibrationResult, DepthFitConfig, fit_depth_model
from tofmetry.calibrate._prediction import before_after, check_prediction, sample_metrics
from tofmetry.calibrate._fit_study import StudyFitConfig, StudyFitResult, fit_study_model
from tofmetry.calibrate._range import fit_range_curve
from tofmetry.calibrate._tilt import TiltFit, fit_depth_tilt, with_depth_tilt
from tofmetry.calibrate._tilt_check import held_out_check, tilt_contradicted
from tofmetry.calibrate._flat_support import FlatSupportCurve, flat_support_curve
from tofmetry.calibrate._surface import SurfaceSpec, fit_surface
from tofmetry.calibrate._wall import (
    PlaneFit, StationStats, central_patch, fit_plane, station_statistics, wall_reference, wall_sample,
)
from tofmetry.calibrate._validate import (
    METHODS, StationReport, central_fraction_mask, cross_validate, evaluate_wall_station, fit_any, summarize,
)
# IR lens
from tofmetry.calibrate._board_pose import board_object_points, check_corners, reprojection_rms_with, solve_board_pose
from tofmetry.calibrate._corner_fit import CornerRefinement
from tofmetry.calibrate._corners import (
    CornerDetection, detect_board, detect_corners, find_grid, grid_consistency_px, normalize_ir, refine_corners,
    refine_corners_subpix,
)
from tofmetry.calibrate._charuco import CharucoBoard, CharucoDetection, detect_charuco
from tofmetry.calibrate._coverage import (
    corner_coverage, corner_region_corners, corner_region_coverage, coverage_mask, uncovered_corner_regions,
)
from tofmetry.calibrate._lens_cv import cross_validate_intrinsics
from tofmetry.calibrate._lens_fit import IntrinsicsResult, calibrate_intrinsics, intrinsic_covariance
from tofmetry.calibrate._ray_error import PARAMS, RayError, predicted_ray_error_px, ray_difference_px, ray_error_px
# IR-colour extrinsics
from tofmetry.calibrate._stereo import StereoResult, calibrate_stereo, common_corners, heldout_reprojection
from tofmetry.calibrate._rig import RigResult, calibrate_rig

__all__ = [
    "DepthCalibration", "CalibrationSupport", "FrameCorrector", "apply_depth_calibration",
    "apply_depth_calibration_reference", "correct_and_backproject", "count_outside_range",
    "calibration_from_arrays", "calibration_to_arrays",
    "DepthSample", "JointSpec", "DepthCalibrationResult", "DepthFitConfig", "fit_depth_model",
    "before_after", "check_prediction", "sample_metrics",
    "StudyFitConfig", "StudyFitResult", "fit_study_model", "fit_range_curve", "SurfaceSpec", "fit_surface",
    "TiltFit", "fit_depth_tilt", "held_out_check", "tilt_contradicted", "with_depth_tilt",
    "FlatSupportCurve", "flat_support_curve",
    "PlaneFit", "StationStats", "central_patch", "fit_plane", "station_statistics", "wall_reference", "wall_sample",
    "METHODS", "StationReport", "central_fraction_mask", "cross_validate", "evaluate_wall_station", "fit_any",
    "summarize",
    "board_object_points", "check_corners", "reprojection_rms_with", "solve_board_pose", "CornerRefinement",
    "CornerDetection", "detect_board", "detect_corners", "find_grid", "grid_consistency_px", "normalize_ir",
    "refine_corners", "refine_corners_subpix", "CharucoBoard", "CharucoDetection", "detect_charuco", "IntrinsicsResult", "calibrate_intrinsics", "corner_coverage",
    "corner_region_corners", "corner_region_coverage", "coverage_mask", "uncovered_corner_regions", "cross_validate_intrinsics", "intrinsic_covariance",
    "PARAMS", "RayError", "predicted_ray_error_px", "ray_difference_px", "ray_error_px",
    "StereoResult", "calibrate_stereo", "common_corners", "heldout_reprojection", "RigResult", "calibrate_rig",
]
