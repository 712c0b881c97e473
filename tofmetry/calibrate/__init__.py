"""Calibration: IR intrinsics (checkerboard) and ToF depth calibration (range curve + per-pixel surfaces).

* :mod:`._model` — :class:`DepthCalibration` (the model, see its module docstring)
* :mod:`._apply` — fused numba correction kernels + numpy reference
* :mod:`._backproject` — streaming correction + undistorted back-projection (:class:`FrameCorrector`)
* :mod:`._fit` — generic fit from :class:`DepthSample` (wall, board...)
* :mod:`._surface` — smooth surfaces over the image (polynomial / tensor spline)
* :mod:`._wall` — wall mode: station statistics, plane fit, wall samples
* :mod:`._validate` — before/after evaluation, leave-one-station-out cross-validation
* :mod:`._intrinsics` — checkerboard intrinsics (the one implementation): detector, outlier-view
  rejection, stability analysis, k-fold pose-wise cross-validation
* :mod:`.board` — board-based depth calibration (board planes as the reference)
* pipelines (folders in, results out) live in :mod:`tofmetry.pipelines`
* :mod:`.figures` — study-style figures (Figs. 7a/7b/8/9, validation, corner coverage)
* file format: :mod:`tofmetry.io.calibration_file` (``.npz`` + JSON header, no pickle)

Constraint where there is no data: the range curve is clamped (constant) outside the
measured distances of the samples and no correction at all is applied beyond
``valid_range_mm`` (data range +- ``range_margin_mm``); surfaces are clamped to the first/last
node in range; across the image, spline surfaces continue linearly (second-difference
penalty) and polynomial surfaces extrapolate as polynomials where a sample has no pixels.
"""

from tofmetry.calibrate._apply import apply_depth_calibration, apply_depth_calibration_reference, count_outside_range
from tofmetry.calibrate._backproject import FrameCorrector, correct_and_backproject
from tofmetry.calibrate._fit import DepthCalibrationResult, DepthFitConfig, DepthSample, fit_depth_model, fit_range_curve
from tofmetry.calibrate._intrinsics import (
    PARAMS, IntrinsicsResult, board_object_points, calibrate_intrinsics, corner_coverage, coverage_mask,
    cross_validate_intrinsics, detect_corners, normalize_ir, ray_difference_px, reprojection_rms_with,
    solve_board_pose,
)
from tofmetry.calibrate._model import FORMAT_VERSION, DepthCalibration
from tofmetry.calibrate._surface import SurfaceSpec, fit_surface
from tofmetry.calibrate._wall import (
    PlaneFit, StationStats, central_patch, fit_plane, station_statistics, wall_reference, wall_sample,
)
from tofmetry.calibrate._validate import (
    StationReport, central_fraction_mask, cross_validate, evaluate_wall_station, summarize, with_surface,
)
from tofmetry.io.calibration_file import load_calibration, read_calibration_header, save_calibration

__all__ = [
    "FrameCorrector", "apply_depth_calibration", "apply_depth_calibration_reference", "correct_and_backproject",
    "count_outside_range",
    "DepthCalibrationResult", "DepthFitConfig", "DepthSample", "fit_depth_model", "fit_range_curve",
    "FORMAT_VERSION", "DepthCalibration", "SurfaceSpec", "fit_surface",
    "PlaneFit", "StationStats", "central_patch", "fit_plane", "station_statistics", "wall_reference", "wall_sample",
    "PARAMS", "IntrinsicsResult", "board_object_points", "calibrate_intrinsics", "corner_coverage", "coverage_mask",
    "detect_corners", "normalize_ir", "ray_difference_px", "cross_validate_intrinsics", "reprojection_rms_with",
    "solve_board_pose",
    "StationReport", "central_fraction_mask", "cross_validate", "evaluate_wall_station", "summarize", "with_surface",
    "load_calibration", "read_calibration_header", "save_calibration",
]
