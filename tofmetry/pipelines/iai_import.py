"""Pipeline ``import iai-kinect2``: an iai_kinect2 folder -> a board dataset, with the device's
depth shift also written as a tofmetry depth calibration (``depth_shift.npz``).

The reader and the dataset layout are :func:`tofmetry.io.board_dataset.import_iai_kinect2`; this
layer adds the one output that needs a calibration model, which io may not build.
"""

from __future__ import annotations

import os
from pathlib import Path

from tofmetry.calibrate.board import constant_shift_calibration
from tofmetry.io.board_dataset import BoardSpec
from tofmetry.io.board_dataset import import_iai_kinect2 as _import_folder
from tofmetry.pipelines.calibration_files import save_calibration


def _write_shift_calibration(folder: Path, cal, src: Path) -> None:
    if cal.depth_shift_mm is None:
        return
    save_calibration(folder / "depth_shift.npz", constant_shift_calibration(
        cal.depth_shift_mm, cal.ir, "kinect_v2", {"source": str(src / "calib_depth.yaml"), "tool": "iai_kinect2"}))


def import_iai_kinect2(src: str | os.PathLike, out: str | os.PathLike, board: BoardSpec | None = None,
                       force: bool = False, progress=None) -> dict:
    """Convert an iai_kinect2 folder to a board dataset (see :func:`tofmetry.io.board_dataset.import_iai_kinect2`),
    adding ``depth_shift.npz`` when ``calib_depth.yaml`` holds a shift.

    Returns
    -------
    dict summary: poses, files written, calibration found.
    """
    src = Path(src)
    return _import_folder(src, out, board, force=force, progress=progress,
                          extra=lambda folder, cal: _write_shift_calibration(folder, cal, src))


def import_iai_kinect2_cli(src, out, *, force: bool = False, progress=None, board: str | None = None,
                           square_mm: float | None = None, **_ignored) -> dict:
    """Registry entry: ``board`` as ``"COLSxROWS"`` plus ``square_mm``."""
    spec = BoardSpec.parse(board, square_mm) if board else None
    return import_iai_kinect2(src, out, spec, force=force, progress=progress)
