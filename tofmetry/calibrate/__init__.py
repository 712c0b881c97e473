"""Calibration: IR intrinsics (checkerboard) and ToF depth calibration (range curve + per-pixel surfaces).

* :mod:`._model` — :class:`DepthCalibration` (the model, see its module docstring)
* :mod:`._apply` — fused numba correction kernels + numpy reference
* :mod:`._fit` — generic fit from :class:`DepthSample` (wall, board...)
* :mod:`._surface` — smooth surfaces over the image (polynomial / tensor spline)
* :mod:`._wall` — wall mode: station statistics, plane fit, wall samples
* :mod:`._validate` — before/after evaluation, leave-one-station-out cross-validation
* :mod:`._intrinsics` — checkerboard intrinsics with stability analysis
"""

from tofmetry.calibrate._apply import (
    apply_depth_calibration, apply_depth_calibration_reference, correct_and_backproject, count_outside_range,
)
from tofmetry.calibrate._fit import DepthCalibrationResult, DepthFitConfig, DepthSample, fit_depth_model, fit_range_curve
from tofmetry.calibrate._model import FORMAT_VERSION, DepthCalibration
from tofmetry.calibrate._surface import SurfaceSpec, fit_surface
from tofmetry.calibrate._wall import (
    PlaneFit, StationStats, central_patch, fit_plane, station_statistics, wall_reference, wall_sample,
)
from tofmetry.io.calibration_file import load_calibration, save_calibration

__all__ = [
    "apply_depth_calibration", "apply_depth_calibration_reference", "correct_and_backproject", "count_outside_range",
    "DepthCalibrationResult", "DepthFitConfig", "DepthSample", "fit_depth_model", "fit_range_curve",
    "FORMAT_VERSION", "DepthCalibration", "SurfaceSpec", "fit_surface",
    "PlaneFit", "StationStats", "central_patch", "fit_plane", "station_statistics", "wall_reference", "wall_sample",
    "load_calibration", "save_calibration",
]
