"""Flying-pixel detector: analytic edges and the simulator's mixed-pixel labels."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.assess import FlyingPixelParams, assess_outdoor, detect_flying_pixels, remove_flying_pixels
from tofmetry.sensor import KINECT_V2


def _step_scene():
    """Foreground plane at 1.0 m over the left half, background at 2.0 m; column 255 mixed."""
    h, w = KINECT_V2.depth.shape
    d = np.full((h, w), 2000, np.uint16)
    d[:, :255] = 1000
    rng = np.random.default_rng(1)
    mix = rng.uniform(0.15, 0.85, h)
    d[:, 255] = np.rint(1000 * mix + 2000 * (1 - mix)).astype(np.uint16)
    return d


def test_mixed_column_detected_and_edges_kept():
    d = _step_scene()
    m = detect_flying_pixels(d, KINECT_V2.depth)
    assert m[:, 255].mean() > 0.95
    m[:, 255] = False
    assert not m.any()  # real edge pixels of both surfaces are kept
    out = remove_flying_pixels(d, KINECT_V2.depth)
    assert out.dtype == d.dtype and (out[:, 255] == 0).mean() > 0.95 and (d[:, 255] > 0).all()


def test_smooth_tilted_noisy_surface_has_no_flying_pixels():
    intr = KINECT_V2.depth
    rays = intr.ray_table()
    # plane tilted 20 deg about the vertical axis at ~1.5 m, noise 1.5 mm/m; with the
    # +-35 deg field of view the incidence stays below 55 deg < theta_max = 60 deg
    n = np.array([np.sin(np.radians(20)), 0, np.cos(np.radians(20))])
    z = 1500.0 * n[2] / (n[0] * rays[..., 0] + n[2])
    rng = np.random.default_rng(2)
    z = z + rng.standard_normal(z.shape) * 1.5 * z / 1000
    d = np.rint(z).astype(np.uint16)
    m = detect_flying_pixels(d, intr)
    # false alarm per pixel for 3-sigma thresholds on 8 neighbours needs >= 7 failures: ~0
    assert m.mean() < 1e-4


def test_thin_line_is_not_flying():
    d = np.full((50, 60), 2000, np.uint16)
    d[:, 30] = 1000  # 1-px wide pole in front of a wall
    m = detect_flying_pixels(d, KINECT_V2.depth.scaled(60, 50))
    # inside the image each pole pixel has 2 supporting neighbours and no "between" jump;
    # its end pixels on the image border have only one (documented limit of a 3x3 test)
    assert not m[1:-1].any()


def test_unknown_parameter_is_rejected():
    with pytest.raises(ValueError, match="unknown"):
        detect_flying_pixels(np.zeros((4, 4), np.uint16), None, bogus=1)


@pytest.fixture(scope="module")
def outdoor_rendering():
    from tofmetry.simulate import ErrorModel, VirtualKinect, scenes
    from tofmetry.simulate.datasets import OUTDOOR_POSITION, OUTDOOR_TARGET
    from tofmetry.simulate.poses import look_at

    scene = scenes.outdoor_table()
    pose = look_at(OUTDOOR_POSITION, OUTDOOR_TARGET)
    return scene, pose, VirtualKinect(errors=ErrorModel(), seed=7).render(scene, pose)


@pytest.mark.parametrize("ambient", [0.0, 1.0])
def test_recall_and_precision_against_simulator_labels(outdoor_rendering, ambient):
    from tofmetry.simulate import ErrorModel, VirtualKinect

    scene, pose, rd = outdoor_rendering
    # ambient 1 = the sunny scenario of datasets.outdoor (~20 % valid, ~2 % flying)
    vk = VirtualKinect(errors=ErrorModel().with_(ambient=ambient), seed=7)
    fr = next(vk.iter_frames(scene, 1, pose, rendering=rd))
    res = assess_outdoor(fr.depth[None], intr=KINECT_V2.depth, ir=fr.ir[None])
    m = detect_flying_pixels(fr.depth, KINECT_V2.depth, FlyingPixelParams(), ir=fr.ir)
    lab = fr.flying
    tp = int((m & lab).sum())
    fp = int((m & ~lab).sum())
    fn = int((~m & lab).sum())
    assert tp + fn > 100  # the scene has mixed pixels to find
    assert tp / (tp + fn) >= 0.8 and tp / (tp + fp) >= 0.8  # issue: recall >= 0.8 at precision >= 0.8
    assert res.valid[0] == int((fr.depth > 0).sum()) and res.n_max == 217_088
    assert res.flying[0] == int(m.sum())


@pytest.mark.realdata
def test_real_kinect_frame_flags_edges(shared_data):
    """Real Kinect v2 frame (iai_kinect2 board recording): few pixels flagged, mostly at depth edges."""
    from scipy import ndimage

    from tofmetry.io.images import read_depth_image, read_ir_image

    rec = shared_data / "kinect2-board-recording"
    d = read_depth_image(rec / "0030_depth.png").astype(np.float64)
    ir = read_ir_image(rec / "0030_ir.png")
    m = detect_flying_pixels(d, KINECT_V2.depth, ir=ir)
    valid = d > 0
    assert 0.001 < m.sum() / valid.sum() < 0.05
    # depth edge: a jump of > 100 mm within 5x5 pixels; edges cover ~7 % of the valid image
    hi = ndimage.maximum_filter(np.where(valid, d, 0.0), 5)
    lo = -ndimage.maximum_filter(np.where(valid, -d, -1e9), 5)
    edge = (hi - lo) > 100
    assert edge[m].mean() > 0.6 > edge[valid].mean() * 5
