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


_MAGIC = ((b"\x89PNG", "a PNG image"), (b"\xff\xd8\xff", "a JPEG image"), (b"II*\x00", "a TIFF image"),
          (b"MM\x00*", "a TIFF image"), (b"ply", "a PLY file"), (b"%YAML", "a YAML file"), (b"\x1aE\xdf\xa3", "a Matroska video"),
          (b"\x93NUMPY", "a single .npy array"), (b"\x80", "a Python pickle"), (b"{", "a JSON file"))


def _what_is(head: bytes) -> str:
    """A short description of a file from its first bytes (for messages)."""
    for magic, what in _MAGIC:
        if head.startswith(magic):
            return what
    if not head:
        return "an empty file"
    try:
        head.decode("utf-8")
        return "a text file"
    except UnicodeDecodeError:
        return f"a binary file starting with {head[:8]!r}"


def _not_ours(path: Path, why: str) -> FormatError:
    return FormatError(f"{path}: not a tofmetry calibration (expected an .npz written by 'tofmetry calibrate depth', "
                       f"with a JSON header): {why}")


def read_calibration_file(path: str | os.PathLike) -> tuple[dict, dict[str, np.ndarray]]:
    """Read and check a calibration container: ``(header, arrays)``.

    Nothing is unpickled: a file holding Python objects is refused like any other foreign file.

    Raises
    ------
    InputError
        The file does not exist.
    FormatError
        Not a tofmetry calibration (naming what the file looks like instead), an unknown version,
        or required arrays missing.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"calibration file not found: {path}")
    with open(path, "rb") as fh:
        head = fh.read(16)
    if not head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        raise _not_ours(path, f"it is {_what_is(head)}")
    try:
        z = np.load(path, allow_pickle=False)
    except Exception:  # noqa: BLE001 - zipfile/zlib/numpy raise many types; none of their text helps a user
        raise _not_ours(path, "a zip archive that numpy cannot read as .npz") from None
    with z:
        if "header" not in z.files:
            raise _not_ours(path, f"no 'header' entry (entries: {', '.join(z.files[:8]) or 'none'})")
        try:
            raw = z["header"]
        except ValueError:  # object arrays would need pickle: never loaded
            raise _not_ours(path, "its 'header' entry holds Python objects, which tofmetry never loads") from None
        except Exception:  # noqa: BLE001 - a damaged member (zlib, CRC, truncated)
            raise _not_ours(path, "its 'header' entry is damaged") from None
        if not isinstance(raw, np.ndarray):
            raise _not_ours(path, "its 'header' entry is not a numpy array")
        if raw.dtype.kind != "U" or raw.ndim != 0:
            raise _not_ours(path, f"its 'header' entry is a {raw.dtype} array of shape {raw.shape}, not JSON text")
        try:
            header = json.loads(str(raw[()]))
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
        arrays = {}
        for a in z.files:
            if a == "header":
                continue
            try:
                arrays[a] = z[a]
            except ValueError:  # an object array would need pickle
                raise FormatError(f"{path}: array {a!r} holds Python objects, which tofmetry never loads") from None
            except Exception:  # noqa: BLE001 - a damaged member
                raise FormatError(f"{path}: array {a!r} is damaged (truncated or corrupt zip member)") from None
            if not isinstance(arrays[a], np.ndarray) or arrays[a].dtype.kind not in "biuf":
                raise FormatError(f"{path}: array {a!r} is {getattr(arrays[a], 'dtype', 'not an array')}, expected numbers")
    return header, arrays


def read_calibration_header(path: str | os.PathLike) -> dict:
    """The JSON header only."""
    return read_calibration_file(path)[0]
