"""Temporal noise analysis against the simulator's sigma map."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tofmetry.assess import assess_noise, recommend_n, summarize_std_map
from tofmetry.errors import InputError


@pytest.fixture(scope="module")
def noise_frames():
    from tofmetry.simulate import ErrorModel, VirtualKinect, scenes
    from tofmetry.simulate import errors as E

    vk = VirtualKinect(errors=ErrorModel(), seed=11)
    scene = scenes.wall(distance_m=1.15)
    fr = vk.capture(scene, n_frames=100)
    rd = vk.render(scene)
    sigma = E.noise_sigma_mm(rd.amplitude, rd.depth0, vk.errors)
    return fr.depth, sigma


def test_std_maps_match_simulated_sigma(noise_frames):
    depth, sigma = noise_frames
    res = assess_noise(depth)
    assert sorted(res.std_maps) == [10, 25, 50, 100]
    # per-pixel std over 100 frames scatters by 1/sqrt(2*99) = 7 %; its median over the image
    # and the chi-corrected sigma must be within 10 % of the true sigma (+1/12 mm^2 quantisation)
    true = np.sqrt(sigma ** 2 + 1 / 12)
    ratio = np.nanmedian(res.std_maps[100] / true)
    assert abs(ratio - 1) < 0.10
    s100 = res.summaries[-1]
    assert abs(s100.sigma_mm / np.median(true) - 1) < 0.10
    # the simulated noise is higher in the (darker) corners
    assert s100.corner_centre_ratio > 1.3
    # the std map gets more uniform with n; the precision of the mean follows sigma/sqrt(n)
    spreads = [s.spread_mm for s in res.summaries]
    assert spreads == sorted(spreads, reverse=True)
    for b in res.block_precision:
        # chi-square scatter of the block std, pooled robustly over ~200k pixels: a few %
        # (n=50 has only 2 blocks: 1 dof per pixel, allow 10 %)
        assert abs(b["ratio"] - 1) < (0.10 if b["n_blocks"] < 4 else 0.05), b
    assert res.recommended_n in (10, 25, 50, 100)
    assert res.profiles[10].shape == (depth.shape[2],)


def test_fewer_frames_use_available_subsets(noise_frames):
    depth, _ = noise_frames
    res = assess_noise(depth[:30])
    assert sorted(res.std_maps) == [10, 25]
    res = assess_noise(depth[:5])
    assert sorted(res.std_maps) == [5]


def test_less_than_two_frames_is_a_clear_error(noise_frames):
    depth, _ = noise_frames
    with pytest.raises(InputError, match="at least 2 frames"):
        assess_noise(depth[:1])
    with pytest.raises(InputError, match="row"):
        assess_noise(depth[:3], row=10_000)


def test_recommend_n_on_pure_sampling_and_on_structure():
    rng = np.random.default_rng(0)
    flat = [summarize_std_map(np.abs(1.0 + rng.standard_normal((60, 60)) / math.sqrt(2 * (n - 1))), n)
            for n in (10, 25, 50, 100)]
    assert recommend_n(flat)[0] == 100  # pure sampling scatter keeps falling as 1/sqrt(n)
    yy = np.linspace(-1, 1, 60)[:, None]
    pattern = 1.0 + 0.5 * yy ** 2 * np.ones((60, 60))
    structured = [summarize_std_map(pattern * (1 + rng.standard_normal((60, 60)) / math.sqrt(2 * (n - 1))), n)
                  for n in (10, 25, 50, 100)]
    assert recommend_n(structured)[0] < 100
