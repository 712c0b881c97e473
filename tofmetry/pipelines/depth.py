"""Depth-calibration pipeline entry: the dataset kind (wall or board) is detected from its content."""

from __future__ import annotations

from pathlib import Path

from tofmetry.errors import InputError
from tofmetry.pipelines.board import calibrate_board
from tofmetry.pipelines.depth_run import DepthRun
from tofmetry.pipelines.wall import calibrate_wall
from tofmetry.sensor import CameraIntrinsics


def calibrate_depth_dataset(path: Path, *, intrinsics: CameraIntrinsics | None = None, config=None,
                            tilted: bool = True, reference_offset_mm: float = 0.0, advance=None,
                            squares: str = "white", k_folds: int = 5, provenance: dict | None = None,
                            accept_implausible: bool = False) -> DepthRun:
    """Fit a depth calibration on a wall dataset (``stations.csv``) or a board dataset (``board.json``).

    Parameters
    ----------
    path : dataset folder; the kind is detected from its content
    intrinsics : IR/depth intrinsics; None -> the captures' (wall) / fitted from the board corners (board)
    config : DepthFitConfig of the wall fit (default ``DepthFitConfig()``); unused in board mode
    tilted : wall mode: fit the wall's orientation per station (else perpendicular to the axis)
    reference_offset_mm : wall mode: distance from the stations' reference point forward to the optical centre
    squares, k_folds : board mode: squares used ("white" / "all") and folds of the pose-wise cross-validation
    provenance : extra provenance entries stored in the calibration (e.g. the command line)
    accept_implausible : return a calibration that fails a plausibility gate
        (:mod:`tofmetry.pipelines.plausibility`) instead of raising
        :class:`~tofmetry.errors.ImplausibleResultError`; the run and the calibration record it
    """
    path = Path(path)
    if (path / "board.json").is_file():
        return calibrate_board(path, intrinsics, squares, k_folds, advance, provenance,
                               accept_implausible=accept_implausible)
    if not (path / "stations.csv").is_file():
        raise InputError(f"{path}: neither a wall dataset (stations.csv) nor a board dataset (board.json)")
    return calibrate_wall(path, intrinsics=intrinsics, config=config, tilted=tilted,
                          reference_offset_mm=reference_offset_mm, advance=advance, provenance=provenance,
                          accept_implausible=accept_implausible)
