"""Virtual Kinect: each error term on/off, truth recovery, determinism, amplitude calibration."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.simulate import ErrorModel, VirtualKinect, scenes
from tofmetry.simulate import errors as E

C = (slice(202, 212), slice(251, 261))  # central 10x10 patch (cx = 256.5, cy = 207)


def _points(depth_mm: np.ndarray, vk: VirtualKinect) -> np.ndarray:
    xy = np.asarray(vk.intrinsics.ray_table())
    z = depth_mm * 1e-3
    ok = z > 0
    return np.column_stack([xy[..., 0][ok] * z[ok], xy[..., 1][ok] * z[ok], z[ok]])


def test_ideal_tilted_wall_fits_true_plane():
    vk = VirtualKinect(ErrorModel.none(quantize=False), seed=1)
    sc = scenes.wall(1.7, tilt_deg=(10.0, -20.0))
    fr = vk.capture(sc, n_frames=3)
    assert fr.depth.dtype == np.float64
    pts = _points(fr.depth.mean(axis=0), vk)
    n = np.asarray(sc.info["plane_normal"])
    resid = pts @ n - sc.info["plane_d_m"]
    # ideal sensor: only float32/float64 round-off remains (<< 0.1 mm)
    assert np.abs(resid).max() < 1e-4
    assert pts.shape[0] == 424 * 512
    np.testing.assert_allclose(fr.true_depth, fr.depth[0], atol=1e-9)


def test_only_wiggling_centre_bias_is_the_documented_function():
    em = ErrorModel.only("wiggling", quantize=False)
    for dist in (1.0, 2.6):
        fr = VirtualKinect(em).capture(scenes.wall(dist), n_frames=2)
        bias = fr.depth[0] - fr.true_depth
        xy = np.asarray(VirtualKinect(em).intrinsics.ray_table())
        np.testing.assert_allclose(bias[C], E.wiggling_mm(fr.true_depth[C], em, xy[C]), atol=1e-6)
        # everywhere: a function of the ray length, applied along the ray (W / rho in Z)
        np.testing.assert_allclose(bias, E.wiggling_mm(fr.true_depth, em, xy), atol=1e-6)


def test_only_deformation_is_the_documented_surface():
    em = ErrorModel.only("deformation", quantize=False)
    vk = VirtualKinect(em)
    fr = vk.capture(scenes.wall(2.0), n_frames=1)
    expect = E.deformation_mm(np.asarray(vk.intrinsics.ray_table()), fr.true_depth, em)
    np.testing.assert_allclose(fr.depth[0] - fr.true_depth, expect, atol=1e-6)


def test_only_noise_std_matches_sigma():
    em = ErrorModel.only("noise", quantize=False)
    fr = VirtualKinect(em, seed=3).capture(scenes.wall(1.0), n_frames=60)
    std = fr.depth[:, C[0], C[1]].std(axis=0, ddof=1)
    sigma = E.noise_sigma_mm(fr.amplitude[C], fr.true_depth[C], em)
    # 100 pixels x 60 frames: the mean of the per-pixel std has ~1 % sampling error; allow 5 %
    assert std.mean() == pytest.approx(sigma.mean(), rel=0.05)
    assert 1.0 < sigma.mean() < 1.5
    # unbiased: mean over frames within 4 standard errors
    assert abs((fr.depth[:, C[0], C[1]] - fr.true_depth[C]).mean()) < 4 * sigma.mean() / np.sqrt(6000)
    # noisier in the corners (vignetting / 1/r^2)
    assert fr.depth[:, :10, :10].std(axis=0).mean() > 1.5 * std.mean()


def test_amplitude_calibration_white_black_at_1m():
    vk = VirtualKinect(ErrorModel.none())
    w = vk.capture(scenes.wall(1.0, albedo=0.8), n_frames=1).ir[0][C].mean()
    b = vk.capture(scenes.wall(1.0, albedo=0.133), n_frames=1).ir[0][C].mean()
    assert w == pytest.approx(12000, rel=0.15)  # paper §3.3.1
    assert b == pytest.approx(2000, rel=0.15)


def test_only_amplitude_bias_black_reads_12mm_long():
    em = ErrorModel.only("amplitude_bias", quantize=False)
    sc = scenes.grey_board(1.0)
    fr = VirtualKinect(em).capture(sc, n_frames=1)
    bias = fr.depth[0] - fr.true_depth
    info = {s["label"]: s for s in sc.info["samples"]}
    # pixels fully inside one square (no anti-aliasing mix): compare white vs black squares
    from scipy.ndimage import binary_erosion

    def mean_bias(albedo):
        m = np.zeros(fr.labels.shape, bool)
        for lab, s in info.items():
            if s["albedo"] == albedo:
                m |= binary_erosion(fr.labels == lab, iterations=2)
        return bias[m].mean()

    d = mean_bias(scenes.GREY_LEVELS[-1]) - mean_bias(scenes.GREY_LEVELS[0])
    # k ln(A_white / A_black) with A proportional to albedo; 0.3 mm for the uneven vignetting mix
    assert d == pytest.approx(em.amp_bias_mm_per_ln * np.log(0.8 / 0.133), abs=0.3)
    assert 11.0 < d < 13.0  # paper: up to 1.2 cm for black


def test_reflective_sample_reads_long_and_uneven():
    em = ErrorModel.only("amplitude_bias", quantize=False)
    sc = scenes.material_board(1.0)
    fr = VirtualKinect(em, seed=2).capture(sc, n_frames=4)
    cd = [k for k, v in sc.labels.items() if v == "cd"][0]
    from scipy.ndimage import binary_erosion

    m = binary_erosion(fr.labels == cd, iterations=2)
    b = (fr.depth[:, m] - fr.true_depth[m])
    assert b.mean() > 20.0 and b.max() > 40.0 and b.max() < 90.0  # several cm (CD: up to 6 cm)
    assert b.mean(axis=0).std() > 5.0  # spatially uneven
    assert np.abs(np.diff(b, axis=0)).mean() > 1.0  # per-frame jitter


def test_only_warmup_shift_follows_timestamps():
    em = ErrorModel.only("warmup", quantize=False)
    ts = np.array([0.0, 600.0, 1200.0, 3600.0])
    fr = VirtualKinect(em).capture(scenes.wall(1.36), n_frames=4, timestamps_s=ts)
    shift = (fr.depth - fr.true_depth)[:, C[0], C[1]].mean(axis=(1, 2))
    np.testing.assert_allclose(shift, E.warmup_mm(ts, em), atol=1e-9)
    np.testing.assert_array_equal(fr.timestamps_s, ts)


def test_invalid_range_and_quantisation():
    em = ErrorModel.only("invalid", quantize=True)
    vk = VirtualKinect(em)
    assert not vk.capture(scenes.wall(4.8), n_frames=1).depth.any()  # beyond 4.5 m
    assert not vk.capture(scenes.wall(0.45), n_frames=1).depth.any()  # below 0.5 m
    fr = vk.capture(scenes.wall(2.0), n_frames=1)
    assert fr.depth.dtype == np.uint16 and fr.depth.all()
    assert np.abs(fr.depth[0] - fr.true_depth).max() <= 0.5 + 1e-9  # whole mm
    # ideal sensor keeps far walls
    assert VirtualKinect(ErrorModel.none()).capture(scenes.wall(4.8), n_frames=1).depth.all()


def test_determinism():
    sc = scenes.wall(1.5, tilt_deg=(5, 5))
    a = VirtualKinect(ErrorModel(), seed=7).capture(sc, n_frames=3)
    b = VirtualKinect(ErrorModel(), seed=7).capture(sc, n_frames=3)
    c = VirtualKinect(ErrorModel(), seed=8).capture(sc, n_frames=3)
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.ir, b.ir)
    assert not np.array_equal(a.depth, c.depth)


def _box_scene():
    from tofmetry.simulate.scenes import MeshSurface, PlaneSurface, Scene, _box, _uniform_texture

    v, f = _box((-0.2, -0.2, 1.0), (0.2, 0.2, 1.3))
    wall = PlaneSurface(np.array([0, 0, 2.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), None,
                        _uniform_texture(0.8, 0))
    return Scene("box", [wall, MeshSurface(v, f, 0.8, 1)], {0: "wall", 1: "box"})


def test_flying_pixels_at_depth_edges_only():
    from tofmetry.sensor import KINECT_V2

    sc = _box_scene()
    small = KINECT_V2.depth.scaled(256, 212)  # half resolution keeps the test fast
    on = VirtualKinect(ErrorModel.only("flying", quantize=False), seed=0, intrinsics=small).capture(sc, n_frames=3)
    off = VirtualKinect(ErrorModel.none(quantize=False), seed=0, intrinsics=small).capture(sc, n_frames=3)
    assert not off.flying.any()
    assert on.flying.any()
    # every flying pixel lies on the box silhouette (a different label in its 3x3 neighbourhood)
    from scipy.ndimage import maximum_filter, minimum_filter

    lab = on.labels
    edge = maximum_filter(lab, size=3) != minimum_filter(lab, size=3)
    assert np.all(edge[on.flying.any(axis=0)])
    # flying values lie between foreground (1.0 m) and background (2.0 m)
    vals = on.depth[on.flying]
    assert vals.min() > 1000 - 1 and vals.max() < 2000 + 1
    # away from edges the depth is the true one
    np.testing.assert_allclose(on.depth[:, ~edge], np.broadcast_to(on.true_depth[~edge], on.depth[:, ~edge].shape))


def test_outdoor_valid_and_flying_fractions():
    from tofmetry.simulate.datasets import OUTDOOR_POSITION, OUTDOOR_TARGET
    from tofmetry.simulate.poses import look_at

    vk = VirtualKinect(ErrorModel(ambient=1.0), seed=0)
    fr = vk.capture(scenes.outdoor_table(), n_frames=2, pose=look_at(OUTDOOR_POSITION, OUTDOOR_TARGET))
    valid = fr.depth > 0
    # paper §3.3.2: ~35 000 of 217 088 points (~20 %), ~2 % of them flying
    assert valid.mean() == pytest.approx(0.20, abs=0.05)
    assert fr.flying.sum() / valid.sum() == pytest.approx(0.02, abs=0.01)
    # more flying pixels toward the edges of the field of view
    H, W = valid.shape[1:]
    centre = np.zeros((H, W), bool)
    centre[H // 4: 3 * H // 4, W // 4: 3 * W // 4] = True
    rate = lambda m: fr.flying[:, m].sum() / max(valid[:, m].sum(), 1)  # noqa: E731
    assert rate(~centre) > rate(centre)
