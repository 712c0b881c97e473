"""Static rendering of a scene for one camera pose (done once per pose).

Rays go through every pixel of the *distorted* image: the undistorted ray table gives the
normalised ``(x, y)`` and the camera-frame direction is ``(x, y, 1)``, so the hit parameter
of a ray is directly its depth Z. Each pixel is also supersampled with ``n x n`` sub-pixel rays
(an n-rooks pattern, :func:`_sub_offsets`, placed through the local Jacobian of the ray table) to anti-alias the IR amplitude and to find mixed
("flying") pixels at depth discontinuities.

A bare wall (:func:`tofmetry.simulate.scenes.wall`: one infinite, uniform plane) takes an
analytic path, :func:`render_wall`: the same arithmetic as the ray cast, element for element
(so the same :class:`Rendering`, bit for bit; ``tests/simulate`` checks it), without the generic
machinery, and with the per-lens ray quantities cached. It is about 5-10x cheaper.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import ndtr

from tofmetry._shared.geometry import ray_factor
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
    rel_reflectance : (H, W) float64, amplitude / amplitude of a white surface facing the ray at that range.
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


def _sub_offsets(n: int, pixels: np.ndarray, blur_px: float = 0.0) -> np.ndarray:
    """Sub-pixel ray offsets of each pixel, ``n x n`` per pixel: (E, n*n, 2) [px].

    The ``S = n*n`` sub-rays of a pixel sample the pixel's footprint: its area (a unit box)
    convolved with the lens's point spread (a Gaussian of sigma ``blur_px`` [px]), a separable
    density. They are placed as an n-rooks ("Latin hypercube") pattern of that density: the ``S``
    quantiles ``(k + 1/2) / S`` of its marginal in u, paired with the same quantiles in v by a
    permutation drawn per pixel from a hash of its index (deterministic, independent of which
    other pixels are sampled). A regular ``n x n`` grid would sense an edge parallel to the pixel
    rows or columns in steps of ``1/n`` px only, so every pixel along a straight, axis-aligned
    board edge would carry the same aliasing error (up to ``1/(2n)`` px, coherent along the edge:
    a bias no corner fit averages out). Here an axis-aligned edge is sensed in steps of ``1/S``
    of the footprint, and the error of a slanted edge changes from pixel to pixel.
    """
    S = n * n
    o = _footprint_quantiles(S, float(blur_px))
    k = np.asarray(pixels, np.uint64)[:, None] * np.uint64(S) + np.arange(S, dtype=np.uint64)[None, :]
    perm = np.argsort(_splitmix64(k), axis=1)
    return np.stack([np.broadcast_to(o, perm.shape), o[perm]], axis=-1)


@lru_cache(maxsize=16)
def _footprint_quantiles(S: int, blur_px: float) -> np.ndarray:
    """(S,) quantiles ``(k + 1/2) / S`` [px] of a unit box convolved with a Gaussian of sigma ``blur_px``."""
    p = (np.arange(S) + 0.5) / S
    if blur_px <= 0:
        return p - 0.5
    t = np.linspace(-0.5 - 6 * blur_px, 0.5 + 6 * blur_px, 4001)

    def g1(x):                          # antiderivative of the Gaussian CDF Phi(x / blur)
        return x * ndtr(x / blur_px) + blur_px * np.exp(-0.5 * (x / blur_px) ** 2) / np.sqrt(2 * np.pi)

    cdf = g1(t + 0.5) - g1(t - 0.5)
    return np.interp(p, cdf, t)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser of uint64 keys: a well-mixed deterministic hash (same shape, uint64)."""
    with np.errstate(over="ignore"):
        z = x + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


#: Rays per chunk of the ray cast (the analytic wall path uses the same chunks).
CHUNK = 1 << 17


def _cast(scene: Scene, R: np.ndarray, o: np.ndarray, sx: np.ndarray, sy: np.ndarray, em: E.ErrorModel,
          chunk: int = CHUNK):
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


