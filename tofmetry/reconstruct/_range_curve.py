"""A smooth range-error curve over the scan's depth span, shared by all views (the global
adjustment's higher-order depth correction; :mod:`tofmetry.reconstruct._adjust`).

Why: a depth calibration from wall stations ~0.25 m apart leaves a residual of the sensor's
range error (wiggling) between them. Over the object's depth span it is a smooth function of the
measured range, the same in every view, but not linear: a single gain (``dz = g (z - z_ref)``)
closes a turntable loop's yaw sum yet leaves 0.4-0.9 deg per edge (measured on a 13-view bunny).
Because each view sees the object over a different depth range, overlapping views observe the
curve's shape; its offset at ``z_ref`` (a uniform range offset, nearly a scale) and its linear
part over the span (the gain, estimated separately) are left out of it.

Model, with ``u = clip((z - z_ref) / h, -1, 1)`` (``h``: half the depth span, ``z``: measured Z)::

    dz(z) = sum_k c_k (P_k(u) - P_k(0)),  k = 2 .. degree

``P_k`` are Legendre polynomials, orthogonal over the span to the linear gain (so the gain keeps
its meaning, the mean local gain over the span, and the two are not correlated), ``c_k`` in metres. Points move along their rays: ``p' = p (z + dz(z)) / z``.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre


def range_basis(z: np.ndarray, z_ref_m: float, half_span_m: float, degree: int) -> np.ndarray:
    """Basis functions of the range curve at measured depths ``z``.

    Parameters
    ----------
    z : (N,) measured depth Z [m]
    z_ref_m : depth where the curve is zero [m]
    half_span_m : half the depth span the curve covers [m] (> 0); beyond it the curve is constant
    degree : highest Legendre degree (>= 2; terms 2 .. degree)

    Returns
    -------
    (N, degree - 1) dimensionless
    """
    if degree < 2 or not half_span_m > 0:
        return np.zeros((len(z), 0))
    u = np.clip((np.asarray(z, np.float64) - z_ref_m) / half_span_m, -1.0, 1.0)
    cols = []
    for k in range(2, degree + 1):
        c = np.zeros(k + 1)
        c[k] = 1.0
        cols.append(legendre.legval(u, c) - legendre.legval(0.0, c))
    return np.stack(cols, axis=1)


def range_curve_m(z: np.ndarray, coeffs_m: np.ndarray, z_ref_m: float, half_span_m: float) -> np.ndarray:
    """The range correction ``dz`` [m] at measured depths ``z`` [m] ((N,) -> (N,))."""
    coeffs_m = np.asarray(coeffs_m, np.float64)
    if coeffs_m.size == 0:
        return np.zeros(np.shape(z))
    return range_basis(np.ravel(z), z_ref_m, half_span_m, coeffs_m.size + 1) @ coeffs_m


def apply_range_curve(points: np.ndarray, coeffs_m: np.ndarray, z_ref_m: float, half_span_m: float) -> np.ndarray:
    """Move camera-frame points along their rays by the range curve: ``Z -> Z + dz(Z)``.

    Parameters
    ----------
    points : (N, 3) [m], camera frame (Z > 0)
    coeffs_m : (degree - 1,) curve coefficients [m]; z_ref_m, half_span_m : [m]

    Returns
    -------
    (N, 3) [m]
    """
    z = points[:, 2]
    dz = range_curve_m(z, coeffs_m, z_ref_m, half_span_m)
    return points * (1.0 + dz / np.where(z > 0, z, np.inf))[:, None]


def range_curve_sigma_m(z: np.ndarray, cov_m2: np.ndarray, z_ref_m: float, half_span_m: float) -> np.ndarray:
    """Standard error [m] of the curve at depths ``z`` from the coefficients' covariance ``cov_m2``
    ((D, D) [m^2])."""
    B = range_basis(np.ravel(z), z_ref_m, half_span_m, len(cov_m2) + 1)
    return np.sqrt(np.clip(np.einsum("ij,jk,ik->i", B, cov_m2, B), 0, None))
