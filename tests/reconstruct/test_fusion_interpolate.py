"""The cut integration reads each voxel's depth between the four pixels around its projection: a surface
seen obliquely fuses flat instead of as a staircase of half a pixel's step."""

from __future__ import annotations

import numpy as np

from tests.reconstruct.test_crop_margin import HALF_PX, oblique_view
from tests.reconstruct.test_fusion_noise import INTR
from tofmetry.reconstruct import ReconstructionConfig
from tofmetry.reconstruct._fusion_reading import interpolated_reading, smooth_depth
from tofmetry.reconstruct._model_build import fuse_views
from tofmetry.reconstruct._pipeline import _no_progress


def plane_offsets_mm(interpolate: bool) -> np.ndarray:
    """|distance| [mm] of the fused vertices to the plane of :func:`oblique_view` (65 deg, 1.3 m, exact
    depth), those projecting four pixels or more inside the view's window."""
    cfg = ReconstructionConfig()
    cfg.fusion.interpolate_depth = interpolate
    views, segs, poses, n = oblique_view()
    V = fuse_views(views, segs, poses, INTR, cfg, _no_progress)[0]
    uv = V[:, :2] / V[:, 2:3] * [INTR.fx, INTR.fy] + [INTR.cx, INTR.cy]
    k = HALF_PX - 4
    inside = (np.abs(uv[:, 0] - INTR.width // 2) < k) & (np.abs(uv[:, 1] - INTR.height // 2) < k)
    return 1e3 * np.abs((V[inside] - [0.0, 0.0, 1.3]) @ n)


def test_an_oblique_plane_fuses_flat():
    """At 1.3 m and 65 deg neighbouring pixels differ by tan 65 z / f = 7.7 mm in depth. Read at the
    nearest pixel, a voxel's depth is off by up to half of that, and the zero level is a staircase: the
    vertices lie up to 1.5 mm off the plane (measured: median 0.54, max 1.47 mm; a voxel is 2.1 mm).
    Read bilinearly the plane's depth is exact to its curvature in the image, and the vertices lie on
    it (measured: max 0.006 mm)."""
    nearest = plane_offsets_mm(False)
    bilinear = plane_offsets_mm(True)
    assert len(nearest) > 100 and len(bilinear) > 100
    assert np.median(nearest) > 0.3 and nearest.max() > 1.0
    assert bilinear.max() < 0.05


def test_the_reading_keeps_the_nearest_pixel_across_a_step():
    """Bilinear where the four pixels around are smooth (a steep slope is: its second difference is
    0); the nearest pixel's depth where one of them sits on a step of 8 mm, or has an invalid
    neighbour."""
    u = np.arange(8, dtype=float)
    slope = np.tile(1000.0 + 15.0 * u, (6, 1))  # 15 mm a pixel: a plane seen at about 80 deg at 1 m
    stepped = slope.copy()
    stepped[:, 5:] += 8.0
    sm = smooth_depth(slope)
    assert sm[1:-1, 1:-1].all() and not sm[0].any() and not sm[:, -1].any()
    assert not smooth_depth(stepped)[1:-1, 4:6].any() and smooth_depth(stepped)[1:-1, 1:4].all()
    uu, vv = np.array([1.5, 4.5, 2.25]), np.array([2.5, 2.5, 1.0])
    nearest = np.array([1.045, 1.075, 1.030])
    np.testing.assert_allclose(interpolated_reading(slope, uu, vv, nearest), [1.0225, 1.0675, 1.03375])
    np.testing.assert_allclose(interpolated_reading(stepped, uu, vv, nearest), [1.0225, 1.075, 1.03375])
