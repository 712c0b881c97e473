"""Depth calibration file: ``.npz`` with a JSON header (no pickle).

Layout (``np.savez``, loaded with ``allow_pickle=False``)::

    header        0-d unicode array: JSON {"format": "tofmetry-depth-calibration", "version": 1,
                  "sensor", "intrinsics", "offset_mm", "valid_range_mm", "range_data_mm",
                  "range_degree", "surface_model", "provenance", "diagnostics"}
    range_knots   (n,) float64 [mm]     B-spline knots of the range error R(d)
    range_coeffs  (n,) float64 [mm]     B-spline coefficients
    node_mm       (K,) float64 [mm]     surface nodes (measured distance)
    surfaces      (K, H, W) float32 [mm] per-pixel deformation maps
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the model lives in tofmetry.calibrate, which itself re-exports this module's functions
    from tofmetry.calibrate._model import DepthCalibration
from tofmetry.errors import FormatError, InputError
from tofmetry.io._atomic import atomic_write_bytes, to_json
from tofmetry.sensor import CameraIntrinsics

_ARRAYS = ("range_knots", "range_coeffs", "node_mm", "surfaces")


def save_calibration(path: str | os.PathLike, cal: DepthCalibration) -> Path:
    """Write ``cal`` to ``path`` (``.npz``) atomically."""
    from tofmetry.calibrate._model import FORMAT_NAME, FORMAT_VERSION

    header = {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "sensor": cal.sensor,
        "intrinsics": cal.intrinsics.to_dict(), "offset_mm": cal.offset_mm,
        "valid_range_mm": cal.valid_range_mm.tolist(), "range_data_mm": cal.range_data_mm.tolist(),
        "range_degree": cal.range_degree, "surface_model": cal.surface_model,
        "shape": list(cal.shape), "n_surfaces": int(cal.surfaces.shape[0]),
        "provenance": cal.provenance, "diagnostics": cal.diagnostics,
    }
    buf = io.BytesIO()
    np.savez(  # uncompressed: smooth float32 maps barely compress and zlib costs seconds
        buf, header=np.array(to_json(header, indent=None)), range_knots=cal.range_knots,
        range_coeffs=cal.range_coeffs, node_mm=cal.node_mm, surfaces=cal.surfaces.astype(np.float32),
    )
    return atomic_write_bytes(Path(path), buf.getvalue())


def read_calibration_header(path: str | os.PathLike) -> dict:
    """The JSON header only (cheap)."""
    return _open(Path(path))[0]


def _open(path: Path):
    from tofmetry.calibrate._model import FORMAT_NAME, FORMAT_VERSION

    if not path.is_file():
        raise InputError(f"calibration file not found: {path}")
    try:
        z = np.load(path, allow_pickle=False)
    except (ValueError, OSError, zipfile.BadZipFile) as exc:
        raise FormatError(f"{path}: not a tofmetry calibration (.npz with a JSON header): {exc}") from None
    with z:
        if "header" not in z.files:
            raise FormatError(f"{path}: no 'header' entry; not a tofmetry calibration file")
        try:
            header = json.loads(str(z["header"][()]))
        except (json.JSONDecodeError, ValueError) as exc:
            raise FormatError(f"{path}: header is not valid JSON ({exc})") from None
        if header.get("format") != FORMAT_NAME:
            raise FormatError(f"{path}: format {header.get('format')!r}, expected {FORMAT_NAME!r}")
        ver = header.get("version")
        if ver != FORMAT_VERSION:
            raise FormatError(f"{path}: calibration format version {ver}, this tofmetry reads version {FORMAT_VERSION}")
        missing = [a for a in _ARRAYS if a not in z.files]
        if missing:
            raise FormatError(f"{path}: missing arrays {missing}")
        arrays = {a: z[a] for a in _ARRAYS}
    return header, arrays


def load_calibration(path: str | os.PathLike, sensor: str | None = None,
                     shape: tuple[int, int] | None = None) -> DepthCalibration:
    """Read and validate a calibration file.

    Parameters
    ----------
    sensor, shape : optional; if given, checked with ``check_compatible`` (SensorMismatchError).

    Raises
    ------
    FormatError
        Not a calibration file, wrong version, missing or inconsistent arrays.
    SensorMismatchError
        Made for another sensor or resolution than ``sensor`` / ``shape``.
    """
    from tofmetry.calibrate._model import DepthCalibration

    path = Path(path)
    header, a = _open(path)
    try:
        intr = CameraIntrinsics.from_dict(header["intrinsics"], source=f"{path} header")
        hshape = tuple(header["shape"])
        if hshape != intr.shape or a["surfaces"].shape[1:] != intr.shape:
            raise FormatError(
                f"{path}: inconsistent resolution: header {hshape}, intrinsics {intr.shape}, surfaces {a['surfaces'].shape[1:]}"
            )
        cal = DepthCalibration(
            sensor=str(header["sensor"]), intrinsics=intr, range_knots=a["range_knots"],
            range_coeffs=a["range_coeffs"], range_degree=int(header["range_degree"]),
            range_data_mm=np.array(header["range_data_mm"], float), valid_range_mm=np.array(header["valid_range_mm"], float),
            node_mm=a["node_mm"], surfaces=a["surfaces"], offset_mm=float(header["offset_mm"]),
            surface_model=str(header.get("surface_model", "")), provenance=header.get("provenance") or {},
            diagnostics=header.get("diagnostics") or {},
        )
    except KeyError as exc:
        raise FormatError(f"{path}: header misses key {exc}") from None
    except InputError as exc:
        if isinstance(exc, FormatError):
            raise
        raise FormatError(f"{path}: {exc}") from None
    cal.check_compatible(sensor=sensor, shape=shape)
    return cal
