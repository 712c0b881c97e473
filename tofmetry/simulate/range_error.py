"""(a) The range error ("wiggling"): a trend plus periodic components of the range.

A continuous-wave ToF camera measures the phase of the light that travelled along the pixel's
ray, i.e. the **radial** path length ``r = Z rho`` with ``rho = sqrt(1 + x^2 + y^2)`` and
``(x, y)`` the undistorted normalised ray of the pixel. Its systematic range error is a curve
``W(d)`` of one range variable ``d``:

``W(d) = o + s (d - 0.8) + q (d - 0.8)^2 + g d[mm]
+ sum_c sum_k a_ck sin(2 pi k d / P_c + phi_ck) + e max(0, d - d_s)^p``   (d in m, W in mm)

(offset, slope, quadratic term, scale/gain error, periodic components of arbitrary periods
``P_c`` with harmonics ``k``, steep growth past ``d_s``). Two switches of
:class:`~tofmetry.simulate.errors.ErrorModel` say how it reaches the depth map:

* ``range_variable``: ``"z"`` (``d = Z``, the default Kinect v2 of this simulator) or
  ``"radial"`` (``d = r = Z rho``, the physical variable);
* ``range_apply``: ``"z"`` (the Z reading is off by ``W``) or ``"ray"`` (the radial reading
  is off by ``W`` and the sensor converts it to Z: the Z error is ``W / rho``).

The default (``"z"``, ``"z"``) is the curve of the study (paper §4.2.2, Fig. 7a) in Z.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tofmetry._shared.geometry import ray_factor
from tofmetry.errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    from tofmetry.simulate.errors import ErrorModel

#: Reference range of the trend terms [m] (the study's first station).
TREND_REF_M = 0.8


def wiggle_components(em: "ErrorModel") -> list[tuple[float, list[tuple[int, float, float]]]]:
    """The periodic components of ``em``: ``[(period_m, [(harmonic k, amp_mm, phase_rad), ...]), ...]``.

    ``em.wiggle_harmonics`` (one count per period) splits the flat ``wiggle_amps_mm`` /
    ``wiggle_phases``; ``None`` means one component holding all of them (harmonics 1..n).
    """
    amps, phases, periods = em.wiggle_amps_mm, em.wiggle_phases, em.wiggle_periods_m
    counts = em.wiggle_harmonics if em.wiggle_harmonics is not None else (len(amps),)
    out, i = [], 0
    for period, n in zip(periods, counts):
        out.append((float(period), [(k, float(amps[i + k - 1]), float(phases[i + k - 1])) for k in range(1, n + 1)]))
        i += n
    return out


def range_error_curve_mm(d_mm: np.ndarray, em: "ErrorModel") -> np.ndarray:
    """The range error curve ``W(d)`` [mm] of the range variable ``d`` [mm] (see the module docstring).

    Parameters
    ----------
    d_mm : array of float [mm]
        The range variable: Z or the radial range, as ``em.range_variable`` says (this function
        does not care which).

    Returns
    -------
    Array of the same shape [mm].
    """
    d_mm = np.asarray(d_mm, dtype=np.float64)
    d = d_mm * 1e-3
    w = em.wiggle_offset_mm + em.wiggle_slope_mm_per_m * (d - TREND_REF_M)
    if em.wiggle_quad_mm_per_m2 != 0.0:
        w = w + em.wiggle_quad_mm_per_m2 * (d - TREND_REF_M) ** 2
    if em.wiggle_gain != 0.0:
        w = w + em.wiggle_gain * d_mm
    # the operations below are written exactly as the original single-component model, so that
    # the default ErrorModel stays bit-identical
    for period, harmonics in wiggle_components(em):
        for k, a, p in harmonics:
            w = w + a * np.sin(2 * np.pi * k * d / period + p)
    w = w + em.wiggle_steep_mm * np.maximum(d - em.wiggle_steep_start_m, 0.0) ** em.wiggle_steep_power
    return w


def needs_rays(em: "ErrorModel") -> bool:
    """Whether the range error of ``em`` depends on the pixel (radial variable or ray application)."""
    return em.range_variable == "radial" or em.range_apply == "ray"


def wiggling_mm(z_mm: np.ndarray, em: "ErrorModel", xy: np.ndarray | None = None) -> np.ndarray:
    """(a) Range-dependent systematic error of the Z reading [mm].

    Default Kinect v2 (``range_variable = range_apply = "z"``):
    ``w(z) = o + s (z - 0.8) + sum_k a_k sin(2 pi k z / L + phi_k) + g max(0, z - z_s)^1.5``
    with ``L`` = 1.874 m, the half wavelength of the 80 MHz modulation (harmonics
    k = 1, 2, 3 of a not perfectly sinusoidal modulation, paper §2.3) and a steep growth
    past ``z_s`` = 4.4 m. Between 0.8 and 4.5 m it spans -15 .. +7 mm (paper Fig. 7a).
    In general the curve :func:`range_error_curve_mm` of Z or of the radial range, applied in Z
    or along the ray (module docstring).

    Parameters
    ----------
    z_mm : array of float [mm]
        Depth Z of the true surface.
    xy : (..., 2) float64, optional
        Undistorted normalised rays of the same pixels (broadcast against ``z_mm``); needed
        when ``em.range_variable == "radial"`` or ``em.range_apply == "ray"``.

    Returns
    -------
    Bias of the Z reading, same shape as ``z_mm`` [mm].
    """
    if not needs_rays(em):
        return range_error_curve_mm(z_mm, em)
    if xy is None:
        raise InputError(f"wiggling_mm: xy (normalised rays) is needed for range_variable={em.range_variable!r}, "
                         f"range_apply={em.range_apply!r}; found None")
    z = np.asarray(z_mm, dtype=np.float64)
    rho = ray_factor(xy)
    d = z * rho if em.range_variable == "radial" else z
    w = range_error_curve_mm(d, em)
    return w / rho if em.range_apply == "ray" else w
