"""The virtual colour camera integrates each pixel's area on edges (``render_colour(supersample=...)``).

Truth: the same lens at 16x the resolution, one ray per fine pixel, averaged over 16 x 16 blocks
(each block is one coarse pixel's box, ``CameraIntrinsics.scaled``): the area integral to
1/256 of a pixel. A single ray per pixel puts an edge pixel wholly on one side (error up to half
the contrast C, 0.8 - 0.133 albedo = 170 DN). The 9 sub-rays of ``supersample=3`` (an n-rooks
pattern, drawn per pixel) estimate the area beyond a straight edge with an error of 0.075 C RMS
and at most 0.32 C over edges of every direction and offset (computed numerically for the
pattern; 1/18 C at most for an edge along a pixel row or column).
"""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.sensor import CameraIntrinsics, Extrinsics
from tofmetry.simulate import ColourCamera, render_colour, scenes
from tofmetry.simulate.scenes import rotation_xyz

LENS = CameraIntrinsics(96, 72, 80.0, 80.0, 47.3, 35.6, (0.12, -0.2, 0.001, -0.002, 0.05))
FINE = 16


def _grey(p, label, albedo):
    return np.repeat(albedo[:, None], 3, axis=1)


def _scene():
    T = np.eye(4)
    T[:3, :3] = rotation_xyz(18.0, -12.0, 7.0)
    T[:3, 3] = [-0.19, -0.13, 0.9]
    return scenes.checkerboard(6, 4, 0.06, T)


@pytest.fixture(scope="module")
def images():
    scene = _scene()
    cam = ColourCamera(LENS, Extrinsics.identity(), texture=_grey)
    fine = ColourCamera(LENS.scaled(LENS.width * FINE, LENS.height * FINE), Extrinsics.identity(), texture=_grey)
    ref = render_colour(scene, fine, supersample=1).image.astype(float)
    ref = ref.reshape(LENS.height, FINE, LENS.width, FINE, 3).mean(axis=(1, 3))
    one = render_colour(scene, cam, supersample=1)
    return ref, one, render_colour(scene, cam)


def test_edge_pixels_integrate_their_area(images):
    ref, one, ss = images
    e1 = np.abs(one.image.astype(float) - ref)[..., 0]
    e3 = np.abs(ss.image.astype(float) - ref)[..., 0]
    edge = e1 > 3.0                       # pixels where a single ray misses the area mean
    rms = lambda x: float(np.sqrt(np.mean(x ** 2)))
    print(f"edge pixels {edge.sum()}: one ray RMS {rms(e1[edge]):.1f} DN (max {e1.max():.0f}), "
          f"3x3 n-rooks RMS {rms(e3[edge]):.1f} DN (max {e3.max():.1f})")
    C = 255.0 * (0.8 - 0.133)
    assert edge.sum() > 100 and rms(e1[edge]) > 0.2 * C
    assert rms(e3[edge]) < 0.075 * C and e3.max() < 0.32 * C + 1.0
    assert rms(e3[edge]) < rms(e1[edge]) / 3
    # away from the edges (the true image flat over the 3 x 3 neighbourhood) the pixel is the centre ray's
    from scipy.ndimage import maximum_filter, minimum_filter

    flat = (maximum_filter(ref[..., 0], 3) - minimum_filter(ref[..., 0], 3)) < 1.0
    assert flat.mean() > 0.5
    np.testing.assert_array_equal(ss.image[flat], one.image[flat])
    # the centre ray's depth and labels are kept
    np.testing.assert_array_equal(ss.labels, one.labels)
    np.testing.assert_array_equal(ss.depth_m, one.depth_m)


def test_supersample_is_validated():
    cam = ColourCamera(LENS, Extrinsics.identity(), texture=_grey)
    for bad in (0, 2.5, True):
        with pytest.raises(InputError, match="supersample"):
            render_colour(_scene(), cam, supersample=bad)
