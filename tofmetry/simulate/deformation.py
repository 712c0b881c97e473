"""(b) The per-pixel deformation: a surface over the image that scales with range.

``D(x, y, Z) = S(x, y) f(Z) + C(x, y) f_c(Z)`` [mm] added to the Z reading, with ``(x, y)`` the
undistorted normalised ray of the pixel and ``Z`` the true depth:

* ``S`` (:func:`deformation_shape`, at 1 m): today's exponential bowl (negative central disc,
  positive corners, off-centre, elliptic, small skew; paper §4.2.3, Fig. 8), plus optional
  non-radial terms: a tilt-like linear term ``t_x x + t_y y`` (e.g. a row/column dependent
  signal delay, paper §2.3: "a time delay ... as a function of the pixel position"), low-order
  2-D Fourier modes and Gaussian bumps;
* ``f`` (:func:`deformation_scale`): the range dependence, 1 at 1 m: ``"linear"``
  ``(1 - g) + g Z`` (today, g = 0.5), ``"constant"``, ``"decay"`` ``exp(-(Z - 1) / l)``,
  ``"quadratic"`` ``(1 - g) + g Z^2``;
* ``C`` (:func:`corner_shape`): a corner fall-off that is zero over the image except near its
  corners, where it grows steeply, with its own linear or quadratic range growth ``f_c``
  (paper §4.2.3: "more important ... especially on the corners ... increase with the distance").

The image extent enters through ``em.deform_corner_xy``: the normalised ray coordinates
``(|x|, |y|)`` of the image corners (0.77, 0.64 for the typical Kinect v2 lens, mean of the four).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from tofmetry.simulate.errors import ErrorModel

#: Range dependences of the deformation (``ErrorModel.deform_range_kind``).
RANGE_KINDS = ("linear", "constant", "decay", "quadratic")


def deformation_shape(xy: np.ndarray, em: "ErrorModel") -> np.ndarray:
    """(b) Per-pixel deformation pattern ``S`` at 1 m [mm] from normalised rays.

    An exponential bowl in an off-centre, slightly elliptic radius, plus a small skew:
    for the default Kinect v2, negative in a central disc (``deform_centre_mm_1m`` = -2 mm),
    +10.4 .. +15 mm in the four corner 10x10 patches at 1 m (paper Fig. 8: ~1 cm), not
    radially symmetric and not a polynomial. Plus the optional tilt, Fourier modes and bumps
    (module docstring); the corner fall-off is separate (:func:`corner_shape`).

    Parameters
    ----------
    xy : (..., 2) float64
        Undistorted normalised ray coordinates (``intr.ray_table()``).

    Returns
    -------
    (...) float64 [mm] at 1 m.
    """
    x = xy[..., 0] - em.deform_centre_shift[0]
    y = xy[..., 1] - em.deform_centre_shift[1]
    q = ((x * em.deform_aspect) ** 2 + y ** 2) / em.deform_radius ** 2  # ~1 in the Kinect v2 corners
    a = em.deform_sharpness
    span = em.deform_corner_mm_1m - em.deform_centre_mm_1m
    bowl = em.deform_centre_mm_1m + span * (np.exp(a * q) - 1.0) / (math.exp(a) - 1.0)
    skew = em.deform_skew_mm_1m * np.tanh(2.0 * x * y / 0.4)
    s = bowl + skew
    x0, y0 = xy[..., 0], xy[..., 1]
    tx, ty = em.deform_tilt_mm_1m
    if tx != 0.0 or ty != 0.0:
        s = s + tx * x0 + ty * y0
    xc, yc = em.deform_corner_xy
    for amp, kx, ky, phase in em.deform_modes:
        s = s + amp * np.cos(np.pi * (kx * x0 / xc + ky * y0 / yc) + phase)
    for amp, bx, by, sigma in em.deform_bumps:
        s = s + amp * np.exp(-((x0 - bx) ** 2 + (y0 - by) ** 2) / (2.0 * sigma ** 2))
    return s


def corner_shape(xy: np.ndarray, em: "ErrorModel") -> np.ndarray:
    """Corner fall-off ``C`` at 1 m [mm]: ``c max(0, (s - s0) / (1 - s0))^p``.

    ``s = sqrt((x / x_c)^2 + (y / y_c)^2) / sqrt(2)`` is 1 in the image corners and 0.71 in
    the middle of the edges, so with ``s0 >= 0.71`` (``deform_corner_start``) only the corners
    move; ``c`` = ``deform_corner_falloff_mm_1m`` is the value at the corner, ``p`` =
    ``deform_corner_power``.

    Parameters
    ----------
    xy : (..., 2) float64, undistorted normalised rays.

    Returns
    -------
    (...) float64 [mm] at 1 m (zeros when the term is off).
    """
    xy = np.asarray(xy, dtype=np.float64)
    if em.deform_corner_falloff_mm_1m == 0.0:
        return np.zeros(xy.shape[:-1])
    xc, yc = em.deform_corner_xy
    s = np.sqrt((xy[..., 0] / xc) ** 2 + (xy[..., 1] / yc) ** 2) / math.sqrt(2.0)
    s0 = em.deform_corner_start
    return em.deform_corner_falloff_mm_1m * (np.maximum(s - s0, 0.0) / (1.0 - s0)) ** em.deform_corner_power


def deformation_scale(z_mm: np.ndarray, em: "ErrorModel") -> np.ndarray:
    """Range dependence ``f(Z)`` of the deformation, 1 at 1 m (module docstring).

    Default ``"linear"``: ``(1 - g) + g z[m]`` (2 at 3 m for g = 0.5).
    """
    z = np.asarray(z_mm, dtype=np.float64) * 1e-3
    kind, g = em.deform_range_kind, em.deform_range_gain
    if kind == "linear":
        return (1.0 - g) + g * z
    if kind == "constant":
        return np.ones_like(z)
    if kind == "decay":
        return np.exp(-(z - 1.0) / em.deform_range_decay_m)
    return (1.0 - g) + g * z * z  # quadratic


def corner_scale(z_mm: np.ndarray, em: "ErrorModel") -> np.ndarray:
    """Range growth ``f_c(Z)`` of the corner fall-off, 1 at 1 m: ``(1 - g) + g Z^n``
    (``g`` = ``deform_corner_range_gain``, ``n`` = ``deform_corner_range_power``, 1 or 2)."""
    z = np.asarray(z_mm, dtype=np.float64) * 1e-3
    g = em.deform_corner_range_gain
    return (1.0 - g) + g * z ** em.deform_corner_range_power


def deformation_mm(xy: np.ndarray, z_mm: np.ndarray, em: "ErrorModel") -> np.ndarray:
    """(b) Per-pixel surface deformation [mm]: ``S(x, y) f(Z) + C(x, y) f_c(Z)``.

    Parameters
    ----------
    xy : (H, W, 2) float64, undistorted normalised rays; z_mm : (H, W) true depth Z [mm].

    Returns
    -------
    (H, W) float64 [mm].
    """
    d = deformation_shape(xy, em) * deformation_scale(z_mm, em)
    if em.deform_corner_falloff_mm_1m != 0.0:
        d = d + corner_shape(xy, em) * corner_scale(z_mm, em)
    return d
