"""Depth calibration file: ``.npz`` with a JSON header (no pickle).

This module reads and writes the container only: a JSON header and named arrays. The model
(:class:`tofmetry.calibrate.DepthCalibration`) is built from them by
:func:`tofmetry.calibrate.calibration_from_arrays`; :func:`tofmetry.pipelines.load_calibration`
and :func:`tofmetry.pipelines.save_calibration` do both.

Layout (``np.savez``, loaded with ``allow_pickle=False``)::

    header          0-d unicode array: JSON {"format": "tofmetry-depth-calibration", "version": 1|2,
                    "sensor", "intrinsics", "offset_mm", "valid_range_mm", "range_data_mm",
                    "range_degree", "surface_model", "provenance", "diagnostics"; version 2 adds
                    "ray_gamma", "ray_data_mm", "fallback", "trend_mm", "prediction"}
    range_knots     (n,) float64 [mm]        B-spline knots of the range error R(d)
    range_coeffs    (n,) float64 [mm]        B-spline coefficients
    node_mm         (K,) float64 [mm]        surface nodes (measured distance)
    surfaces        (K, H, W) float32 [mm]   per-pixel deformation maps
    version 2, optional:
    ray_knots, ray_coeffs   (m,) float64     cubic B-spline W of the ray length [mm]
    support_*               the support map (see tofmetry.calibrate.CalibrationSupport)
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from tofmetry.errors import FormatError, InputError
from tofmetry.io._atomic import atomic_write_bytes, to_json

FORMAT_NAME = "tofmetry-depth-calibration"
#: versions this module reads; it writes the last one
VERSIONS = (1, 2)
REQUIRED = ("range_knots", "range_coeffs", "node_mm", "surfaces")


def write_calibration_file(path: str | os.PathLike, header: dict, arrays: dict[str, np.ndarray]) -> Path:
    """Write a calibration container atomically.

    Parameters
    ----------
    path : destination ``.npz``
    header : JSON-able dict (format name and version are set here)
    arrays : name -> numeric array (no object arrays)
    """
    bad = [k for k, a in arrays.items() if np.asarray(a).dtype == object]
    if bad:
        raise InputError(f"calibration file: arrays {bad} are object arrays; only numeric arrays are stored")
    missing = [a for a in REQUIRED if a not in arrays]
    if missing:
        raise InputError(f"calibration file: missing arrays {missing}")
    head = {"format": FORMAT_NAME, "version": VERSIONS[-1], **header}
    buf = io.BytesIO()
    # uncompressed: smooth float32 maps barely compress and zlib costs seconds
    np.savez(buf, header=np.array(to_json(head, indent=None)), **{k: np.asarray(a) for k, a in arrays.items()})
    return atomic_write_bytes(Path(path), buf.getvalue())


def read_calibration_file(path: str | os.PathLike) -> tuple[dict, dict[str, np.ndarray]]:
    """Read and check a calibration container: ``(header, arrays)``.

    Raises
    ------
    InputError
        The file does not exist.
    FormatError
        Not a tofmetry calibration, an unknown version, or required arrays missing.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"calibration file not found: {path}")
    try:
        z = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise FormatError(f"{path}: not a tofmetry calibration (.npz with a JSON header): {exc}") from None
    if not hasattr(z, "files"):
        raise FormatError(f"{path}: a single .npy array, not a tofmetry calibration (.npz with a JSON header)")
    with z:
        if "header" not in z.files:
            raise FormatError(f"{path}: no 'header' entry; not a tofmetry calibration file")
        try:
            header = json.loads(str(z["header"][()]))
        except (json.JSONDecodeError, ValueError) as exc:
            raise FormatError(f"{path}: header is not valid JSON ({exc})") from None
        if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
            fmt = header.get("format") if isinstance(header, dict) else type(header).__name__
            raise FormatError(f"{path}: format {fmt!r}, expected {FORMAT_NAME!r}")
        ver = header.get("version")
        if ver not in VERSIONS:
            raise FormatError(f"{path}: calibration format version {ver}, this tofmetry reads versions {list(VERSIONS)}")
        missing = [a for a in REQUIRED if a not in z.files]
        if missing:
            raise FormatError(f"{path}: missing arrays {missing}")
        try:
            arrays = {a: z[a] for a in z.files if a != "header"}
        except ValueError as exc:  # an object array would need pickle
            raise FormatError(f"{path}: unreadable array ({exc})") from None
    return header, arrays


def read_calibration_header(path: str | os.PathLike) -> dict:
    """The JSON header only."""
    return read_calibration_file(path)[0]
