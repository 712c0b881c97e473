"""The colour camera's calibration of a capture: ``color_intrinsics.json`` + ``extrinsics.json`` beside
the frames, else the sensor profile's typical values.

Layout (the same as an imported Azure Kinect capture, :mod:`tofmetry.io.azure_kinect`)::

    <capture>/color_intrinsics.json   colour camera intrinsics (intrinsics.json format)
    <capture>/extrinsics.json         depth (IR) camera -> colour camera, metres:
                                      {"rotation": 3x3, "translation_m": [3], "source", "target"}
"""

from __future__ import annotations

import os
from pathlib import Path

from tofmetry.io._atomic import atomic_write_json
from tofmetry.io.azure_kinect import load_capture_calibration
from tofmetry.io.capture import Capture
from tofmetry.io.intrinsics_json import write_intrinsics
from tofmetry.sensor import CameraIntrinsics, Extrinsics, get_profile


def capture_colour_calibration(cap: Capture) -> tuple[CameraIntrinsics, Extrinsics, str]:
    """Colour intrinsics, depth -> colour extrinsics [m] and where they came from.

    The capture's own files (an imported device calibration, or a simulated sensor's) when both are
    present, else the profile of ``cap.sensor`` (typical values of the model).

    Raises
    ------
    InputError
        No calibration files and an unknown sensor (no profile).
    """
    if (cap.path / "color_intrinsics.json").is_file() and (cap.path / "extrinsics.json").is_file():
        cintr, ext = load_capture_calibration(cap.path)
        return cintr, ext, "capture"
    prof = get_profile(cap.sensor)
    return prof.color, prof.ir_to_color, f"profile {prof.name} (typical values)"


def write_colour_calibration(folder: str | os.PathLike, intrinsics: CameraIntrinsics, depth_to_color: Extrinsics,
                             **extra) -> Path:
    """Write ``color_intrinsics.json`` and ``extrinsics.json`` into a capture folder (or its staging
    folder) atomically; ``extra`` keys (e.g. ``source``) go into both. Returns the folder."""
    folder = Path(folder)
    write_intrinsics(folder / "color_intrinsics.json", intrinsics, **extra)
    atomic_write_json(folder / "extrinsics.json", {**depth_to_color.to_dict(), **extra})
    return folder
