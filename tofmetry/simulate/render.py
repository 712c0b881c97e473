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
from tofmetry.simulate.scenes import Scene


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


def render(scene: Scene, intr: CameraIntrinsics, pose: np.ndarray, em: E.ErrorModel, supersample: int = 3,
           chunk_rows: int = 53) -> Rendering:
    """Raycast ``scene`` from camera-to-world ``pose`` (4x4, metres).

    Parameters
    ----------
    supersample : int
        Sub-rays per pixel along each axis (>= 1; 4 recommended for checkerboard IR).
    """
    pose = np.asarray(pose, np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise InputError(f"render: pose must be a finite 4x4 camera-to-world matrix, found shape {pose.shape}")
    if supersample < 1:
        raise InputError(f"render: supersample must be >= 1, found {supersample}")
    if scene.smooth:
        supersample = 1  # no edges: sub-pixel rays would all agree
    H, W = intr.shape
    R, o = pose[:3, :3], pose[:3, 3]
    xy = np.asarray(intr.ray_table(True))
    gx_v, gx_u = np.gradient(xy[..., 0])
    gy_v, gy_u = np.gradient(xy[..., 1])
    offs = _sub_offsets(supersample)
    S = offs.shape[0]

    z_c = np.zeros((H, W))
    lab = np.full((H, W), -1, np.int32)
    rb = np.zeros((H, W))
    refl = np.zeros((H, W), bool)
    amp = np.zeros((H, W))
    z_sub_all = np.full((H, W, S), np.nan)
    a_sub_all = np.zeros((H, W, S))
    for r0 in range(0, H, chunk_rows):
        r1 = min(H, r0 + chunk_rows)
        sl = slice(r0, r1)
        xc = xy[sl]
        n = xc.shape[0] * W
        # centre rays
        d = np.concatenate([xc.reshape(-1, 2), np.ones((n, 1))], axis=1)
        h = scene.intersect(o, d @ R.T)
        hit = np.isfinite(h.t)
        z_c[sl] = np.where(hit, h.t * 1e3, 0.0).reshape(-1, W)
        lab[sl] = np.where(hit, h.label, -1).reshape(-1, W)
        rb[sl] = h.refl_bias_mm.reshape(-1, W)
        refl[sl] = h.reflective.reshape(-1, W)
        # sub rays
        sx = (xc[..., 0][..., None] + gx_u[sl][..., None] * offs[:, 0] + gx_v[sl][..., None] * offs[:, 1])
        sy = (xc[..., 1][..., None] + gy_u[sl][..., None] * offs[:, 0] + gy_v[sl][..., None] * offs[:, 1])
        ds = np.stack([sx.ravel(), sy.ravel(), np.ones(sx.size)], axis=1)
        hs = scene.intersect(o, ds @ R.T)
        ok = np.isfinite(hs.t)
        rng_m = np.where(ok, hs.t * np.sqrt(sx.ravel() ** 2 + sy.ravel() ** 2 + 1.0), 1.0)
        sxy = np.stack([sx.ravel(), sy.ravel()], axis=1)
        a = np.where(ok, E.amplitude(hs.albedo, hs.cos_inc, sxy, rng_m, em), 0.0)
        z_sub_all[sl] = np.where(ok, hs.t * 1e3, np.nan).reshape(-1, W, S)
        a_sub_all[sl] = a.reshape(-1, W, S)
        amp[sl] = a.reshape(-1, W, S).mean(axis=2)

    with np.errstate(invalid="ignore"):
        any_hit = np.isfinite(z_sub_all).any(axis=2)
        zmax = np.where(any_hit, np.nanmax(np.where(np.isfinite(z_sub_all), z_sub_all, -np.inf), axis=2), 0.0)
        zmin = np.where(any_hit, np.nanmin(np.where(np.isfinite(z_sub_all), z_sub_all, np.inf), axis=2), 0.0)
    mixed = any_hit & ((zmax - zmin) > em.flying_gap_mm)
    wsum = a_sub_all.sum(axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        zmean = np.nansum(a_sub_all * np.nan_to_num(z_sub_all), axis=2) / wsum
    depth0 = np.where(z_c > 0, z_c, np.where(wsum > 0, zmean, 0.0))
    depth0 = np.nan_to_num(depth0)
    rng_c = depth0 * 1e-3 * np.sqrt(1.0 + xy[..., 0] ** 2 + xy[..., 1] ** 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(depth0 > 0, amp / E.white_amplitude(xy, np.where(depth0 > 0, rng_c, 1.0), em), 0.0)
    midx = np.flatnonzero(mixed)
    return Rendering(
        true_depth=z_c, depth0=depth0, amplitude=amp, rel_reflectance=np.nan_to_num(rel), labels=lab,
        refl_bias_mm=rb, reflective=refl, mixed=mixed, mixed_idx=midx,
        mixed_z=z_sub_all.reshape(-1, S)[midx], mixed_a=a_sub_all.reshape(-1, S)[midx], xy=xy,
    )
