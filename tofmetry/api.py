"""The public Python API of tofmetry, re-exported by the package: ``tofmetry.correct(...)``.

Thin, typed wrappers: folder-level functions call :mod:`tofmetry.pipelines` (folders in, result
objects out); the array-level :func:`correct` and :func:`to_points` call the frame path
(:class:`~tofmetry.pipelines.frame_path.FramePath`, the fused numba kernels). ``import tofmetry``
does not import this module; the first use of one of its names does.

Conventions: depth is Z along the optical axis in millimetres (uint16, 0 = no measurement);
points are in metres in the camera frame (x right, y down, z forward).
"""

from __future__ import annotations

import os
from typing import Callable

import numpy as np

from tofmetry.calibrate import DepthCalibration
from tofmetry.errors import InputError
from tofmetry.evaluate import EvaluationConfig, EvaluationResult
from tofmetry.io import Capture, read_capture
from tofmetry.pipelines import (
    DepthRun, IntrinsicsRun, calibrate_depth_dataset, intrinsics_from_images, load_calibration, save_calibration,
    write_depth_report, write_intrinsics_report,
)
from tofmetry.pipelines.evaluate import evaluate_files
from tofmetry.pipelines.frame_path import frame_path
from tofmetry.pipelines.reconstruct import reconstruct_scan
from tofmetry.reconstruct import ReconstructionConfig, ReconstructionResult
from tofmetry.sensor import CameraIntrinsics

__all__ = ["calibrate_depth", "calibrate_intrinsics", "correct", "evaluate", "load_capture", "reconstruct", "to_points"]

PathLike = str | os.PathLike


def _calibration(calibration: DepthCalibration | PathLike) -> DepthCalibration:
    return calibration if isinstance(calibration, DepthCalibration) else load_calibration(calibration)


def load_capture(path: PathLike) -> Capture:
    """Open and validate a capture folder (``capture.json`` + ``depth/``, optional ``ir/``, ``color/``).

    Parameters
    ----------
    path : the capture folder

    Returns
    -------
    Capture
        Lazy and indexable: ``len(cap)``, ``cap.depth(i)`` -> (H, W) uint16 [mm], ``cap.ir(i)``,
        ``cap.intrinsics()``.

    Raises
    ------
    FormatError
        Naming the file: no frames, wrong bit depth or resolution, frames of mixed size.
    """
    return read_capture(path)


def calibrate_intrinsics(images: PathLike, board: tuple[int, int], square_mm: float, *,
                         output: PathLike | None = None, leave_one_out: bool = True, fix_k3: bool = False,
                         advance: Callable[[], None] | None = None) -> IntrinsicsRun:
    """Lens calibration (pinhole + Brown) of the IR camera from checkerboard images.

    Parameters
    ----------
    images : folder of checkerboard images (8- or 16-bit)
    board : (cols, rows) inner corners of the board
    square_mm : square size [mm]
    output : optional folder for the report (``intrinsics.json`` of the result, figures)
    leave_one_out : also analyse the stability of each parameter (one refit per image)
    fix_k3 : keep k3 = 0
    advance : optional progress callable

    Returns
    -------
    IntrinsicsRun
        ``run.result.intrinsics`` (CameraIntrinsics), uncertainties, rejected views, cross-validation.
    """
    run = intrinsics_from_images(images, board, square_mm, leave_one_out=leave_one_out, fix_k3=fix_k3, advance=advance)
    if output is not None:
        write_intrinsics_report(run, output)
    return run


def calibrate_depth(dataset: PathLike, *, output: PathLike | None = None, intrinsics: CameraIntrinsics | None = None,
                    reference_offset_mm: float = 0.0, report: PathLike | None = None,
                    advance: Callable[[], None] | None = None, **options) -> DepthRun:
    """Depth calibration on a wall dataset (``stations.csv``) or a board dataset (``board.json``).

    Parameters
    ----------
    dataset : the dataset folder; its kind is detected from its content
    output : optional calibration file to write (``.npz``)
    intrinsics : IR intrinsics (default: the captures' for a wall, fitted on the corners for a board)
    reference_offset_mm : wall: known distance [mm] from the stations' reference point forward to
        the optical centre
    report : optional folder for the fit report (JSON + figures)
    advance : optional progress callable
    **options : further options of :func:`tofmetry.pipelines.calibrate_depth_dataset`

    Returns
    -------
    DepthRun
        ``run.calibration`` (DepthCalibration) and the fit's diagnostics.
    """
    run = calibrate_depth_dataset(dataset, intrinsics=intrinsics, reference_offset_mm=reference_offset_mm,
                                  advance=advance, **options)
    if output is not None:
        save_calibration(output, run.calibration)
    if report is not None:
        write_depth_report(run, report)
    return run


