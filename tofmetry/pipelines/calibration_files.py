"""Calibration files: a :class:`~tofmetry.calibrate.DepthCalibration` to and from ``.npz``."""

from __future__ import annotations

import os
from pathlib import Path

from tofmetry.calibrate import DepthCalibration, calibration_from_arrays, calibration_to_arrays
from tofmetry.errors import FormatError, TofmetryError
from tofmetry.io.calibration_file import read_calibration_file, write_calibration_file


def save_calibration(path: str | os.PathLike, cal: DepthCalibration) -> Path:
    """Write ``cal`` to ``path`` (``.npz``, JSON header, no pickle) atomically."""
    header, arrays = calibration_to_arrays(cal)
    return write_calibration_file(path, header, arrays)


def load_calibration(path: str | os.PathLike, sensor: str | None = None,
                     shape: tuple[int, int] | None = None) -> DepthCalibration:
    """Read and validate a calibration file.

    Parameters
    ----------
    sensor, shape : optional; if given, checked with ``check_compatible`` (SensorMismatchError).

    Raises
    ------
    InputError
        The file does not exist.
    FormatError
        Not a calibration file, unknown version, missing or inconsistent arrays.
    SensorMismatchError
        Made for another sensor or resolution than ``sensor`` / ``shape``.
    """
    header, arrays = read_calibration_file(path)
    try:
        cal = calibration_from_arrays(header, arrays, source=str(path))
    except TofmetryError as exc:
        msg = str(exc)
        raise type(exc)(msg if "calibration" in msg else f"not a valid tofmetry calibration: {msg}") from None
    except Exception as exc:  # noqa: BLE001 - a header or array the model cannot be built from
        raise FormatError(f"{path}: not a valid tofmetry calibration: its content is inconsistent "
                          f"({type(exc).__name__}: {exc})") from None
    cal.check_compatible(sensor=sensor, shape=shape)
    return cal
