"""Flying-pixel (mixed-pixel) detector and filter.

A *flying pixel* is a depth sample that lies on no surface: at a depth edge the pixel
footprint straddles a foreground and a background surface, and the time-of-flight phase
mixes both returns into a value somewhere between them (or, in strong ambient light, a
sample is sprayed at a random range). In 3D such a sample floats alone along its viewing
ray. The detector therefore asks, for every valid pixel, two questions in its 3x3
neighbourhood:

1. *Discontinuity*: does at least one valid neighbour differ in depth by more than the
   continuity threshold ``tau(Z)``?  (otherwise the pixel lies on a smooth surface)
2. *Isolation along the ray*: are at most ``max_support`` (1) neighbours within
   ``tau(Z)`` of it?  A pixel on a real surface, even at its border, is supported by >= 2
   neighbours of the same surface (>= 3 at a corner, 2 on a 1-pixel-wide line); a mixed
   pixel sits between two surfaces and is supported by none of them -- or, along a
   straight edge, by up to ``max_support_between`` (2) mixed neighbours of similar value.
   Such a pixel is flying only if it lies *between* its discontinuous neighbours: one of
   them nearer than ``Z - tau`` and one farther than ``Z + tau`` or invalid (a silhouette
   against a background that returned nothing). A real edge pixel has
   discontinuous neighbours on one side only (all farther for the foreground, all nearer
   for the background), and a 1-pixel-wide line has background on both sides.

A valid pixel whose 8 neighbours are all invalid is also reported (``flag_lonely``): it
has no surface to belong to (typical of the sparse sun-light spray).

The continuity threshold has a physical meaning and scales with depth::

    tau(Z) = k_noise * sqrt(2) * sigma(Z)  +  Z * step / f * tan(theta_max)
             `-- two noisy samples -----'    `-- surface slope across a pixel --'

with ``sigma`` the temporal noise: from the IR amplitude when given (shot noise,
``sigma = sigma_1m_mm * sqrt(amp_ref / A)``, ``amp_ref`` = 12 000 = white at 1 m, study
§3.3.1), else ``sigma_1m_mm * Z / 1 m`` (the amplitude of a given surface falls as 1/Z^2), ``step`` the pixel distance to the neighbour
(1 or sqrt 2), ``f`` the focal length [px] and ``theta_max`` the steepest incidence
angle still regarded as one continuous surface. With the defaults (1.5 mm, k = 3,
60 deg, f = 365 px) ``tau`` is about 11 mm at 1 m and 32 mm at 3 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics

_OFFSETS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


@dataclass(frozen=True)
class FlyingPixelParams:
    """Thresholds of :func:`detect_flying_pixels` (see the module docstring).

    Attributes
    ----------
    sigma_1m_mm : float
        Temporal depth noise at 1 m [mm]; scaled linearly with Z.
    k_noise : float
        Number of noise sigmas a difference of two samples may reach on one surface.
    theta_max_deg : float
        Steepest incidence angle [deg] still treated as a continuous surface.
    max_support : int
        A pixel with at most this many neighbours within ``tau`` (and a discontinuity)
        is flying.
    flag_lonely : bool
        Also flag valid pixels with no valid neighbour at all.
    """

    sigma_1m_mm: float = 1.5
    k_noise: float = 3.0
    theta_max_deg: float = 60.0
    max_support: int = 1
    max_support_between: int = 2
    flag_lonely: bool = True
    amp_ref: float = 12_000.0

    def sigma_mm(self, z_mm: np.ndarray, ir: np.ndarray | None = None) -> np.ndarray:
        """Temporal noise sigma [mm] per pixel: from the IR amplitude if given, else from Z."""
        if ir is not None:
            a = np.maximum(np.asarray(ir, dtype=np.float64), 1.0)
            return self.sigma_1m_mm * np.sqrt(self.amp_ref / a)
        return self.sigma_1m_mm * np.asarray(z_mm, dtype=np.float64) / 1000.0

    def tau_mm(self, z_mm: np.ndarray, focal_px: float, step_px: float = 1.0,
               ir: np.ndarray | None = None) -> np.ndarray:
        """Continuity threshold [mm] for depth ``z_mm`` and a neighbour ``step_px`` away."""
        z = np.asarray(z_mm, dtype=np.float64)
        noise = self.k_noise * math.sqrt(2.0) * self.sigma_mm(z, ir)
        slope = z * step_px / focal_px * math.tan(math.radians(self.theta_max_deg))
        return noise + slope

    def to_dict(self) -> dict:
        return {"sigma_1m_mm": self.sigma_1m_mm, "k_noise": self.k_noise, "theta_max_deg": self.theta_max_deg,
                "max_support": self.max_support, "max_support_between": self.max_support_between,
                "flag_lonely": self.flag_lonely, "amp_ref": self.amp_ref}


def _validate(depth: np.ndarray, intr: CameraIntrinsics | None) -> np.ndarray:
    d = np.asarray(depth)
    if d.ndim != 2:
        raise InputError(f"depth: expected an (H, W) depth map [mm], found shape {d.shape}")
    if intr is not None and d.shape != intr.shape:
        raise InputError(f"depth: shape {d.shape} does not match the intrinsics {intr.height}x{intr.width} (H, W)")
    z = d.astype(np.float64)
    z[~np.isfinite(z)] = 0.0
    return z


def neighbour_support(depth: np.ndarray, intr: CameraIntrinsics | None = None,
                      params: FlyingPixelParams = FlyingPixelParams(), ir: np.ndarray | None = None):
    """Counts of the 3x3 neighbourhood used by the detector.

    Parameters
    ----------
    depth : (H, W) uint16 or float [mm], 0/NaN = invalid
    intr : CameraIntrinsics or None (focal length; Kinect v2's 365 px if None)
    ir : (H, W) IR amplitude or None (noise from amplitude instead of depth)

    Returns
    -------
    n_valid : (H, W) int8, valid neighbours
    n_support : (H, W) int8, valid neighbours within ``tau(Z)``
    n_jump : (H, W) int8, valid neighbours differing by more than ``tau(Z)``
    between : (H, W) bool, a neighbour nearer than Z - tau and one farther than Z + tau (or invalid)
    """
    z = _validate(depth, intr)
    f = 365.0 if intr is None else 0.5 * (intr.fx + intr.fy)
    h, w = z.shape
    zp = np.pad(z, 1)
    valid = z > 0
    n_valid = np.zeros((h, w), np.int8)
    n_sup = np.zeros((h, w), np.int8)
    nearer = np.zeros((h, w), bool)
    farther = np.zeros((h, w), bool)
    if ir is not None and np.shape(ir) != z.shape:
        raise InputError(f"ir: shape {np.shape(ir)} differs from the depth shape {z.shape}")
    tau1 = params.tau_mm(z, f, 1.0, ir)
    tau2 = params.tau_mm(z, f, math.sqrt(2.0), ir)
    for dv, du in _OFFSETS:
        zn = zp[1 + dv:1 + dv + h, 1 + du:1 + du + w]
        ok = valid & (zn > 0)
        tau = tau2 if (dv and du) else tau1
        n_valid += ok
        diff = zn - z
        n_sup += ok & (np.abs(diff) <= tau)
        nearer |= ok & (diff < -tau)
        farther |= ok & (diff > tau)
    # a neighbour without a return (invalid: beyond range, too dark) counts as "farther":
    # a mixed pixel on a silhouette against the empty background straddles the object and
    # a surface that gave no measurement
    open_side = valid & (n_valid < 8)
    return n_valid, n_sup, (n_valid - n_sup).astype(np.int8), nearer & (farther | open_side)


def detect_flying_pixels(depth: np.ndarray, intr: CameraIntrinsics | None = None,
                         params: FlyingPixelParams | None = None, ir: np.ndarray | None = None,
                         **overrides) -> np.ndarray:
    """Flag flying (mixed) pixels of one depth frame.

    Parameters
    ----------
    depth : (H, W) uint16 or float [mm]
        Z depth, 0/NaN = invalid.
    intr : CameraIntrinsics, optional
        Of the depth camera (only its focal length is used).
    params : FlyingPixelParams, optional
        Thresholds; keyword ``overrides`` (e.g. ``sigma_1m_mm=3``) replace single fields.
    ir : (H, W) IR amplitude of the same frame, optional
        Scales the noise term per pixel (dark or far surfaces are noisier).

    Returns
    -------
    (H, W) bool, True on flying pixels (always False on invalid pixels).
    """
    p = params or FlyingPixelParams()
    if overrides:
        unknown = set(overrides) - set(p.to_dict())
        if unknown:
            raise InputError(f"detect_flying_pixels: unknown parameter(s) {sorted(unknown)}; known: {sorted(p.to_dict())}")
        p = FlyingPixelParams(**{**p.to_dict(), **overrides})
    n_valid, n_sup, n_jump, between = neighbour_support(depth, intr, p, ir)
    valid = _validate(depth, intr) > 0
    flying = valid & (n_jump > 0) & ((n_sup <= p.max_support) | (between & (n_sup <= p.max_support_between)))
    if p.flag_lonely:
        flying |= valid & (n_valid == 0)
    return flying


def remove_flying_pixels(depth: np.ndarray, intr: CameraIntrinsics | None = None,
                         params: FlyingPixelParams | None = None, ir: np.ndarray | None = None,
                         **overrides) -> np.ndarray:
    """Copy of ``depth`` (same dtype) with the flying pixels of :func:`detect_flying_pixels` set to 0."""
    mask = detect_flying_pixels(depth, intr, params, ir, **overrides)
    out = np.array(depth, copy=True)
    out[mask] = 0
    return out
