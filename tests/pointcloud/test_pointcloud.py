"""Depth -> points, colouring through extrinsics, temporal statistics."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.pointcloud import depth_to_points, robust_mean_depth, sample_colors, temporal_stats
from tofmetry.sensor import KINECT_V2, CameraIntrinsics, Extrinsics


def test_depth_to_points_plane_is_exact():
    intr = KINECT_V2.depth
    depth = np.full(intr.shape, 1500, np.uint16)
    depth[0, 0] = 0
    pts, idx = depth_to_points(depth, intr, return_index=True)
    assert len(pts) == intr.width * intr.height - 1 and 0 not in idx
    assert np.allclose(pts[:, 2], 1.5)
    # every point projects back onto its own pixel (with distortion)
    uv = intr.project(pts)
    u, v = idx % intr.width, idx // intr.width
    assert np.abs(uv[:, 0] - u).max() < 1e-6 and np.abs(uv[:, 1] - v).max() < 1e-6


def test_depth_to_points_range_and_shape_check():
    intr = KINECT_V2.depth
    depth = np.full(intr.shape, 400, np.uint16)
    assert len(depth_to_points(depth, intr, min_mm=500)) == 0
    with pytest.raises(InputError, match="shape"):
        depth_to_points(np.zeros((10, 10)), intr)


def test_temporal_stats_ignores_zeros_and_matches_numpy():
    rng = np.random.default_rng(0)
    st = rng.normal(3000.0, 2.0, size=(30, 8, 9)).round().astype(np.uint16)
    st[::3, 0, 0] = 0
    ts = temporal_stats(list(st), median=True)
    ref = st.astype(float)
    ref[ref == 0] = np.nan
    assert np.allclose(ts.mean, np.nanmean(ref, axis=0), atol=1e-9)
    assert np.allclose(ts.std, np.nanstd(ref, axis=0, ddof=1), atol=1e-9)  # shifted sums: no cancellation
    assert ts.count[0, 0] == 20 and ts.count[1, 1] == 30
    assert np.allclose(ts.median, np.nanmedian(ref, axis=0))


def test_robust_mean_rejects_outliers():
    st = np.full((10, 2, 2), 1000, np.uint16)
    st[3, 0, 0] = 1500  # flying sample
    st[4, 0, 0] = 0  # dropout
    m = robust_mean_depth(st)
    assert m[0, 0] == pytest.approx(1000.0)


def test_sample_colors_occlusion_and_out_of_view():
    # identity extrinsics, same camera: a near point hides a far one on the same pixel
    cam = CameraIntrinsics(64, 48, 50, 50, 31.5, 23.5)
    img = np.zeros((48, 64, 3), np.uint8)
    img[..., 0] = 200
    pts = np.array([[0, 0, 1.0], [0, 0, 2.0], [100.0, 0, 1.0]])
    cols, ok = sample_colors(pts, img, cam, Extrinsics.identity())
    assert ok.tolist() == [True, False, False]
    assert cols[0, 0] == 200 and cols[1].sum() == 0


def test_robust_mean_matches_a_nanmedian_reference():
    rng = np.random.default_rng(0)
    st = rng.normal(1000, 2, (7, 30, 40)).round().astype(np.uint16)
    st[rng.random(st.shape) < 0.1] = 0
    st[0, :5] = 3000  # outliers
    x = np.where(st > 0, st.astype(float), np.nan)
    med = np.nanmedian(x, axis=0)
    mad = np.maximum(np.nanmedian(np.abs(x - med), axis=0) * 1.4826, 0.5)
    keep = np.abs(x - med) <= 3.0 * mad
    n = keep.sum(axis=0)
    ref = np.where(n >= 2, np.where(keep, x, 0).sum(axis=0) / np.maximum(n, 1), 0.0)
    np.testing.assert_allclose(robust_mean_depth(st, 3.0, 2), ref, atol=1e-9)
