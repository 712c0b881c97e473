"""Occlusion-aware colouring against rendered truth: a panel in front of a wall, seen by an IR
camera and a colour camera a few centimetres beside it (random virtual sensors).

Geometry -> render (IR depth from the IR camera, colour image from the colour camera's own
viewpoint) -> colourise the IR cloud -> compare with the truth of every point: does the colour
camera see it (a ray cast from the colour camera), and its noise-free colour.
"""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.pointcloud import colour_points, depth_to_points
from tofmetry.sensor import KINECT_V2, CameraIntrinsics, Extrinsics
from tofmetry.simulate import ColourCamera, ErrorModel, occluder_scene, render, render_colour, true_point_colours
from tofmetry.simulate.scenes import rotation_xyz


def _virtual_sensor(seed: int) -> tuple[CameraIntrinsics, ColourCamera]:
    rng = np.random.default_rng(seed)
    ir = KINECT_V2.depth.with_(fx=365 + rng.normal(0, 3), fy=365 + rng.normal(0, 3))
    c = KINECT_V2.color
    model = ("brown", "rational")[seed % 2]
    dist = (0.02, -0.03, 0, 0, 0) if model == "brown" else (0.3, -0.05, 1e-4, -1e-4, 0.0, 0.28, -0.04, 0.0)
    color = CameraIntrinsics(c.width, c.height, 1060 + rng.normal(0, 10), 1060 + rng.normal(0, 10),
                             959.5 + rng.normal(0, 5), 539.5 + rng.normal(0, 5), dist, model)
    ext = Extrinsics(rotation_xyz(*rng.normal(0, 0.5, 3)), np.array([0.052, 0.0, 0.0]) + rng.normal(0, 0.002, 3))
    return ir, ColourCamera(color, ext, exposure=rng.uniform(0.8, 1.0), noise_dn=2.0)


@pytest.mark.parametrize("seed", [0, 1])
def test_occluded_points_get_no_colour_and_colour_error_is_small(seed):
    ir, cam = _virtual_sensor(seed)
    scene = occluder_scene(background_m=2.0, occluder_m=1.2, occluder_half_width_m=0.25)
    em = ErrorModel().without(*ErrorModel().enabled)
    depth = render(scene, ir, np.eye(4), em, supersample=1).true_depth  # exact Z [mm] of each ray
    pts = depth_to_points(depth, ir)
    img = render_colour(scene, cam, rng=np.random.default_rng(seed)).image
    visible, truth = true_point_colours(scene, cam, pts)
    # the wall strip behind the panel edge: baseline * (1/1.2 - 1/2) * f_ir ~ 6 IR pixels over 0.5 m
    assert (~visible).sum() > 1000

    res = colour_points(pts, img, cam.intrinsics, cam.ir_to_color, depth_focal_px=ir.fx)
    # no point the colour camera cannot see is coloured
    assert not (res.colored & ~visible).any()
    # and almost every visible point is coloured: the splats only widen the hidden strip by about
    # one depth-pixel footprint along the panel's edges (2 x 0.5 m edges, ~1 px each)
    missed = visible & ~res.colored
    assert missed.sum() < 4 * 0.5 * ir.fx / 1.2 * 2, missed.sum()
    assert res.summary()["share_colored"] == pytest.approx(res.colored.mean())
    # colour error of the coloured points: image noise (2 DN) and 8-bit rounding; large only where
    # a bilinear sample straddles the panel's edge in the colour image
    err = np.abs(res.colors[res.colored].astype(float) - truth[res.colored]).max(axis=1)
    assert np.median(err) < 3.0 and np.percentile(err, 99) < 12.0, (np.median(err), np.percentile(err, 99))


def test_points_behind_the_colour_camera_or_outside_get_no_colour():
    cam = ColourCamera(CameraIntrinsics(64, 48, 50, 50, 31.5, 23.5), Extrinsics.identity())
    img = np.full((48, 64, 3), 200, np.uint8)
    pts = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [10.0, 0.0, 1.0]])
    res = colour_points(pts, img, cam.intrinsics, cam.ir_to_color)
    assert res.colored.tolist() == [True, False, False] and res.in_view.tolist() == [True, False, False]
    assert res.colors[0].tolist() == [200, 200, 200]
