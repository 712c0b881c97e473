"""Global adjustment with a depth error linear in the image position (the tilt a wall calibration
cannot see), and the poses' predicted spread under the calibration's per-pixel residual."""

from __future__ import annotations

import numpy as np
import pytest

from tofmetry.reconstruct import AdjustView, global_adjust
from tofmetry.reconstruct._adjust_field import DepthFieldPrior, pose_spread

from .test_adjust import _errors, _perturb, _visible, ring  # noqa: F401 (the fixture)

TRUE_AB = np.array([8e-3, -6e-3])  # [m per unit of x / z]: 8 and 6 mm at 45 deg off the axis


def _views(poses, ab, rng, n=20000):
    """Each view's own samples of its visible surface, camera frame, its depth reading
    ``Z - (a x + b y)`` so that the correction ``Z + a x + b y`` restores it (x, y = X / Z, Y / Z:
    constant along the ray)."""
    out = []
    for T in poses:
        pc, nc = _visible(T, rng, n)
        zt = pc[:, 2]
        zm = zt - (pc[:, :2] / zt[:, None]) @ ab
        pm = pc * (zm / zt)[:, None]
        out.append(AdjustView(pm[::4], nc[::4], pm, nc))
    return out


@pytest.fixture(scope="module")
def scan(ring):
    rng = np.random.default_rng(3)
    views = _views(ring, TRUE_AB, rng)
    init = np.stack([ring[0]] + [_perturb(T, rng, 0.3, 2.0) for T in ring[1:]])
    return views, init


def test_recovers_the_tilt_and_the_poses(ring, scan):
    """Noise-free views of the ellipsoid with an 8 / -6 mm per unit tilt, poses started 0.3 deg /
    2 mm off. With the tilt the adjustment must find it within 3 of its standard errors (plus
    0.2 mm for the sampling of the curved surface, the only error) and the poses within the
    limits of ``test_adjust`` (0.06 deg / 1 mm); without it each view keeps the tilt's rotation,
    ~a / Z rad (guards against passing for the wrong reason)."""
    views, init = scan
    with_tilt = global_adjust(views, init, 1.0, tilt_prior_m=10e-3, estimate_gain=False)
    without = global_adjust(views, init, 1.0, estimate_gain=False)
    assert with_tilt.image_tilt_estimated, with_tilt.image_tilt_note
    ab, s = with_tilt.image_tilt_m, with_tilt.image_tilt_sigma_m
    assert np.all(s > 0) and np.all(s < 2e-3), s  # determined, far better than the 10 mm prior
    assert np.all(np.abs(ab - TRUE_AB) < 3 * s + 2e-4), (ab, s)
    e_tilt, e_none = _errors(with_tilt.poses, ring), _errors(without.poses, ring)
    assert e_tilt[:, 0].max() < 0.06 and e_tilt[:, 1].max() < 1.0, e_tilt
    assert e_none[:, 0].max() > 3 * e_tilt[:, 0].max(), (e_none, e_tilt)
    rep = with_tilt.to_dict()["image_tilt"]
    assert rep["estimated"] and len(rep["ab_mm"]) == 2
    assert not without.to_dict()["image_tilt"]["estimated"]


def test_an_implausible_tilt_is_refused(scan):
    """A prior far below the true tilt: the views ask for more than 3 of its standard deviations,
    so the estimate is refused and the adjustment is run again without it (note says why)."""
    views, init = scan
    res = global_adjust(views, init, 1.0, tilt_prior_m=1.5e-3, estimate_gain=False)
    assert not res.image_tilt_estimated
    assert res.image_tilt_note.startswith("implausible"), res.image_tilt_note
    np.testing.assert_array_equal(res.image_tilt_m, 0.0)


def test_predicted_spread_covers_the_tilts_pose_error(ring, scan):
    """Left unestimated, the tilt moves the poses by what the first-order propagation of a field of
    its size predicts: the actual worst-view error (whole set aligned on the object, as the
    prediction does it) lies between the predicted 10th and 99th percentile of fields with the
    tilt's magnitude. The sampling of the surface adds ~0.01 deg."""
    views, init = scan
    ax = 0.6  # half field of view in x / z
    prior = DepthFieldPrior((ax, ax * 0.8), 0.0, 0.0, degree=1, tilt_sigma_m=float(np.linalg.norm(TRUE_AB)) / np.sqrt(2))
    res = global_adjust(views, init, 1.0, estimate_gain=False, depth_field=prior)
    pred = res.calibration_pose
    assert pred is not None and pred["rot_deg"]["p90"] > pred["rot_deg"]["p50"] > 0
    # the actual error, aligned like the prediction: the mean small-motion increment removed
    from tofmetry.reconstruct import rotation_angle_deg
    from scipy.spatial.transform import Rotation
    w = np.array([Rotation.from_matrix((P @ np.linalg.inv(T))[:3, :3]).as_rotvec() for P, T in zip(res.poses, ring)])
    actual = np.degrees(np.linalg.norm(w - w.mean(0), axis=1)).max()
    assert rotation_angle_deg(res.poses[1] @ np.linalg.inv(ring[1])) > 0.1  # the tilt does move the poses
    assert 0.3 * pred["rot_deg"]["p50"] < actual < 2.5 * pred["rot_deg"]["p90"], (actual, pred)


