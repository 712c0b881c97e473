"""The pipeline layer: dataset folders in, result objects out.

The CLI, the study and the public API call these; they read datasets through
:mod:`tofmetry.io`, call the pure estimators of the algorithm packages and never print.
Progress goes through an optional ``advance()`` callable (called once per unit of work).
Every ``*Run`` result has ``to_dict()`` (JSON-able) and a ``write_*_report`` companion.

Calibration:

* :mod:`.intrinsics` — checkerboard intrinsics (:func:`intrinsics_from_images`)
* :mod:`.depth` — depth calibration of a wall or board dataset (:func:`calibrate_depth_dataset`),
  with :mod:`.wall` and :mod:`.board` for the two modes and :mod:`.depth_run` for the result
* :mod:`.calibration_files` — calibration ``.npz`` files (:func:`load_calibration`, :func:`save_calibration`)
* :mod:`.validate` — before/after validation on a wall dataset (:func:`validate_depth`)

Frames (all through the one frame path of :mod:`.frame_path`, streamed by :mod:`.frame_stream`):

* :mod:`.correct` — a capture corrected by a calibration (:func:`~.correct.correct_capture`)
* :mod:`.cloud` — the point cloud of a capture (:func:`~.cloud.capture_cloud`)
* :mod:`.flying` — a capture without its flying pixels (:func:`~.flying.filter_capture`)

Safety: :mod:`.plausibility` (the plausibility gates of every estimator: thresholds from the sensor
profile, :class:`~tofmetry.errors.ImplausibleResultError` unless accepted) and :mod:`.paths` (an output
never goes into an input).

Assessment, model, accuracy: :mod:`.assess` (an assessment's files), :mod:`.reconstruct`
(:func:`~.reconstruct.reconstruct_scan`), :mod:`.amplitude_slope` (the sensor's amplitude-bias
coefficient from grey-level boards, :func:`~.amplitude_slope.amplitude_slope_from_boards`),
:mod:`.evaluate` (:func:`~.evaluate.evaluate_files`).

The names below load their module on first use (PEP 562): ``tofmetry correct`` imports the frame
pipelines only, not the calibration pipelines' figures (matplotlib; 0.5 s of start-up measured).
"""

import importlib as _importlib

_NAMES = {
    "load_calibration": "calibration_files", "save_calibration": "calibration_files",
    "calibrate_depth_dataset": "depth",
    "DepthRun": "depth_run", "write_depth_report": "depth_run",
    "IntrinsicsRun": "intrinsics", "intrinsics_from_images": "intrinsics", "write_intrinsics_report": "intrinsics",
    "ValidationRun": "validate", "validate_depth": "validate", "write_validation_report": "validate",
}

__all__ = [
    "DepthRun", "IntrinsicsRun", "ValidationRun", "calibrate_depth_dataset", "intrinsics_from_images",
    "load_calibration", "save_calibration", "validate_depth", "write_depth_report", "write_intrinsics_report",
    "write_validation_report",
]
assert sorted(__all__) == sorted(_NAMES)

TYPE_CHECKING = False
if TYPE_CHECKING:
    from tofmetry.pipelines.calibration_files import load_calibration, save_calibration
    from tofmetry.pipelines.depth import calibrate_depth_dataset
    from tofmetry.pipelines.depth_run import DepthRun, write_depth_report
    from tofmetry.pipelines.intrinsics import IntrinsicsRun, intrinsics_from_images, write_intrinsics_report
    from tofmetry.pipelines.validate import ValidationRun, validate_depth, write_validation_report


def __getattr__(name: str):
    if name in _NAMES:
        value = getattr(_importlib.import_module(f"tofmetry.pipelines.{_NAMES[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'tofmetry.pipelines' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*__all__, *(k for k in globals() if not k.startswith("_"))})
