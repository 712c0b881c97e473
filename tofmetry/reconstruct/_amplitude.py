"""Amplitude-dependent range bias (study §3.3.1): dark / oblique surfaces read long.

Model: ``bias = k ln(A_white / A)`` [mm], with ``A`` the measured IR amplitude; the study reports a
black surface (about 1/6 of the white amplitude) reading up to 12 mm long, hence
``k = 12 / ln 6 = 6.7 mm``.

What the correction removes is the bias *beyond what the depth calibration already took off*. The
calibration is fitted on a white, fronto-parallel wall, and took off whatever that wall read at
each pixel and range: at a pixel ``theta`` off the axis the wall meets the ray at ``theta`` and
returns ``cos theta`` of what a white surface facing the ray would, so its own bias
(``k ln(1 / cos theta)``, about 1.2 mm at 30 deg for k = 8) is inside the calibration. The
reference ``A_white`` is therefore that wall's amplitude at the same pixel and range: a surface
returning as much as the calibration wall needs no correction (:func:`amplitude_log_ratio`).
Before 2026-12-04 the reference was a white surface facing the ray, and every surface off the axis
was corrected once more by ``k ln(1 / cos theta)``: a bowl, short toward the corners (a dot mat
seen in the lower image read 0.6-1.3 mm shorter than the object, and the views placed on it went up to 1.4 mm
too far).

Per pixel ``a(u, v) = A_wall * range^2 / cos_wall`` is constant (amplitude falls as 1 / range^2 and
with the cosine of the incidence): :func:`white_amplitude_map`, the amplitude of a white surface
facing the ray at 1 m (the photometric albedo's reference), and the wall's ``A_white =
a cos_wall / range^2``. Measuring ``a`` on a wall dataset (files) is
:func:`tofmetry.pipelines.reconstruct.white_map_from_wall`.
"""

from __future__ import annotations

import warnings

import numpy as np

from tofmetry._shared.study_constants import AMPLITUDE_BIAS_MM_PER_LN as PAPER_K_MM_PER_LN
from tofmetry.errors import InputError
from tofmetry.sensor import CameraIntrinsics


def white_amplitude_map(ir_means: list[np.ndarray], depth_means_mm: list[np.ndarray], intr: CameraIntrinsics) -> np.ndarray:
    """Per pixel, the amplitude of a white surface facing the ray at 1 m, ``a(u, v)`` [amplitude * m^2], from wall
    stations (the fronto-parallel wall returns ``a cos_wall / range^2``: :func:`amplitude_log_ratio`).

    Parameters
    ----------
    ir_means : list of (H, W) mean IR amplitude of each station (fronto-parallel white wall)
    depth_means_mm : list of (H, W) mean depth [mm] of the same stations (0 = invalid)
    intr : intrinsics (ray table gives the range and the incidence on a frontal wall)

    Returns
    -------
    (H, W) float64, NaN where no station gives a valid sample.
    """
    if not ir_means or len(ir_means) != len(depth_means_mm):
        raise InputError("amplitude reference: need one IR and one depth mean per wall station")
    rays = intr.ray_table(True)
    norm = np.sqrt(rays[..., 0] ** 2 + rays[..., 1] ** 2 + 1.0)  # |ray| = range / Z = 1 / cos(incidence)
    vals = []
    for ir, z in zip(ir_means, depth_means_mm):
        z = np.asarray(z, np.float64) * 1e-3
        a = np.asarray(ir, np.float64) * (z * norm) ** 2 * norm
        vals.append(np.where((z > 0) & (np.asarray(ir) > 0), a, np.nan))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(np.stack(vals), axis=0)


def amplitude_log_ratio(depth_mm: np.ndarray, ir: np.ndarray, white_map: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:
    """``ln(A_white / A)`` per pixel (dimensionless; 0 where it cannot be formed): the regressor of
    the amplitude bias, how much darker (or more oblique) a pixel is than the depth calibration's
    white fronto-parallel wall at that pixel and range (module docstring: 0 on that wall, whose
    bias the calibration took off).

    Parameters
    ----------
    depth_mm : (H, W) Z [mm]; ir : (H, W) mean amplitude; white_map : from :func:`white_amplitude_map`

    Returns
    -------
    (H, W) float64
    """
    rays = intr.ray_table(True)
    norm = np.sqrt(rays[..., 0] ** 2 + rays[..., 1] ** 2 + 1.0)
    r = np.asarray(depth_mm, np.float64) * 1e-3 * norm
    ok = (r > 0) & np.isfinite(white_map) & (np.asarray(ir) > 0)
    out = np.zeros(r.shape)
    a_white = white_map[ok] / (r[ok] ** 2 * norm[ok])  # the wall at this pixel, ``cos_wall = 1 / norm``
    out[ok] = np.log(a_white / np.asarray(ir, np.float64)[ok])
    return out


def amplitude_bias_mm(depth_mm: np.ndarray, ir: np.ndarray, white_map: np.ndarray, intr: CameraIntrinsics,
                      k_mm_per_ln: float = PAPER_K_MM_PER_LN) -> np.ndarray:
    """Estimated bias ``k ln(A_white / A)`` [mm] per pixel (0 where it cannot be formed).

    Parameters
    ----------
    depth_mm : (H, W) Z [mm]; ir : (H, W) mean amplitude; white_map : from :func:`white_amplitude_map`
    """
    return k_mm_per_ln * amplitude_log_ratio(depth_mm, ir, white_map, intr)
