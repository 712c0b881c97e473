"""A :class:`DepthCalibration` as a JSON header plus named arrays, and back.

The container format lives in :mod:`tofmetry.io.calibration_file`; this module only maps the
model's fields onto it (versions 1 and 2), so that :mod:`tofmetry.io` needs nothing from
:mod:`tofmetry.calibrate`.
"""

from __future__ import annotations

import numpy as np

from tofmetry.calibrate._model import DepthCalibration
from tofmetry.calibrate._support import CalibrationSupport
from tofmetry.errors import FormatError, InputError
from tofmetry.sensor import CameraIntrinsics


def calibration_to_arrays(cal: DepthCalibration) -> tuple[dict, dict]:
    """``(header, arrays)`` of ``cal`` for :func:`tofmetry.io.calibration_file.write_calibration_file`."""
    header = {
        "sensor": cal.sensor, "intrinsics": cal.intrinsics.to_dict(), "offset_mm": cal.offset_mm,
        "valid_range_mm": cal.valid_range_mm.tolist(), "range_data_mm": cal.range_data_mm.tolist(),
        "range_degree": cal.range_degree, "surface_model": cal.surface_model,
        "shape": list(cal.shape), "n_surfaces": int(cal.surfaces.shape[0]),
        "provenance": cal.provenance, "diagnostics": cal.diagnostics,
        "fallback": cal.fallback, "trend_mm": list(cal.trend_mm), "prediction": cal.prediction,
        "ray_gamma": cal.ray_gamma, "ray_degree": cal.ray_degree, "ray_data_mm": None if cal.ray_data_mm is None else cal.ray_data_mm.tolist(),
    }
    arrays = {"range_knots": cal.range_knots, "range_coeffs": cal.range_coeffs, "node_mm": cal.node_mm,
              "surfaces": cal.surfaces.astype(np.float32)}
    if cal.ray_knots is not None:
        arrays |= {"ray_knots": cal.ray_knots, "ray_coeffs": cal.ray_coeffs}
    if cal.support is not None:
        arrays |= cal.support.to_arrays()
    return header, arrays


def calibration_from_arrays(header: dict, arrays: dict, source: str = "calibration") -> DepthCalibration:
    """Build and validate a :class:`DepthCalibration`; errors are :class:`FormatError` naming ``source``."""
    a = arrays
    try:
        intr = CameraIntrinsics.from_dict(header["intrinsics"], source=f"{source} header")
        hshape = tuple(header["shape"])
        if hshape != intr.shape or np.shape(a["surfaces"])[1:] != intr.shape:
            raise FormatError(f"{source}: inconsistent resolution: header {hshape}, intrinsics {intr.shape}, "
                              f"surfaces {np.shape(a['surfaces'])[1:]}")
        support = CalibrationSupport.from_arrays(a, intr.shape) if "support_lo_mm" in a else None
        ray = {}
        if "ray_knots" in a:
            ray = {"ray_knots": a["ray_knots"], "ray_coeffs": a["ray_coeffs"],
                   "ray_gamma": float(header.get("ray_gamma", 1.0)), "ray_degree": int(header.get("ray_degree", 3)),
                   "ray_data_mm": None if header.get("ray_data_mm") is None else np.array(header["ray_data_mm"], float)}
        return DepthCalibration(
            sensor=str(header["sensor"]), intrinsics=intr, range_knots=a["range_knots"],
            range_coeffs=a["range_coeffs"], range_degree=int(header["range_degree"]),
            range_data_mm=np.array(header["range_data_mm"], float), valid_range_mm=np.array(header["valid_range_mm"], float),
            node_mm=a["node_mm"], surfaces=a["surfaces"], offset_mm=float(header["offset_mm"]),
            surface_model=str(header.get("surface_model", "")), provenance=header.get("provenance") or {},
            diagnostics=header.get("diagnostics") or {}, support=support,
            fallback=str(header.get("fallback", "unchanged")), trend_mm=tuple(header.get("trend_mm", (0.0, 0.0))),
            prediction=header.get("prediction") or {}, **ray,
        )
    except KeyError as exc:
        raise FormatError(f"{source}: missing {exc}") from None
    except (TypeError, ValueError) as exc:
        if isinstance(exc, FormatError):
            raise
        if isinstance(exc, InputError):
            raise FormatError(f"{source}: {exc}") from None
        raise FormatError(f"{source}: malformed calibration ({exc})") from None
