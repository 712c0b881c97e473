"""The depth calibration model: a range curve plus per-pixel surfaces interpolated in range.

Model (all values in mm)::

    corrected(p) = d(p) - R(d(p)) - S(p, d(p))

* ``d(p)`` is the depth the sensor reports at pixel ``p`` (Z along the optical axis).
* ``R(d)`` is the range error: a cubic B-spline of the *measured* distance, fitted to the
  deviations of pixels near the principal point. It includes the constant offset between
  the reference point of the distances and the optical centre (reported as ``offset_mm``).
  Between ``range_data_mm`` and the edges of ``valid_range_mm`` it is clamped (constant).
* ``S(p, d)`` is the per-pixel deformation: K full-resolution maps ``surfaces[k]`` fitted at
  the nodes ``node_mm[k]`` (measured central distance of each station), linearly
  interpolated between the two nodes bracketing the pixel's own measured distance and
  clamped to the first/last map outside the nodes. By construction each map is zero on
  average near the principal point (the range curve owns that part).
* Depths outside ``valid_range_mm`` are returned unchanged (counted by
  :func:`count_outside_range`); invalid depths (0 / NaN) stay invalid.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.interpolate import BSpline

from tofmetry.errors import InputError, SensorMismatchError
from tofmetry.sensor import CameraIntrinsics

FORMAT_NAME = "tofmetry-depth-calibration"
FORMAT_VERSION = 1


@dataclass(frozen=True, eq=False)
class DepthCalibration:
    """A fitted depth calibration (see the module docstring for the model).

    Attributes
    ----------
    sensor : str
        Sensor profile name (e.g. ``"kinect_v2"``) or ``"unknown"``.
    intrinsics : CameraIntrinsics
        Intrinsics used for the fit (and to use with the corrected depth).
    range_knots, range_coeffs : (n,) float64
        Knots [mm] and coefficients [mm] of the range-error B-spline ``R``.
    range_degree : int
    range_data_mm : (2,) float64
        Measured distances [mm] spanned by the range data; ``R`` is clamped outside.
    valid_range_mm : (2,) float64
        Measured distances [mm] that are corrected; others stay unchanged.
    node_mm : (K,) float64
        Strictly increasing measured distances [mm] of the surfaces.
    surfaces : (K, H, W) float32 [mm]
    offset_mm : float
        Constant part of the range error (reference point to optical centre + mean bias).
    surface_model : str
        How the surfaces were fitted (``"spline"``, ``"poly3"``, ``"none"``...).
    provenance : dict
        How the file was produced (tool version, command, data, config, time).
    diagnostics : dict
        Small summary of the fit (per-station residuals...).
    """

    sensor: str
    intrinsics: CameraIntrinsics
    range_knots: np.ndarray
    range_coeffs: np.ndarray
    range_degree: int
    range_data_mm: np.ndarray
    valid_range_mm: np.ndarray
    node_mm: np.ndarray
    surfaces: np.ndarray
    offset_mm: float
    surface_model: str = "spline"
    provenance: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        h, w = self.intrinsics.shape
        s = np.ascontiguousarray(self.surfaces, dtype=np.float32)
        if s.ndim != 3 or s.shape[1:] != (h, w):
            raise InputError(f"calibration surfaces: expected (K, {h}, {w}) for the intrinsics, found {s.shape}")
        nodes = np.asarray(self.node_mm, dtype=np.float64).ravel()
        if len(nodes) != s.shape[0] or len(nodes) < 1:
            raise InputError(f"calibration: {len(nodes)} surface nodes for {s.shape[0]} surfaces")
        if np.any(np.diff(nodes) <= 0):
            raise InputError(f"calibration: surface nodes must be strictly increasing, found {nodes.tolist()}")
        vr = np.asarray(self.valid_range_mm, dtype=np.float64).ravel()
        if vr.shape != (2,) or not (0 < vr[0] < vr[1] < 65536):
            raise InputError(f"calibration: valid_range_mm must be [lo, hi] with 0 < lo < hi, found {vr.tolist()}")
        object.__setattr__(self, "surfaces", s)
        object.__setattr__(self, "node_mm", nodes)
        object.__setattr__(self, "valid_range_mm", vr)
        object.__setattr__(self, "range_data_mm", np.asarray(self.range_data_mm, np.float64).ravel())
        object.__setattr__(self, "range_knots", np.asarray(self.range_knots, np.float64).ravel())
        object.__setattr__(self, "range_coeffs", np.asarray(self.range_coeffs, np.float64).ravel())
        object.__setattr__(self, "range_degree", int(self.range_degree))

    # ------------------------------------------------------------------ API
    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the depth images this calibration applies to."""
        return self.intrinsics.shape

    def check_compatible(self, sensor: str | None = None, shape: tuple[int, int] | None = None) -> None:
        """Raise :class:`SensorMismatchError` if made for another sensor or resolution.

        A sensor of ``None``/``"unknown"`` on either side is accepted (cannot be checked).
        """
        if shape is not None and tuple(shape) != self.shape:
            raise SensorMismatchError(
                f"calibration is for {self.shape[1]}x{self.shape[0]} depth images, the data is {shape[1]}x{shape[0]}"
            )
        if sensor not in (None, "unknown") and self.sensor != "unknown" and sensor != self.sensor:
            raise SensorMismatchError(f"calibration is for sensor {self.sensor!r}, the data comes from {sensor!r}")

    def range_error(self, d_mm: np.ndarray) -> np.ndarray:
        """``R(d)`` [mm] at measured distances ``d_mm`` (any shape), clamped to the data range."""
        lo, hi = self.range_data_mm
        d = np.clip(np.asarray(d_mm, dtype=np.float64), lo, hi)
        return self._spline(d)

    def surface_weights(self, d_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bracketing node indices ``k0, k1`` and weight ``w`` of ``k1`` for distances ``d_mm``."""
        return _node_weights(self.node_mm, np.asarray(d_mm, dtype=np.float64))

    @cached_property
    def _spline(self) -> BSpline:
        return BSpline(self.range_knots, self.range_coeffs, self.range_degree, extrapolate=True)

    @cached_property
    def tables(self) -> "CorrectionTables":
        """Exact 65 536-entry lookup tables for integer-mm depth (built once)."""
        return _build_tables(self)

    def summary(self) -> dict:
        """Small JSON-able description (for printing / reports)."""
        return {
            "sensor": self.sensor, "shape": list(self.shape), "offset_mm": self.offset_mm,
            "valid_range_mm": self.valid_range_mm.tolist(), "nodes_mm": self.node_mm.tolist(),
            "surface_model": self.surface_model,
        }


@dataclass(frozen=True)
class CorrectionTables:
    """Kernel-ready lookup tables of a :class:`DepthCalibration` (built once per calibration).

    Tables indexed by integer depth ``d`` [mm] (65 536 entries each):

    * ``r``: range error ``R(d)`` [mm] (float32, 0 outside the valid range and for 0);
    * ``k0``/``k1``: bracketing surface indices (int32, ``k0 = -1`` outside the valid range or
      for 0); ``w``: weight of ``k1`` (float32). Used by the float-depth path.
    * ``lut_f``/``lut_i``: two views (float32 / int32, 262 144 entries) of one buffer of 16-byte
      entries: ``lut_f[4 d] = d - R(d)`` [mm] (rounded once from float64),
      ``lut_i[4 d + 1] = plane(d) * H * W`` (the offset of the linear-form plane of the node
      interval of ``d``), ``lut_f[4 d + 2] = d`` [mm] (saves the kernels an int-to-float
      conversion), ``lut_f[4 d + 3] = 0``; one cache line serves a whole entry.

    Per-pixel linear form of the surface term (uint16 kernels): on each interval between two
    nodes ``S(p, d) = a[k, p] + b[k, p] * d`` exactly, so with ``q = lut_i[4 d + 1] + p`` the
    correction of pixel ``p`` is ``(d - R(d)) - (b * d + a)``, ``b = coef[2 q]``, ``a = coef[2 q + 1]``.

    * ``coef``: (2 * P * H * W,) float32, pairs ``(b [mm/mm], a [mm])``, pixel-minor within each
      plane. Planes ``0`` (below the first node: ``a = surfaces[0]``, ``b = 0``), ``1 .. K-1``
      (between nodes ``k-1`` and ``k``), ``K`` (above the last node: ``a = surfaces[K-1]``) and
      ``K + 1`` (identity, ``a = b = 0``: depth 0 and depths outside ``valid_range_mm``).
      All arrays are flat so the kernels index with constant strides.

    Rounding: ``d - R(d)``, ``a`` and ``b`` are rounded from float64 to float32; the error of
    the result is below ``(2 |result| + |a| + |b| d) * 2**-24`` plus the rounding of ``b d + a``
    (< 1e-3 mm for surfaces of tens of mm), the float32 resolution of the corrected depth itself
    (2.4e-4 mm at 4 m).
    """

    r: np.ndarray
    k0: np.ndarray
    k1: np.ndarray
    w: np.ndarray
    lut_f: np.ndarray
    lut_i: np.ndarray
    coef: np.ndarray


def _node_weights(nodes: np.ndarray, d: np.ndarray):
    k = len(nodes)
    if k == 1:
        z = np.zeros(d.shape, np.int64)
        return z, z, np.zeros(d.shape, np.float64)
    k0 = np.clip(np.searchsorted(nodes, d, side="right") - 1, 0, k - 2)
    k1 = k0 + 1
    with np.errstate(invalid="ignore"):
        w = np.clip((d - nodes[k0]) / (nodes[k1] - nodes[k0]), 0.0, 1.0)
    return k0, k1, w


def _build_tables(cal: DepthCalibration) -> CorrectionTables:
    d = np.arange(65536, dtype=np.float64)
    lo, hi = cal.valid_range_mm
    inside = (d >= lo) & (d <= hi) & (d > 0)
    r = np.where(inside, cal.range_error(d), 0.0).astype(np.float32)
    k0, k1, w = cal.surface_weights(d)
    k0 = np.where(inside, k0, -1).astype(np.int32)
    k1 = np.where(inside, k1, 0).astype(np.int32)
    w = np.where(inside, w, 0.0).astype(np.float32)
    # linear form, planes 0 (below), 1..K-1 (intervals), K (above), K+1 (identity)
    nodes = cal.node_mm
    kk = len(nodes)
    s = cal.surfaces.reshape(kk, -1)
    npix = s.shape[1]
    if (kk + 2) * npix > np.iinfo(np.int32).max:
        raise InputError(f"calibration: {kk} surfaces of {npix} pixels are too many for int32 table offsets")
    coef = np.zeros((kk + 2, npix, 2), np.float32)
    coef[0, :, 1] = s[0]
    for k in range(1, kk):
        s0 = s[k - 1].astype(np.float64)
        b = (s[k].astype(np.float64) - s0) / (nodes[k] - nodes[k - 1])
        coef[k, :, 0] = b
        coef[k, :, 1] = s0 - b * nodes[k - 1]
    coef[kk, :, 1] = s[kk - 1]
    plane = np.where(inside, np.searchsorted(nodes, d, side="right"), kk + 1)
    lut = np.zeros((65536, 4), np.float32)
    lut[:, 0] = d - np.where(inside, cal.range_error(d), 0.0)
    lut[:, 2] = d
    lut_i = lut.view(np.int32)
    lut_i[:, 1] = plane * npix
    return CorrectionTables(r=r, k0=k0, k1=k1, w=w, lut_f=lut.reshape(-1), lut_i=lut_i.reshape(-1), coef=coef.reshape(-1))
