"""Board calibration building blocks on analytic data (no rendering): model family, folds,
grid test, prediction intervals, support, pose selection."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.calibrate import CalibrationSupport, count_outside_range, apply_depth_calibration_reference
from tofmetry.calibrate import board as B
from tofmetry.calibrate._board_model import BoardDepthModel, ModelSpec, fit_board_model, ray_length, to_depth_calibration
from tofmetry.errors import InputError
from tofmetry.pipelines.board import parse_pose_selection
from tofmetry.sensor import KINECT_V2

INTR = KINECT_V2.depth
H, W = INTR.shape


def truth_correction(u, v, z):
    """Analytic truth [mm] to add to measured Z: a radial range term plus a smooth surface."""
    x = z * ray_length(INTR)[v, u]
    return -(8.0 + 0.006 * (x - 1000.0)) + 3.0 * (((u - 256) / 256) ** 2 + ((v - 212) / 212) ** 2) - 2.0


def analytic_samples(n_views=12, seed=0, noise=1.0):
    """Board-like patches: each view a random image rectangle at one range, tilted a little."""
    rng = np.random.default_rng(seed)
    u, v, z, zr, view = [], [], [], [], []
    for k in range(n_views):
        u0, v0 = rng.integers(0, W - 160), rng.integers(0, H - 130)
        vv, uu = np.mgrid[v0:v0 + 130:2, u0:u0 + 160:2]
        uu, vv = uu.ravel(), vv.ravel()
        ztrue = 600 + 900 * k / (n_views - 1) + 0.2 * (uu - u0) + 0.1 * (vv - v0)
        zm = ztrue - truth_correction(uu, vv, ztrue) + rng.normal(0, noise, uu.shape)
        u.append(uu), v.append(vv), z.append(zm), zr.append(ztrue), view.append(np.full(uu.shape, k))
    return [np.concatenate(a) for a in (u, v, z, zr, view)]


def test_model_recovers_analytic_truth_and_clamps_beyond_the_data():
    u, v, z, zr, _ = analytic_samples()
    m = fit_board_model(u, v, z, zr, (H, W), ModelSpec("s", "radial", 200.0, surface_smooth=1.0), intrinsics=INTR)
    c = m.correction(u, v, z)
    t = truth_correction(u, v, z)
    # noise 1 mm over ~60k samples; the membrane smoothing and the bilinear grid leave < 0.5 mm
    assert np.sqrt(np.mean((c - t) ** 2)) < 0.5
    # constant beyond the training range of the range variable: no extrapolated trend
    _, hi = m.x_support_mm
    uu, vv = np.array([256]), np.array([212])
    far = m.correction(uu, vv, np.array([hi * 3.0]))
    edge = m.correction(uu, vv, np.array([hi / ray_length(INTR)[212, 256] + 1.0]))
    assert far == pytest.approx(edge, abs=1e-6)


def test_model_serialises_and_becomes_an_equal_depth_calibration():
    u, v, z, zr, _ = analytic_samples()
    m = fit_board_model(u, v, z, zr, (H, W), ModelSpec("s", "radial", 200.0, surface_smooth=3.0, gain_smooth=3.0,
                                                        grid=(9, 8)), intrinsics=INTR)
    m2 = BoardDepthModel.from_dict(m.to_dict())
    np.testing.assert_allclose(m2.correction(u, v, z), m.correction(u, v, z))
    sup = CalibrationSupport.from_samples(u, v, z, (H, W))
    cal = to_depth_calibration(m, INTR, "kinect_v2", support=sup)
    # the radial range term is the core's ray term (exact); the gain surface is tabulated at
    # nodes, and its interpolation error is reported and small
    assert cal.ray_knots is not None and cal.ray_degree == 1 and cal.ray_gamma == 0.0
    assert cal.diagnostics["node_interpolation_max_mm"] < 0.5
    np.testing.assert_allclose(B.core_correction(cal, u, v, z), m.correction(u, v, z), atol=0.5)
    depth = np.full((H, W), 1000, np.uint16)
    depth[:10] = 0
    depth[10:20] = 6000        # far beyond the training depths: held at the farthest one, counted
    out = apply_depth_calibration_reference(depth, cal)
    vv, uu = np.mgrid[0:H, 0:W]
    ok = (depth == 1000)
    np.testing.assert_allclose(out[ok], (1000 + m.correction(uu, vv, np.full((H, W), 1000.0)))[ok], atol=0.5)
    hi = cal.support_range_mm[1]
    held = 6000 + m.correction(uu, vv, np.full((H, W), hi))
    np.testing.assert_allclose(out[10:20], held[10:20], atol=0.5)
    assert count_outside_range(depth, cal) >= 10 * W


def test_identity_and_constant_models():
    u, v, z, zr, _ = analytic_samples(4)
    ident = fit_board_model(u, v, z, zr, (H, W), ModelSpec("none", "z", 0.0, identity=True))
    assert np.all(ident.correction(u, v, z) == 0) and ident.describe() == "no correction"
    const = fit_board_model(u, v, z, zr, (H, W), ModelSpec("c", "z", 0.0))
    assert const.correction(u[:1], v[:1], z[:1])[0] == pytest.approx(np.mean(zr - z), abs=1e-6)
    cal = to_depth_calibration(const, INTR)
    assert cal.surfaces.shape[0] == 1


def test_blocked_folds():
    order = np.arange(10)
    z = np.array([5, 1, 9, 3, 7, 2, 8, 4, 6, 0], float)
    t = B.blocked_folds(order, z, "time", k=3)
    assert [f.tolist() for f in t] == [[0, 1, 2, 3], [4, 5, 6], [7, 8, 9]]
    r = B.blocked_folds(order, z, "range", k=2)
    assert sorted(z[r[0]]) == [0, 1, 2, 3, 4] and sorted(z[r[1]]) == [5, 6, 7, 8, 9]
    rnd = B.blocked_folds(order, z, "random", k=5, seed=1)
    assert sorted(np.concatenate(rnd).tolist()) == list(range(10))
    regions = B.region_folds((H, W))
    area = sum((u1 - u0) * (v1 - v0) for u0, u1, v0, v1 in regions)
    assert area == H * W and len(regions) == 6
    with pytest.raises(InputError, match="design"):
        B.blocked_folds(order, z, "pixels")


def test_grid_threshold_from_measured_corner_noise():
    rng = np.random.default_rng(0)
    n = 35
    sigma = 0.08
    # per-grid PnP RMS under corner noise sigma: sqrt(chi2(2n - 6) / 2n) * sigma
    rms = sigma * np.sqrt(rng.chisquare(2 * n - 6, 200) / (2 * n))
    est = B.corner_noise_px(rms, n)
    assert est == pytest.approx(sigma, rel=0.05)
    thr = B.grid_threshold_px(est, n)
    assert 3 * sigma < thr < 8 * sigma
    assert np.mean(rms > thr) == 0.0
    # exact synthetic corners: the noise floor keeps the threshold usable
    assert B.corner_noise_px(np.full(5, 1e-6), n) == B.MIN_CORNER_NOISE_PX


def test_prediction_intervals_cover_and_widen_with_shared_errors():
    rng = np.random.default_rng(1)
    V = 40
    ids = np.repeat(np.arange(V), 300)
    iid = rng.normal(0, 2.0, ids.size)
    p = B.predict_error(ids, iid, n_new_views=20)
    assert p["rms_mm_interval"][0] < 2.0 < p["rms_mm_interval"][1]
    assert p["mean_mm_interval"][0] < 0 < p["mean_mm_interval"][1]
    # the same errors plus a slow drift shared by neighbouring views: the moving-block bootstrap
    # (views in recording order) gives a wider interval for the mean than independent draws
    drift = np.repeat(3.0 * np.sin(np.arange(V) / 5.0), 300)
    e = iid + drift
    indep = B.predict_error(ids, e, n_new_views=20)
    block = B.predict_error(ids, e, n_new_views=20, view_order=np.arange(V))
    w = lambda q: q["mean_mm_interval"][1] - q["mean_mm_interval"][0]
    assert block["block"] == 6 and w(block) > 1.3 * w(indep)


def test_support_counts_and_outside():
    u = np.array([0, 5, 20, 511])
    v = np.array([0, 5, 20, 423])
    z = np.array([1010.0, 1090.0, 1500.0, 800.0])
    s = B.support_counts(u, v, z, (H, W))
    assert s["counts"].shape == (27, 32, len(s["z_edges_mm"]) - 1) and s["counts"].sum() == 4
    assert s["counts"][0, 0].sum() == 2
    out = B.outside_support(s, np.array([3, 3, 300]), np.array([3, 3, 300]), np.array([1050.0, 1250.0, 1050.0]))
    assert out.tolist() == [False, True, True]


def test_dark_bias_is_fitted_against_amplitude():
    parts = []
    rng = np.random.default_rng(2)
    for k, amp in enumerate(np.linspace(800, 4000, 12)):
        n = 200
        truth = 20.0 - 6.0 * np.log(amp / 800.0)
        white = np.r_[np.ones(n, bool), np.zeros(n, bool)]
        meas = np.r_[np.full(n, 1000.0), np.full(n, 1000.0 + truth)] + rng.normal(0, 1, 2 * n)
        parts.append(B.BoardSamples(np.zeros(2 * n, int), np.zeros(2 * n, int), meas, np.full(2 * n, 1000.0), white,
                                    ~white, 0.1, float("nan"), amplitude=np.r_[np.full(n, 6 * amp), np.full(n, amp)]))
    db = B.fit_dark_bias(parts)
    for a in (900.0, 2000.0, 3900.0):
        assert db(np.array([a]))[0] == pytest.approx(20.0 - 6.0 * np.log(a / 800.0), abs=1.0)
    # never extrapolated beyond the measured amplitudes
    assert db(np.array([1e5]))[0] == pytest.approx(db(np.array([4000.0]))[0])


def test_pose_selection():
    names = [f"{i:04d}" for i in range(70)]
    assert parse_pose_selection("0-49", names) == list(range(50))
    assert parse_pose_selection("0050-0052, 69", names) == [50, 51, 52, 69]
    assert parse_pose_selection(None, names) is None
    with pytest.raises(InputError, match="--judge-poses"):
        parse_pose_selection("80-90", names, "--judge-poses")
    with pytest.raises(InputError, match="range like"):
        parse_pose_selection("a-b", names)
    assert parse_pose_selection("1-2", ["left", "mid", "right"]) == [1, 2]
    assert parse_pose_selection("mid", ["left", "mid", "right"]) == [1]
