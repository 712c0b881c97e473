"""The pipeline layer: dataset folders in, result objects out.

The CLI, the study and the public API call these; they read datasets through
:mod:`tofmetry.io`, call the pure estimators of the algorithm packages and never print.
Progress goes through an optional ``advance()`` callable (called once per unit of work).
Every ``*Run`` result has ``to_dict()`` (JSON-able) and a ``write_*_report`` companion.

* :mod:`.intrinsics` — checkerboard intrinsics (:func:`intrinsics_from_images`)
* :mod:`.depth` — depth calibration of a wall or board dataset (:func:`calibrate_depth_dataset`),
  with :mod:`.wall` and :mod:`.board` for the two modes and :mod:`.depth_run` for the result
* :mod:`.validate` — before/after validation on a wall dataset (:func:`validate_depth`)
"""

from tofmetry.pipelines.depth import calibrate_depth_dataset
from tofmetry.pipelines.depth_run import DepthRun, write_depth_report
from tofmetry.pipelines.intrinsics import IntrinsicsRun, intrinsics_from_images, write_intrinsics_report
from tofmetry.pipelines.validate import ValidationRun, validate_depth, write_validation_report

__all__ = [
    "DepthRun", "IntrinsicsRun", "ValidationRun", "calibrate_depth_dataset", "intrinsics_from_images",
    "validate_depth", "write_depth_report", "write_intrinsics_report", "write_validation_report",
]
