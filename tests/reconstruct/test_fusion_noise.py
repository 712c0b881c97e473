"""Fusion of noisy depth: the projective TSDF's truncation must not pull surfaces into the object."""

from __future__ import annotations

import numpy as np

from tofmetry.reconstruct import TSDFFusion
from tofmetry.reconstruct._preprocess import denoise_depth, mean_standard_error
from tofmetry.sensor import KINECT_V2

INTR = KINECT_V2.depth
RAYS = np.dstack([INTR.ray_table(True), np.ones(INTR.shape)])  # (x, y, 1) of each (distorted) pixel


def look_at(cam: np.ndarray) -> np.ndarray:
    """Camera-to-world pose at ``cam`` [m] looking at the origin, z up in the world."""
    z = -cam / np.linalg.norm(cam)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.c_[x, np.cross(z, x), z]
    T[:3, 3] = cam
    return T


def sphere_depth(T: np.ndarray, radius: float) -> np.ndarray:
    """Z [mm] of a sphere of ``radius`` [m] at the world origin seen from pose ``T``; 0 off it."""
    c = np.linalg.inv(T)[:3, 3]
    a = np.sum(RAYS ** 2, -1)
    b = -2 * RAYS @ c
    disc = b * b - 4 * a * (c @ c - radius * radius)
    return np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a) * 1e3, 0.0)


def fused_radius_error_mm(sigma_mm: float, denoise: bool, radius: float = 0.1) -> float:
    """Median radius error [mm] of a sphere fused from 8 views at 0.7 m with depth noise ``sigma_mm``."""
    rng = np.random.default_rng(3)
    f = TSDFFusion(INTR, voxel_mm=1.0, trunc_mm=3.8)  # the family's rule at 0.65 m
    for k in range(8):
        a = 2 * np.pi * k / 8
        T = look_at(0.7 * np.array([np.cos(a), np.sin(a), 0.35]))
        z = sphere_depth(T, radius)
        z = np.where(z > 0, z + rng.normal(0.0, sigma_mm, z.shape), 0.0)
        if denoise:
            z = denoise_depth(z, 3.0 * sigma_mm)
        f.integrate(z, T)
    V = f.extract(1.0)[0]
    return float(np.median(np.linalg.norm(V, axis=1)) - radius) * 1e3


def test_noisy_views_fuse_inside_the_surface_without_smoothing_and_on_it_with():
    """The standard error of a pixel's 5-frame mean near the minimum range is ~2 mm (the family's
    simulated slab at 0.65 m: 1.3-3.1 mm), half the truncation. Open3D skips observations more than
    the truncation behind the surface and keeps those in front, so the noise biases the voxels
    inside positive: per observation about sigma phi(a) / Phi(a) with a = trunc / sigma = 1.9, 0.14
    mm. The fused sphere shrinks by that much (measured 0.18 mm). Smoothed over each pixel and its 4
    neighbours first, the noise drops about 2-fold, a ~ 4, and the bias to a few hundredths of a
    millimetre; the filter's own sag on a 0.1 m sphere is 0.01 mm."""
    raw = fused_radius_error_mm(2.0, denoise=False)
    smooth = fused_radius_error_mm(2.0, denoise=True)
    assert raw < -0.1, raw
    assert abs(smooth) < 0.06, smooth


def test_denoise_keeps_depth_jumps_and_invalid_pixels():
    """A step of 50 mm between two noisy planes: each side keeps its level (the other side gets no
    weight at 3 sigma of range), the noise drops, and invalid pixels stay 0."""
    rng = np.random.default_rng(0)
    z = np.full((60, 80), 700.0)
    z[:, 40:] = 750.0
    z += rng.normal(0.0, 2.0, z.shape)
    z[10:15, 10:15] = 0.0
    out = denoise_depth(z, 6.0)
    assert np.all(out[10:15, 10:15] == 0)
    left, right = out[20:, 2:39], out[20:, 41:78]
    assert abs(np.mean(left) - 700.0) < 0.1 and abs(np.mean(right) - 750.0) < 0.1
    assert np.std(left) < 0.6 * 2.0 and np.std(right) < 0.6 * 2.0
    assert np.array_equal(denoise_depth(z, 0.0), z.astype(np.float32))


def test_mean_standard_error_of_the_frames():
    """Frames of a pixel with noise sigma: the standard error of their mean is sigma / sqrt(T). The
    sample variance is unbiased, so the RMS over 20 000 pixels is sqrt(sigma^2 + 1/12) / sqrt(T)
    (the 1/12 mm^2 of rounding to whole mm), within its sampling spread (0.2 %); a pixel valid in
    one frame only has none (NaN)."""
    rng = np.random.default_rng(1)
    stack = np.rint(800.0 + rng.normal(0.0, 4.0, (8, 100, 200))).astype(np.uint16)
    stack[1:, 0, 0] = 0
    se = mean_standard_error(stack)
    assert np.isnan(se[0, 0])
    assert abs(np.sqrt(np.nanmean(se.astype(np.float64) ** 2)) - np.sqrt(16.0 + 1 / 12) / np.sqrt(8)) < 0.015


def test_prepare_view_smooths_the_depth_every_stage_uses():
    """A tilted wall at 0.7 m, 5 frames of 4 mm noise: with ``preprocess.denoise`` the view's points
    scatter about the wall about twice less (OpenCV's 3-px window is the pixel and its 4 neighbours,
    weighted 0.8 by the spatial sigma of 1.5 px and ~0.9 by the range sigma of 3 standard errors:
    (1 + 4 w)^2 / (1 + 4 w^2) = 4.4 effective samples, 2.1 times less noise), the standard error the
    view was smoothed with is recorded (4 / sqrt(5) = 1.8 mm), and fusion does not smooth it again."""
    from tofmetry.reconstruct import PreprocessConfig, ReconstructionConfig
    from tofmetry.reconstruct._model_build import fusion_depth
    from tofmetry.reconstruct._preprocess import prepare_view

    n = np.array([0.0, -0.3, 1.0]) / np.linalg.norm([0.0, -0.3, 1.0])
    rays = RAYS / RAYS[..., 2:]
    z = 0.7 / (rays @ n) * 1e3  # Z [mm] of the plane n . p = 0.7 m
    rng = np.random.default_rng(2)
    stack = np.rint(z[None] + rng.normal(0.0, 4.0, (5, *z.shape))).astype(np.uint16)
    spread = {}
    for on in (False, True):
        v = prepare_view(stack, INTR, config=PreprocessConfig(denoise=on, remove_flying=False, max_incidence_deg=89.0))
        spread[on] = float(np.std(v.points @ n - 0.7)) * 1e3
        smoothed = v.stats["denoised_with_standard_error_mm"]
        assert (smoothed is None) is (not on)
    assert spread[True] < spread[False] / 1.8, spread
    assert abs(smoothed - 4.0 / np.sqrt(5)) < 0.15
    seg = type("Seg", (), {"object_mask": np.ones(len(v.points), bool), "ring_mask": np.zeros(len(v.points), bool)})()
    d = fusion_depth(v, seg, ReconstructionConfig())
    assert np.array_equal(d[d > 0], v.depth_mm[d > 0])