def correct(depth: np.ndarray, calibration: DepthCalibration | PathLike) -> np.ndarray:
    """Corrected depth of one frame.

    Parameters
    ----------
    depth : (H, W) uint16 [mm] (0 = invalid), or float [mm] (0/NaN = invalid, e.g. a temporal mean)
    calibration : DepthCalibration or a calibration file

    Returns
    -------
    (H, W) float32 [mm] for uint16 input, float64 [mm] for float input; invalid pixels stay
    invalid, depths outside the calibrated range are unchanged.
    """
    cal = _calibration(calibration)
    return frame_path(cal.intrinsics, cal).correct(depth)


def to_points(depth: np.ndarray, calibration: DepthCalibration | PathLike | None = None, *,
              intrinsics: CameraIntrinsics | None = None, undistort: bool = True,
              out: np.ndarray | None = None) -> np.ndarray:
    """Points of one depth frame: corrected (with a calibration), undistorted, back-projected.

    A uint16 frame takes the fused kernel (about 0.2-0.4 ms for 512x424); the kernels are prepared
    once per calibration object and intrinsics and reused by later calls, so in a loop pass a
    loaded :class:`~tofmetry.calibrate.DepthCalibration` (a file name is read again at every call).

    Parameters
    ----------
    depth : (H, W) uint16 [mm] (0 = invalid), or float [mm] (0/NaN = invalid, e.g. a temporal mean)
    calibration : DepthCalibration, a calibration file, or None (raw depth)
    intrinsics : intrinsics of the depth camera; default the calibration's (required without one)
    undistort : undistorted rays (default) or the plain pinhole
    out : optional (>= H*W, 3) float32 C-contiguous buffer reused across uint16 frames; the result
        is then a view of its first N rows

    Returns
    -------
    (N, 3) float32 [m] (uint16 input) or float64 [m] (float input), camera frame, one point per
    valid pixel in row-major order.
    """
    cal = None if calibration is None else _calibration(calibration)
    intr = intrinsics if intrinsics is not None else (None if cal is None else cal.intrinsics)
    if intr is None:
        raise InputError("to_points: pass the intrinsics (or a calibration, whose intrinsics are used)")
    path = frame_path(intr, cal, bool(undistort))
    depth = np.asarray(depth)
    if depth.dtype == np.uint16:
        return path.points(depth, out=out)
    return path.backproject(path.correct(depth))[0]


def reconstruct(scan: PathLike, calibration: DepthCalibration | PathLike | None = None,
                output: PathLike | None = None, *, config: ReconstructionConfig | None = None,
                amplitude_wall: PathLike | None = None, force: bool = False) -> ReconstructionResult:
    """3D model of an object from a scan dataset (``views/<name>/`` captures): segmentation,
    registration (pose graph + global adjustment), TSDF fusion, mesh.

    Parameters
    ----------
    scan : scan dataset folder
    calibration : DepthCalibration, a calibration file, or None (raw depth)
    output : optional model folder (``points.ply``, ``mesh.ply``, ``poses.json``), written atomically
    config : ReconstructionConfig (default settings when None)
    amplitude_wall : optional wall dataset with IR: enables the amplitude-bias correction
    force : replace an existing output folder

    Returns
    -------
    ReconstructionResult
        Poses (camera-to-world, metres), mesh, cloud; ``diagnostics["reliable"]`` is False when
        the registration cannot be trusted.
    """
    return reconstruct_scan(scan, calibration, output, config=config, amplitude_wall=amplitude_wall, force=force)


def evaluate(model: PathLike, reference: PathLike, output: PathLike | None = None, *,
             config: EvaluationConfig | None = None, poses: PathLike | None = None,
             init_transform: PathLike | None = None, force: bool = False) -> EvaluationResult:
    """Accuracy of a model (PLY/OBJ/STL, metres) against a reference: alignment, signed deviations,
    statistics, completeness.

    Parameters
    ----------
    model, reference : geometry files [m] (cloud or mesh)
    output : optional folder for ``metrics.json``, figures and ``deviation.ply``
    config : EvaluationConfig (default settings when None; ``align=True`` for a coarse alignment)
    poses : optional ``poses.json`` of the reconstruction (completeness of the observed surface)
    init_transform : optional JSON 4x4 model -> reference transform
    force : replace an existing, non-empty ``output`` folder (refused otherwise)

    Returns
    -------
    EvaluationResult
        ``stats_all`` / ``stats_trimmed`` (mean |d|, std, RMS, max [mm]), completeness, alignment.
    """
    return evaluate_files(model, reference, output, config=config, poses=poses, init_transform=init_transform,
                          force=force).result
