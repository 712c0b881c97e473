"""Kernel-ready lookup tables of a depth calibration (built once per calibration).

The kernels of :mod:`._apply` (depth -> corrected depth) and :mod:`._backproject` (depth ->
points) evaluate :meth:`DepthCalibration.correction` exactly through these tables; the numpy
definition there is the reference the tests hold them to.

Per integer depth ``d`` [mm], one 16-byte entry of ``lut`` (a float32 and an int32 view):

* ``lut_f[4 d]``     = ``d - R(dh)`` [mm] (``d - (a + b d)`` under the trend fallback, ``d`` when
  the depth is left unchanged);
* ``lut_i[4 d + 1]`` = ``plane(dh) * H * W``, the offset of the linear-form plane of ``dh``'s
  node interval (the identity plane when no surface term applies);
* ``lut_f[4 d + 2]`` = ``dh`` [mm], the depth the model is evaluated at: ``d`` inside the
  calibration's overall supported range, the nearest end of it under the hold fallback;
* ``lut_f[4 d + 3]`` = ``dh**gamma`` where the ray term applies, else 0 (see below).

Per-pixel linear form of the surface term: on each interval between two nodes
``S(p, d) = a[k, p] + b[k, p] d`` exactly; ``coef`` holds the pairs ``(b, a)`` plane by plane
(pixel-minor): planes ``0`` (below the first node), ``1 .. K-1`` (between nodes), ``K`` (above
the last) and ``K + 1`` (identity, zero).

Ray term ``W(dh rho) / rho**gamma`` (when the calibration has one), written with the ray length
``q = dh rho`` as ``dh**gamma V(q)``, ``V(q) = W(q) / q**gamma``: ``ray_w`` holds ``(V, dV/dq)`` at
every mm of ray length from ``ray_q0`` over every ray length the kernels can meet (linear
interpolation: error below ``h^2/8 max|V''|``, about 1e-4 mm for any wiggle of period above
0.3 m), and ``pix_rho`` holds ``rho`` per pixel: one float per pixel, no per-pixel power.

The corrected depth of pixel ``p`` is then
``lut_f[4d] - (b dh + a) - lut_f[4d+3] * V(dh rho)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tofmetry.errors import InputError

if TYPE_CHECKING:
    from tofmetry.calibrate._model import DepthCalibration


@dataclass(frozen=True)
class CorrectionTables:
    """See the module docstring. All arrays flat, C-contiguous.

    Attributes
    ----------
    lut_f, lut_i : (262144,) float32 / int32 views of one buffer of 16-byte entries
    coef : (2 (K + 2) H W,) float32 ``(b, a)`` pairs
    has_ray : bool
    ray_w : (2 n,) float32 ``(V, dV/dq)`` per mm of ray length (zeros when no ray term)
    ray_q0 : float, ray length [mm] of the first entry
    ray_tmax : float32, the last index of ``ray_w``'s entries as a float (the clamp)
    pix_rho : (H W,) float32 ``rho`` per pixel
    """

    lut_f: np.ndarray
    lut_i: np.ndarray
    coef: np.ndarray
    has_ray: bool
    ray_w: np.ndarray
    ray_q0: float
    pix_rho: np.ndarray

    @property
    def ray_tmax(self) -> np.float32:
        return np.float32(len(self.ray_w) // 2 - 1)


def _linear_form(cal: "DepthCalibration") -> np.ndarray:
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
    return coef


def build_tables(cal: "DepthCalibration") -> CorrectionTables:
    """Tables of ``cal`` (see the module docstring)."""
    d = np.arange(65536, dtype=np.float64)
    kk = len(cal.node_mm)
    npix = cal.shape[0] * cal.shape[1]
    lo, hi = cal.support_range_mm
    in_range = (d >= lo) & (d <= hi) & (d > 0)
    fb = cal.fallback
    if fb == "hold":
        dh = np.where(d > 0, np.clip(d, lo, hi), 0.0)
        applies = d > 0
    else:
        dh = d.copy()
        applies = in_range
    lane0 = np.where(applies, d - cal.range_error(dh), d)
    if fb == "trend":
        a, b = cal.trend_mm
        lane0 = np.where(~in_range & (d > 0), d - (a + b * d), lane0)
    plane = np.where(applies, np.searchsorted(cal.node_mm, dh, side="right"), kk + 1)
    lut = np.zeros((65536, 4), np.float32)
    lut[:, 0] = lane0
    lut[:, 2] = dh
    lut[:, 3] = np.where(applies, dh ** cal.ray_gamma, 0.0) if cal.ray_knots is not None else 0.0
    lut_i = lut.view(np.int32)
    lut_i[:, 1] = plane * npix
    coef = _linear_form(cal)
    rho = cal.rho.reshape(-1)
    pix = rho.astype(np.float32)
    if cal.ray_knots is not None:
        # every ray length the kernels can meet: dh over [1, 65535] where the term applies
        dh_on = dh[applies & (d > 0)]
        q_lo = min(float(cal.ray_data_mm[0]), float(dh_on.min()) * float(rho.min()))
        q_hi = max(float(cal.ray_data_mm[1]), float(dh_on.max()) * float(rho.max()))
        q0 = float(np.floor(q_lo))
        q = np.arange(q0, np.ceil(q_hi) + 2.0)
        vv = cal.ray_error(q) / q ** cal.ray_gamma
        ray = np.zeros((len(q), 2), np.float32)
        ray[:, 0] = vv
        ray[:-1, 1] = np.diff(vv)  # the last entry's slope is 0: the clamp lands exactly on it
    else:
        q0, ray = 0.0, np.zeros((2, 2), np.float32)
    return CorrectionTables(lut_f=lut.reshape(-1), lut_i=lut_i.reshape(-1), coef=coef.reshape(-1),
                            has_ray=cal.ray_knots is not None, ray_w=ray.reshape(-1), ray_q0=q0,
                            pix_rho=pix.reshape(-1))
