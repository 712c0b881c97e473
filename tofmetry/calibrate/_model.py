"""The depth calibration model: range terms plus per-pixel surfaces interpolated in range.

Model (all values in mm)::

    corrected(p) = d - R(d) - W(d rho(p)) / rho(p)**gamma - S(p, d)        d = d(p)

* ``d(p)`` is the depth the sensor reports at pixel ``p`` (Z along the optical axis);
  ``rho(p) = sqrt(1 + x^2 + y^2)`` for the pixel's undistorted normalised ray, so ``d rho`` is
  the measured ray length.
* ``R(d)`` is a range error in Z: a cubic B-spline of the *measured* distance (a constant when
  the range error is modelled along the ray). It includes the constant offset between the
  reference point of the distances and the optical centre (reported as ``offset_mm``).
  Clamped (constant) outside ``range_data_mm``.
* ``W(q)`` (optional, ``ray_knots``/``ray_coeffs``): the range error of a continuous-wave ToF
  camera as a function of the measured ray length ``q``, seen in Z as ``W / rho**gamma``
  (``gamma = 1``: the error lies along the ray). Clamped outside ``ray_data_mm``.
* ``S(p, d)`` is the per-pixel deformation: K full-resolution maps ``surfaces[k]`` fitted at
  the nodes ``node_mm[k]``, linearly interpolated between the two nodes bracketing the pixel's
  own measured distance and clamped to the first/last map outside the nodes.
* **Support** (optional, :class:`~tofmetry.calibrate._support.CalibrationSupport`): the depth
  interval fitted at each pixel. Outside it the ``fallback`` applies: ``"hold"`` evaluates
  the correction at the nearest supported depth (no extrapolation of any curve), ``"trend"``
  applies the low-order part ``a + b d`` only. Pixels of image cells that were never seen keep
  the surfaces' smooth continuation and are counted as outside the support. Files without a support (format version 1) keep the old rule:
  depths outside ``valid_range_mm`` are returned unchanged (``fallback = "unchanged"``).
* Invalid depths (0 / NaN) stay invalid.
* ``prediction`` (optional): the calibration's own predicted error on new data, from its
  blocked validation (see :mod:`tofmetry.calibrate._prediction`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.interpolate import BSpline

from tofmetry._shared.geometry import ray_factor
from tofmetry.calibrate._support import CalibrationSupport
from tofmetry.calibrate._tables import CorrectionTables, build_tables
from tofmetry.errors import InputError, SensorMismatchError
from tofmetry.sensor import CameraIntrinsics

#: fallback rules outside the support (see the module docstring)
FALLBACKS = ("hold", "trend", "unchanged")


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
    ray_knots, ray_coeffs : (n,) float64 or None
        B-spline ``W`` [mm] of the measured ray length [mm] (None: no ray term).
    ray_degree : int
        Degree of that B-spline (3; 1 for a piecewise-linear term such as the board model's).
    ray_gamma : float
        ``W`` is divided by ``rho**ray_gamma``.
    ray_data_mm : (2,) float64
        Ray lengths [mm] spanned by the data; ``W`` is clamped outside.
    support : CalibrationSupport or None
        Per-pixel supported depth interval (None: ``valid_range_mm`` everywhere).
    fallback : str
        Rule outside the support: ``"hold"``, ``"trend"`` or ``"unchanged"``.
    trend_mm : (2,) float64
        ``(a [mm], b [mm/mm])`` of the ``"trend"`` fallback ``a + b d``.
    prediction : dict
        Predicted error on new data with intervals (empty when not validated).
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
    ray_knots: np.ndarray | None = None
    ray_coeffs: np.ndarray | None = None
    ray_degree: int = 3
    ray_gamma: float = 1.0
    ray_data_mm: np.ndarray | None = None
    support: CalibrationSupport | None = None
    fallback: str = "unchanged"
    trend_mm: tuple = (0.0, 0.0)
    prediction: dict = field(default_factory=dict)

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
        if self.fallback not in FALLBACKS:
            raise InputError(f"calibration: fallback must be one of {FALLBACKS}, found {self.fallback!r}")
        if (self.ray_knots is None) != (self.ray_coeffs is None):
            raise InputError("calibration: ray_knots and ray_coeffs must be given together")
        if self.ray_knots is not None:
            rk = np.asarray(self.ray_knots, np.float64).ravel()
            rc = np.asarray(self.ray_coeffs, np.float64).ravel()
            if self.ray_degree not in (1, 3) or len(rk) != len(rc) + self.ray_degree + 1:
                raise InputError(f"calibration: {len(rk)} ray knots for {len(rc)} coefficients of degree {self.ray_degree} "
                                 f"(expected n + degree + 1, degree 1 or 3)")
            object.__setattr__(self, "ray_knots", rk)
            object.__setattr__(self, "ray_coeffs", rc)
            kd = int(self.ray_degree)
            rd = np.asarray(self.ray_data_mm if self.ray_data_mm is not None else (rk[kd], rk[-kd - 1]), np.float64).ravel()
            object.__setattr__(self, "ray_data_mm", rd)
        if self.support is not None and tuple(self.support.shape) != (h, w):
            raise InputError(f"calibration: support shape {tuple(self.support.shape)} differs from the intrinsics {(h, w)}")
        if self.fallback != "unchanged" and self.support is None:
            raise InputError(f"calibration: fallback {self.fallback!r} needs a support map")
        object.__setattr__(self, "trend_mm", tuple(float(x) for x in self.trend_mm))

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

    def ray_error(self, q_mm: np.ndarray) -> np.ndarray:
        """``W(q)`` [mm] at measured ray lengths ``q_mm`` (any shape), clamped to the data; 0 without a ray term."""
        q = np.asarray(q_mm, dtype=np.float64)
        if self.ray_knots is None:
            return np.zeros(q.shape)
        lo, hi = self.ray_data_mm
        return self._ray_spline(np.clip(q, lo, hi))

    @cached_property
    def rho(self) -> np.ndarray:
        """(H, W) float64 ray length per unit depth ``sqrt(1 + x^2 + y^2)`` of each pixel."""
        return ray_factor(self.intrinsics.ray_table())

    def correction(self, depth_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Correction [mm] to subtract from a depth image, and where it is supported.

        The plain numpy definition of the model (see :meth:`correction_at`); the kernels of
        :mod:`._apply` and :mod:`._backproject` compute the same through :mod:`._tables`.

        Parameters
        ----------
        depth_mm : (H, W) float or uint16 [mm], 0 / NaN = invalid

        Returns
        -------
        corr : (H, W) float64 [mm] (0 where invalid or left unchanged), inside : (H, W) bool
        """
        d = np.asarray(depth_mm, np.float64)
        self.check_compatible(shape=d.shape)
        v, u = np.indices(d.shape)
        return self.correction_at(u, v, d)

    def correction_at(self, u: np.ndarray, v: np.ndarray, d_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Correction [mm] at integer pixels ``(u, v)`` for measured depths ``d_mm`` (same shapes).

        With a support, depths within its overall range ``[lo, hi]`` get the full model (the
        surfaces continue smoothly over image cells the fit never saw, as they were fitted);
        outside it the
        ``fallback``: ``"hold"`` = the full model at the nearest of ``lo``/``hi``, ``"trend"`` =
        ``a + b d``, ``"unchanged"`` = no correction. ``inside`` is the per-pixel test against
        the pixel's own supported interval (what is reported as extrapolated). Without a
        support (format version 1) depths outside ``valid_range_mm`` are left unchanged.

        Returns
        -------
        corr : float64 [mm] (0 where invalid or left unchanged), inside : bool
        """
        u = np.asarray(u, np.intp)
        v = np.asarray(v, np.intp)
        d = np.asarray(d_mm, np.float64)
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(d) & (d > 0)
        dv = np.where(valid, d, 0.0)
        if self.support is None:
            lo, hi = self.valid_range_mm
            inside = valid & (dv >= lo) & (dv <= hi)
            return np.where(inside, self._full(u, v, dv), 0.0), inside
        sup = self.support
        inside = valid & (dv >= sup.lo_mm[v, u]) & (dv <= sup.hi_mm[v, u])
        lo, hi = self.support_range_mm
        in_range = (dv >= lo) & (dv <= hi)
        if self.fallback == "hold":
            corr = self._full(u, v, np.clip(dv, lo, hi))
        elif self.fallback == "trend":
            a, b = self.trend_mm
            corr = np.where(in_range, self._full(u, v, dv), a + b * dv)
        else:
            corr = np.where(in_range, self._full(u, v, dv), 0.0)
        return np.where(valid, corr, 0.0), inside

    @property
    def support_range_mm(self) -> tuple[float, float]:
        """Overall depth range [mm] the correction is evaluated in (support's, else ``valid_range_mm``)."""
        if self.support is None:
            return float(self.valid_range_mm[0]), float(self.valid_range_mm[1])
        lo, hi = self.support.range_mm
        if not np.isfinite(lo):
            return float(self.range_data_mm[0]), float(self.range_data_mm[-1])
        return lo, hi

    def _full(self, u: np.ndarray, v: np.ndarray, d: np.ndarray) -> np.ndarray:
        """``R(d) + W(d rho) / rho**gamma + S(p, d)`` at pixels ``(u, v)``."""
        out = self.range_error(d)
        if self.ray_knots is not None:
            rho = self.rho[v, u]
            out = out + self.ray_error(d * rho) / rho ** self.ray_gamma
        k0, k1, w = self.surface_weights(d)
        s = (1 - w) * self.surfaces[k0, v, u] + w * self.surfaces[k1, v, u]
        return out + s

    def surface_weights(self, d_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bracketing node indices ``k0, k1`` and weight ``w`` of ``k1`` for distances ``d_mm``."""
        return _node_weights(self.node_mm, np.asarray(d_mm, dtype=np.float64))

    @cached_property
    def _spline(self) -> BSpline:
        return BSpline(self.range_knots, self.range_coeffs, self.range_degree, extrapolate=True)

    @cached_property
    def _ray_spline(self) -> BSpline:
        return BSpline(self.ray_knots, self.ray_coeffs, int(self.ray_degree), extrapolate=True)

    @cached_property
    def tables(self) -> CorrectionTables:
        """Kernel-ready lookup tables (:mod:`tofmetry.calibrate._tables`, built once)."""
        return build_tables(self)

    def summary(self) -> dict:
        """Small JSON-able description (for printing / reports)."""
        out = {
            "sensor": self.sensor, "shape": list(self.shape), "offset_mm": self.offset_mm,
            "valid_range_mm": self.valid_range_mm.tolist(), "nodes_mm": self.node_mm.tolist(),
            "surface_model": self.surface_model, "ray_term": self.ray_knots is not None,
            "ray_gamma": self.ray_gamma if self.ray_knots is not None else None, "fallback": self.fallback,
        }
        if self.support is not None:
            out["support"] = self.support.summary()
        if self.prediction:
            out["prediction"] = self.prediction
        return out


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