def test_pose_spread_of_a_known_response():
    """One view, a response that rotates it by 1 mrad about z per unit coefficient, coefficient
    sigma 1: the whole set (view 0 fixed at 0) aligned on the object leaves each view half of it,
    |N(0, 1)| * 0.5 mrad; its median is 0.674 * 0.5 mrad."""
    resp = np.zeros((6, 1))
    resp[2, 0] = 1e-3
    out = pose_spread(resp, np.array([1.0]), 2, np.zeros((5, 3)), n_draws=20000)
    assert out["rot_deg"]["p50"] == pytest.approx(np.degrees(0.674 * 0.5e-3), rel=0.03)
    assert out["object_mm"]["p50"] == pytest.approx(0.0, abs=1e-9)  # points at the rotation centre


def test_pose_spread_adds_the_noise_of_the_poses():
    """The same response (field: 1 mrad about z per unit, sigma 1) plus the poses' noise, 1 mrad
    about z (sigma) independently: the aligned view keeps half of their sum, |N(0, 2)| * 0.5 mrad,
    so the median grows by sqrt(2); the field alone stays as it was."""
    resp = np.zeros((6, 1))
    resp[2, 0] = 1e-3
    cov = np.zeros((6, 6))
    cov[2, 2] = 1e-6
    out = pose_spread(resp, np.array([1.0]), 2, np.zeros((5, 3)), n_draws=20000, noise_cov=cov)
    assert out["rot_deg"]["p50"] == pytest.approx(np.degrees(0.674 * 0.5e-3), rel=0.03)
    assert out["with_noise"]["rot_deg"]["p50"] == pytest.approx(np.degrees(0.674 * 0.5e-3 * np.sqrt(2)), rel=0.03)
    # a covariance of another size is not used
    assert "with_noise" not in pose_spread(resp, np.array([1.0]), 2, np.zeros((5, 3)), noise_cov=np.eye(3))


def test_field_prior_rms_matches_its_parts():
    """The field's mean square over the image is offset^2 + shape_rms^2 (+ the tilt's)."""
    p = DepthFieldPrior((0.7, 0.58), 0.3e-3, 0.5e-3, degree=3)
    rng = np.random.default_rng(0)
    u, v = rng.uniform(-1, 1, (2, 20000))
    pts = np.column_stack([u * 0.7, v * 0.58, np.ones_like(u)])
    B = p.basis(pts)
    ms = np.mean((B * p.coefficient_sigmas()) ** 2) * B.shape[1]
    assert ms == pytest.approx(0.3e-3 ** 2 + 0.5e-3 ** 2, rel=0.05)


def test_field_prior_from_a_calibrations_folds():
    """The prior takes the largest central error and per-pixel systematic RMS of the folds where the
    object lies (one fold inside 830-994 mm, so the stations either side join it: 716, 966, 1214 mm;
    their centres are not on the 0.1 mm grid the local stations are rounded to), the image's half
    field of view, and the uncalibrated tilt only when the calibration did not calibrate it."""
    from tofmetry.reconstruct._calibration_support import depth_field_prior
    from tofmetry.sensor import CameraIntrinsics

    folds = [{"center_mm": c, "central_mm": e, "rms_systematic_mm": r}
             for c, e, r in ((715.98, 0.1, 0.2), (965.98, -0.14, 0.06), (1213.72, 0.2, 0.19), (1460.31, 0.4, 0.5))]
    pred = {"folds": folds, "interpolation": {"central_abs_mm": {"predicted": 0.3}}, "tilt_calibrated": False}
    intr = CameraIntrinsics(512, 424, 365.0, 365.0, 256.0, 212.0)
    p = depth_field_prior(pred, (830.0, 994.0), intr, tilt_sigma_mm=10.0)
    assert p is not None
    assert p.offset_sigma_m == pytest.approx(0.2e-3)
    assert p.shape_rms_m == pytest.approx(0.2e-3)  # not the 0.5 mm of the fold at 1460 mm
    assert p.half_extent == pytest.approx((256 / 365.0, 212 / 365.0))
    assert p.tilt_sigma_m == pytest.approx(10e-3)
    assert depth_field_prior(pred | {"tilt_calibrated": True}, (830.0, 994.0), intr, tilt_sigma_mm=10.0).tilt_sigma_m == 0
    # boards that found the tilt too small to measure bound it; a bound above the default is not taken
    bounded = pred | {"tilt_bound": {"bound_mm": [0.8, 1.4]}}
    assert depth_field_prior(bounded, (830.0, 994.0), intr, tilt_sigma_mm=10.0).tilt_sigma_m == pytest.approx(1.4e-3)
    wide = pred | {"tilt_bound": {"bound_mm": [0.8, 31.0]}}
    assert depth_field_prior(wide, (830.0, 994.0), intr, tilt_sigma_mm=10.0).tilt_sigma_m == pytest.approx(10e-3)
    assert depth_field_prior(None, (830.0, 994.0), intr) is None
