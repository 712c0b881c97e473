"""The joint fit's depth corrections applied to the views: points and depth maps stay one surface."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tofmetry._shared.geometry import fit_plane_svd
from tofmetry.reconstruct._adjust_apply import correct_views
from tofmetry.reconstruct._preprocess import ViewData
from tofmetry.reconstruct._segment import Segmentation
from tofmetry.sensor import KINECT_V2


def _plane_view(intr):
    """A plane seen obliquely, Z = 1 m / (1 - 0.15 y) (y the pixel's ray), every pixel valid."""
    xy = intr.ray_table()
    z = 1.0 / (1.0 - 0.15 * xy[..., 1])
    pts = np.concatenate([xy * z[..., None], z[..., None]], -1).reshape(-1, 3)
    n = pts.shape[0]
    view = ViewData("v", z * 1e3, pts, np.arange(n), np.zeros((n, 3)), np.ones(n), None, {})
    plane = fit_plane_svd(pts, orient=np.array([0.0, 0.0, -1.0]))
    seg = Segmentation(np.zeros(n, bool), np.ones(n, bool), None, plane, 1.0)
    return view, seg


def _result(gain=0.0, tilt=None, centre=(0.0, 0.0)):
    return SimpleNamespace(depth_gain=gain, range_curve_estimated=False, range_curve_m=None,
                           range_curve_half_span_m=0.3, amplitude_estimated=False, amplitude_dk_m=0.0,
                           image_tilt_estimated=tilt is not None, image_tilt_m=tilt, image_tilt_centre=np.array(centre))


def test_gain_and_tilt_move_points_and_depth_alike_and_refit_the_support_plane():
    """Z -> Z + g (Z - z_ref) + a (x - x0) + b (y - y0): every point's Z is its pixel's corrected depth,
    the point stays on its ray, and the support plane is refitted on the moved points."""
    intr = KINECT_V2.depth
    view, seg = _plane_view(intr)
    z0, p0 = view.depth_mm.copy(), view.points.copy()
    g, ab, c = 0.01, np.array([4e-3, -6e-3]), (0.05, -0.02)
    correct_views([view], [seg], _result(g, ab, c), 1.0, intr, None, 0.005)
    xy = intr.ray_table().reshape(-1, 2)
    want = z0.ravel() * 1e-3 + g * (z0.ravel() * 1e-3 - 1.0) + (xy - c) @ ab
    np.testing.assert_allclose(view.depth_mm.ravel() * 1e-3, want, atol=1e-9)
    np.testing.assert_allclose(view.points[:, 2], want, atol=1e-9)
    np.testing.assert_allclose(view.points[:, :2] / view.points[:, 2:], p0[:, :2] / p0[:, 2:], atol=1e-12)
    # the support plane is refitted on the moved points (which are no longer exactly on a plane)
    np.testing.assert_allclose(seg.plane, fit_plane_svd(view.points, orient=seg.plane[:3]), atol=1e-12)
    assert not np.allclose(seg.plane, fit_plane_svd(p0, orient=seg.plane[:3]), atol=1e-4)


def test_nothing_estimated_leaves_the_views_alone():
    intr = KINECT_V2.depth
    view, seg = _plane_view(intr)
    before = (view.points.copy(), view.depth_mm.copy(), seg.plane.copy())
    correct_views([view], [seg], _result(), 1.0, intr, None, 0.005)
    assert view.points is not None and np.array_equal(view.points, before[0])
    assert np.array_equal(view.depth_mm, before[1]) and np.array_equal(seg.plane, before[2])


@pytest.mark.parametrize("gain", [-0.02, 0.02])
def test_a_gain_scales_about_the_reference_depth(gain):
    intr = KINECT_V2.depth
    view, seg = _plane_view(intr)
    z0 = view.points[:, 2].copy()
    correct_views([view], [seg], _result(gain), 0.9, intr, None, 0.005)
    np.testing.assert_allclose(view.points[:, 2] - z0, gain * (z0 - 0.9), atol=1e-12)