def render(scene: Scene, intr: CameraIntrinsics, pose: np.ndarray, em: E.ErrorModel, supersample: int = 3,
           analytic_wall: bool = True) -> Rendering:
    """Raycast ``scene`` from camera-to-world ``pose`` (4x4, metres).

    A bare wall goes through :func:`render_wall` (same result, cheaper) unless
    ``analytic_wall`` is False. Otherwise one ray per pixel centre first; pixels whose 3x3 neighbourhood shows an edge (label,
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
    if analytic_wall and is_bare_wall(scene):
        return render_wall(scene, intr, pose, em, supersample)
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
    xe, ye = xy[..., 0].ravel()[eidx], xy[..., 1].ravel()[eidx]
    jac = (gx_u.ravel()[eidx][:, None], gx_v.ravel()[eidx][:, None], gy_u.ravel()[eidx][:, None],
           gy_v.ravel()[eidx][:, None])

    def sub_rays(blur_px: float):
        offs = _sub_offsets(supersample, eidx, blur_px)
        du, dv = offs[..., 0], offs[..., 1]
        sx = xe[:, None] + jac[0] * du + jac[1] * dv
        sy = ye[:, None] + jac[2] * du + jac[3] * dv
        z_, a_, _, _, _ = _cast(scene, R, o, sx.ravel(), sy.ravel(), em)
        return z_.reshape(-1, S), a_.reshape(-1, S)

    # the depth of a mixed pixel from its area (the flying-pixel model as matched to the study, §3.3.2);
    # the IR image through the lens's point spread as well (the edge width of a real Kinect's IR)
    zs, as_ = sub_rays(0.0)
    amp.reshape(-1)[eidx] = (sub_rays(em.optical_blur_px)[1] if em.optical_blur_px > 0 and eidx.size else as_).mean(axis=1)

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
    rng_c = depth0 * 1e-3 * ray_factor(xy)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(depth0 > 0, amp / E.white_amplitude(xy, np.where(depth0 > 0, rng_c, 1.0), em), 0.0)
    return Rendering(
        true_depth=z_c, depth0=depth0, amplitude=amp, rel_reflectance=np.nan_to_num(rel), labels=lab,
        refl_bias_mm=rb, reflective=refl, mixed=mixed, mixed_idx=eidx[emixed],
        mixed_z=zs[emixed], mixed_a=as_[emixed], xy=xy,
    )


# ---------------------------------------------------------------- analytic wall
def is_bare_wall(scene: Scene) -> bool:
    """Whether ``scene`` is a :func:`~tofmetry.simulate.scenes.wall`: one infinite plane of one albedo."""
    from tofmetry.simulate.surfaces import PlaneSurface

    return (scene.smooth and scene.info.get("type") == "wall" and len(scene.surfaces) == 1
            and isinstance(scene.surfaces[0], PlaneSurface) and scene.surfaces[0].extent is None
            and "albedo" in scene.info)


@lru_cache(maxsize=4)
def _wall_rays(key: tuple, rot: bytes, vignetting_power: float):
    """Per-lens, per-orientation ray quantities of :func:`render_wall` (read-only), computed as in :func:`_cast`."""
    intr = CameraIntrinsics(*key)
    R = np.frombuffer(rot, np.float64).reshape(3, 3)
    xy = np.asarray(intr.ray_table(True))
    xs, ys = xy[..., 0].ravel(), xy[..., 1].ravel()
    n = xs.size
    dirs, norm = np.empty((n, 3)), np.empty(n)
    for k0 in range(0, n, CHUNK):
        k1 = min(n, k0 + CHUNK)
        x, y = xs[k0:k1], ys[k0:k1]
        d = np.stack([x, y, np.ones_like(x)], axis=1) @ R.T
        dirs[k0:k1] = d
        norm[k0:k1] = np.sqrt(np.einsum("ij,ij->i", d, d))
    rho_cast = np.sqrt(xs * xs + ys * ys + 1.0)
    rho = ray_factor(xy)
    vig = (1.0 / rho) ** vignetting_power
    out = (dirs, norm, rho_cast, rho, vig)
    for a in out:
        a.setflags(write=False)
    return out


def render_wall(scene: Scene, intr: CameraIntrinsics, pose: np.ndarray, em: E.ErrorModel,
                supersample: int = 3) -> Rendering:
    """Analytic rendering of a bare wall (:func:`is_bare_wall`), equal to the ray cast of :func:`render`.

    Every quantity is computed with the same floating-point operations as the ray cast
    (plane intersection ``t = ((p0 - o) . n) / (d . n)`` per chunk of rays, amplitude
    ``A_white,1m cos(theta)^p / r^2 (albedo / albedo_white) cos(i)``), so the fields are
    identical; a smooth scene is never supersampled, so ``mixed`` is empty.

    Parameters
    ----------
    scene : Scene, a bare wall; intr : CameraIntrinsics; pose : (4, 4) camera-to-world [m];
    supersample : int, only sets the (empty) ``mixed_z`` / ``mixed_a`` width ``supersample^2``.

    Returns
    -------
    Rendering
    """
    if not is_bare_wall(scene):
        raise InputError(f"render_wall: scene must be a bare wall (scenes.wall), found {scene.name!r}")
    pose = np.asarray(pose, np.float64)
    H, W = intr.shape
    R, o = np.ascontiguousarray(pose[:3, :3]), pose[:3, 3]
    dirs, norm, rho_cast, rho, vig = _wall_rays(intr._key(), R.tobytes(), float(em.vignetting_power))
    surf = scene.surfaces[0]
    nrm = surf.normal
    num = (surf.origin - o) @ nrm
    n = dirs.shape[0]
    dn = np.empty(n)
    for k0 in range(0, n, CHUNK):
        k1 = min(n, k0 + CHUNK)
        dn[k0:k1] = dirs[k0:k1] @ nrm
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / dn
    ok = np.isfinite(t) & (t > 1e-9)
    t = np.where(ok, t, 0.0)
    vig_f = vig.reshape(-1)
    cos_inc = np.where(ok, np.abs(dn) / norm, 0.0)
    rng_m = np.where(ok, t * rho_cast, 1.0)
    wa = em.amp_white_1m * vig_f / np.maximum(rng_m, 1e-3) ** 2
    amp = np.where(ok, wa * (float(scene.info["albedo"]) / em.albedo_white) * np.clip(cos_inc, 0.0, 1.0), 0.0)
    z_c = np.where(ok, t * 1e3, 0.0).reshape(H, W)
    amp = amp.reshape(H, W)
    hit = ok.reshape(H, W)
    rng_c = z_c * 1e-3 * rho
    with np.errstate(invalid="ignore", divide="ignore"):
        wa_c = em.amp_white_1m * vig / np.maximum(np.where(hit, rng_c, 1.0), 1e-3) ** 2
        rel = np.where(hit, amp / wa_c, 0.0)
    S = supersample * supersample
    return Rendering(
        true_depth=z_c, depth0=z_c.copy(), amplitude=amp, rel_reflectance=np.nan_to_num(rel),
        labels=np.where(hit, 1, -1).astype(np.int32), refl_bias_mm=np.zeros((H, W)),
        reflective=np.zeros((H, W), bool), mixed=np.zeros((H, W), bool), mixed_idx=np.zeros(0, np.int64),
        mixed_z=np.zeros((0, S)), mixed_a=np.zeros((0, S)), xy=np.asarray(intr.ray_table(True)),
    )
