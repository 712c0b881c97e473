"""Static rendering of a scene for one camera pose (done once per pose).

Rays go through every pixel of the *distorted* image: the undistorted ray table gives the
normalised ``(x, y)`` and the camera-frame direction is ``(x, y, 1)``, so the hit parameter
of a ray is directly its depth Z. Each pixel is also supersampled ``n x n`` (sub-pixel rays
from the local Jacobian of the ray table) to anti-alias the IR amplitude and to find mixed
("flying") pixels at depth discontinuities.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofmetry.errors import InputError
from tofmetry.sensor.intrinsics import CameraIntrinsics
from tofmetry.simulate import errors as E
from tofmetry.simulate.surfaces import Scene


@dataclass
class Rendering:
    """Noise-free rendering of one pose.

    Attributes
    ----------
    true_depth : (H, W) float64 [mm], Z of the centre ray's hit, 0 = no hit.
    depth0 : (H, W) float64 [mm], the depth an ideal sensor delivers (centre hit, or the
        amplitude-weighted sub-pixel mean where the centre ray misses), 0 = nothing.
    amplitude : (H, W) float64, anti-aliased IR amplitude (mean of the sub-pixel amplitudes).
    rel_reflectance : (H, W) float64, amplitude / amplitude of white frontal at that range.
    labels : (H, W) int32, scene label of the centre hit (-1 = no hit).
    refl_bias_mm : (H, W) float64, static extra bias of reflective samples [mm].
    reflective : (H, W) bool.
    mixed : (H, W) bool, pixel straddles surfaces farther apart than ``flying_gap_mm``.
    mixed_idx : (M,) int64 flat indices of mixed pixels; mixed_z, mixed_a : (M, S) sub-pixel
        depths [mm] (NaN = miss) and amplitudes (0 = miss).
    xy : (H, W, 2) normalised rays of the pixel centres.
    """

    true_depth: np.ndarray
    depth0: np.ndarray
    amplitude: np.ndarray
    rel_reflectance: np.ndarray
    labels: np.ndarray
    refl_bias_mm: np.ndarray
    reflective: np.ndarray
    mixed: np.ndarray
    mixed_idx: np.ndarray
    mixed_z: np.ndarray
    mixed_a: np.ndarray
    xy: np.ndarray


def _sub_offsets(n: int) -> np.ndarray:
    o = (np.arange(n) + 0.5) / n - 0.5
    du, dv = np.meshgrid(o, o)
    return np.column_stack([du.ravel(), dv.ravel()])  # (S, 2)


def _cast(scene: Scene, R: np.ndarray, o: np.ndarray, sx: np.ndarray, sy: np.ndarray, em: E.ErrorModel,
          chunk: int = 1 << 17):
    """Cast rays of normalised camera directions (sx, sy) (N,): Z [mm] (NaN = miss), amplitude, hits."""
    n = sx.size
    z = np.full(n, np.nan)
    a = np.zeros(n)
    lab = np.full(n, -1, np.int32)
    rb = np.zeros(n)
    refl = np.zeros(n, bool)
    for k0 in range(0, n, chunk):
        k1 = min(n, k0 + chunk)
        x, y = sx[k0:k1], sy[k0:k1]
        d = np.stack([x, y, np.ones_like(x)], axis=1) @ R.T
        h = scene.intersect(o, d)
        ok = np.isfinite(h.t)
        rng_m = np.where(ok, h.t * np.sqrt(x * x + y * y + 1.0), 1.0)
        z[k0:k1] = np.where(ok, h.t * 1e3, np.nan)
        a[k0:k1] = np.where(ok, E.amplitude(h.albedo, h.cos_inc, np.stack([x, y], 1), rng_m, em), 0.0)
        lab[k0:k1] = np.where(ok, h.label, -1)
        rb[k0:k1] = h.refl_bias_mm
        refl[k0:k1] = h.reflective
    return z, a, lab, rb, refl


def render(scene: Scene, intr: CameraIntrinsics, pose: np.ndarray, em: E.ErrorModel, supersample: int = 3) -> Rendering:
    """Raycast ``scene`` from camera-to-world ``pose`` (4x4, metres).

    One ray per pixel centre first; pixels whose 3x3 neighbourhood shows an edge (label,
    hit/miss, albedo or a depth step > ``flying_gap_mm`` / 2) are then supersampled with
    ``supersample x supersample`` sub-rays (adaptive anti-aliasing; features thinner than
    about one pixel between two pixel centres can be missed).

    Parameters
    ----------
    supersample : int
        Sub-rays per pixel along each axis (>= 1; 4 recommended for checkerboard IR).
    """
    from scipy.ndimage import maximum_filter, minimum_filter

    pose = np.asarray(pose, np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise InputError(f"render: pose must be a finite 4x4 camera-to-world matrix, found shape {pose.shape}")
    if supersample < 1:
        raise InputError(f"render: supersample must be >= 1, found {supersample}")
    H, W = intr.shape
    R, o = pose[:3, :3], pose[:3, 3]
    xy = np.asarray(intr.ray_table(True))
    zc, ac, lab, rb, refl = _cast(scene, R, o, xy[..., 0].ravel(), xy[..., 1].ravel(), em)
    zc, ac, lab, rb, refl = (v.reshape(H, W) for v in (zc, ac, lab, rb, refl))
    hit = np.isfinite(zc)
    z_c = np.where(hit, zc, 0.0)
    amp = ac.copy()
    S = supersample * supersample
    if supersample > 1 and not scene.smooth:
        zf = np.where(hit, zc, -1e9)
        alb = np.where(hit, ac / np.maximum(E.white_amplitude(xy, np.where(hit, zc, 1e3) * 1e-3, em), 1e-12), -1.0)
        edge = (maximum_filter(lab, 3) != minimum_filter(lab, 3))
        edge |= (maximum_filter(zf, 3) - minimum_filter(zf, 3)) > em.flying_gap_mm / 2
        edge |= (maximum_filter(alb, 3) - minimum_filter(alb, 3)) > 0.02
        eidx = np.flatnonzero(edge)
    else:
        eidx = np.zeros(0, np.int64)
    gx_v, gx_u = np.gradient(xy[..., 0])
    gy_v, gy_u = np.gradient(xy[..., 1])
    offs = _sub_offsets(supersample)
    xe, ye = xy[..., 0].ravel()[eidx], xy[..., 1].ravel()[eidx]
    sx = xe[:, None] + gx_u.ravel()[eidx][:, None] * offs[:, 0] + gx_v.ravel()[eidx][:, None] * offs[:, 1]
    sy = ye[:, None] + gy_u.ravel()[eidx][:, None] * offs[:, 0] + gy_v.ravel()[eidx][:, None] * offs[:, 1]
    zs, as_, _, _, _ = _cast(scene, R, o, sx.ravel(), sy.ravel(), em)
    zs, as_ = zs.reshape(-1, S), as_.reshape(-1, S)
    amp.reshape(-1)[eidx] = as_.mean(axis=1)

    depth0 = z_c.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        any_hit = np.isfinite(zs).any(axis=1)
        zmax = np.where(any_hit, np.nanmax(np.where(np.isfinite(zs), zs, -np.inf), axis=1), 0.0)
        zmin = np.where(any_hit, np.nanmin(np.where(np.isfinite(zs), zs, np.inf), axis=1), 0.0)
        wsum = as_.sum(axis=1)
        zmean = (as_ * np.nan_to_num(zs)).sum(axis=1) / wsum
    emixed = any_hit & ((zmax - zmin) > em.flying_gap_mm)
    centre_miss = ~hit.reshape(-1)[eidx] & (wsum > 0)
    depth0.reshape(-1)[eidx[centre_miss]] = zmean[centre_miss]
    mixed = np.zeros((H, W), bool)
    mixed.reshape(-1)[eidx[emixed]] = True
    rng_c = depth0 * 1e-3 * np.sqrt(1.0 + xy[..., 0] ** 2 + xy[..., 1] ** 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(depth0 > 0, amp / E.white_amplitude(xy, np.where(depth0 > 0, rng_c, 1.0), em), 0.0)
    return Rendering(
        true_depth=z_c, depth0=depth0, amplitude=amp, rel_reflectance=np.nan_to_num(rel), labels=lab,
        refl_bias_mm=rb, reflective=refl, mixed=mixed, mixed_idx=eidx[emixed],
        mixed_z=zs[emixed], mixed_a=as_[emixed], xy=xy,
    )
