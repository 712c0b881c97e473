"""The mat's range error from its dots' size: synthetic placements whose truth is known."""

import numpy as np
import pytest

from tofmetry.reconstruct._mat_locate import MatFix
from tofmetry.reconstruct._mat_range import moved_along_sight, range_offset


def _fix(camera: np.ndarray, centre_xy, scale: float, sigma: float, n: int = 20) -> MatFix:
    T = np.eye(4)
    T[:3, 3] = camera
    return MatFix(True, camera_to_mat=T, n_matched=n, n_dots=n, how="dots", pattern_scale=scale,
                  pattern_scale_sigma=sigma, centre_xy=np.asarray(centre_xy, float))


def _ring(delta_m: float, sigma: float = 2e-4, noise: bool = False, rng=None):
    """Eight cameras on a ring 0.7 m out and 0.3 m up, each placed ``delta_m`` too far back along its
    line of sight to its dots (as a mat read too far puts them), its dots ``delta / D`` too large."""
    fixes, truth = [], []
    for k in range(8):
        a = 2 * np.pi * k / 8
        c = np.array([0.05 * np.cos(a), 0.05 * np.sin(a), 0.0])  # the dots' centroid, toward the camera
        cam = np.array([0.7 * np.cos(a), 0.7 * np.sin(a), 0.3])
        D = np.linalg.norm(cam - c)
        u = (cam - c) / D
        e = delta_m / D + (rng.normal(0, sigma) if noise else 0.0)
        fixes.append(_fix(cam + delta_m * u, c[:2], e, sigma))
        truth.append(cam)
    return fixes, np.array(truth)


def test_a_common_range_error_is_read_from_the_dots_and_taken_out_of_every_placement():
    fixes, truth = _ring(0.8e-3)
    r = range_offset(fixes)
    # the distance is the placed one, delta too long: the estimate is off by delta / D of itself (0.1 %)
    assert r["delta_mm"] == pytest.approx(0.8, rel=2e-3) and r["views"] == 8
    moved = [moved_along_sight(f, r["delta_mm"]) for f in fixes]
    err = np.array([m.camera_to_mat[:3, 3] for m in moved]) - truth
    assert np.abs(err).max() < 2e-6  # the same line of sight back: within a micrometre of where it was taken
    assert all(np.allclose(m.camera_to_mat[:3, :3], np.eye(3)) for m in moved)


def test_the_dots_noise_sets_the_sigma():
    """Eight views with 0.02 % of noise on each dot scale, at about 0.78 m: the common value is known
    to about 0.2 % x 0.78 m / sqrt(8) = 0.055 mm; over 200 draws the estimates scatter as their sigma says."""
    rng = np.random.default_rng(3)
    est, sig = [], []
    for _ in range(200):
        r = range_offset(_ring(-0.5e-3, sigma=2e-4, noise=True, rng=rng)[0])
        est.append(r["delta_mm"])
        sig.append(r["sigma_mm"])
    z = (np.array(est) + 0.5) / np.array(sig)
    assert abs(np.mean(est) + 0.5) < 3 * np.std(est) / np.sqrt(200)
    assert 0.8 < np.std(z) < 1.3  # the sigma (widened only by excess scatter) holds
    assert 0.04 < np.median(sig) < 0.07


def test_a_range_error_within_its_noise_is_not_significant():
    """No range error, 0.02 % of noise on each view's dot scale: over 200 draws the estimate is called
    significant (and would move the placements) about as often as 3 sigma allows (0.27 %)."""
    rng = np.random.default_rng(5)
    hits = sum(range_offset(_ring(0.0, sigma=2e-4, noise=True, rng=rng)[0])["significant"] for _ in range(200))
    assert hits <= 3


def test_too_few_views_with_dots_give_nothing():
    fixes, _ = _ring(1e-3)
    assert range_offset(fixes[:1]) is None
    few = [MatFix(True, n_matched=3, how="dots", pattern_scale=0.001, pattern_scale_sigma=1e-4)] * 3
    assert range_offset(few, min_dots=6) is None
    unplaced = MatFix(False, reason="no dots")
    assert moved_along_sight(unplaced, 1.0) is unplaced
