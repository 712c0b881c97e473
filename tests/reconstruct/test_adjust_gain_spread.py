"""The poses' predicted spread under the depth gain a calibration can leave between its stations
(the range term of the depth-field prior): a range error is the same in every view, and its linear
part over the object's depth stretches each view along its own line of sight."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tofmetry.reconstruct import global_adjust
from tofmetry.reconstruct._adjust_field import DepthFieldPrior

from .test_adjust import _views, ring  # noqa: F401 (the fixture)

GAIN = 0.006  # 0.6 % about 1 m: 0.6 mm over +-0.1 m of depth
Z_REF = 1.0


def _aligned_worst_deg(poses, truth) -> float:
    """Worst view's rotation error with the mean small-motion increment removed (as the prediction
    aligns the whole set on the object)."""
    w = np.array([Rotation.from_matrix((P @ np.linalg.inv(T))[:3, :3]).as_rotvec() for P, T in zip(poses, truth)])
    return float(np.degrees(np.linalg.norm(w - w.mean(0), axis=1)).max())


@pytest.fixture(scope="module")
def stretched(ring):
    return _views(ring, GAIN, Z_REF, np.random.default_rng(5))


def _prior(gain_sigma: float) -> DepthFieldPrior:
    return DepthFieldPrior((0.6, 0.5), 0.0, 0.0, degree=0, gain_sigma=gain_sigma, z_ref_m=Z_REF)


def test_the_gain_term_predicts_the_stretchs_pose_error(ring, stretched):
    """Noise-free views of the ellipsoid stretched by a 0.6 % gain, fitted without a gain from the
    true poses: the poses take up the stretch, and the spread predicted for a gain of that size lies
    around it (the actual worst view between 0.3 times the predicted median and 2.5 times its 90th
    percentile, the tilt test's band: one draw of |N(0, 1)|-like spreads). Without the range term
    the prior has nothing of this size (guards against passing for the wrong reason)."""
    res = global_adjust(stretched, ring, Z_REF, estimate_gain=False, depth_field=_prior(GAIN))
    actual = _aligned_worst_deg(res.poses, ring)
    pred = res.calibration_pose["rot_deg"]
    assert actual > 0.05, actual  # the stretch does move the poses
    assert 0.3 * pred["p50"] < actual < 2.5 * pred["p90"], (actual, pred)
    none = global_adjust(stretched, ring, Z_REF, estimate_gain=False, depth_field=_prior(0.0))
    assert none.calibration_pose["rot_deg"]["p90"] < 0.01 * actual, none.calibration_pose


def test_an_estimated_gain_takes_up_its_own_term(ring, stretched):
    """With the gain estimated, a gain in the field moves the estimate, not the poses: the
    response passes through the normal matrix the fit solved, so the predicted spread collapses."""
    off = global_adjust(stretched, ring, Z_REF, estimate_gain=False, depth_field=_prior(GAIN))
    on = global_adjust(stretched, ring, Z_REF, estimate_gain=True, depth_field=_prior(GAIN))
    assert on.gain_estimated, on.gain_note
    assert on.calibration_pose["rot_deg"]["p90"] < 0.1 * off.calibration_pose["rot_deg"]["p90"], \
        (on.calibration_pose["rot_deg"], off.calibration_pose["rot_deg"])


def test_the_basis_is_the_gains_displacement():
    """The range column is ``Z - z_ref`` [m] (a gain g moves Z by g (Z - z_ref)), after the image
    terms, and its sigma is the gain's; with gain_sigma 0 there is no such column."""
    p = DepthFieldPrior((0.6, 0.5), 1e-3, 0.0, degree=0, gain_sigma=0.01, z_ref_m=0.8)
    pts = np.array([[0.0, 0.0, 0.7], [0.1, -0.1, 0.9]])
    np.testing.assert_allclose(p.basis(pts), [[1.0, -0.1], [1.0, 0.1]])
    np.testing.assert_allclose(p.coefficient_sigmas(), [1e-3, 0.01])
    q = DepthFieldPrior((0.6, 0.5), 1e-3, 0.0, degree=0)
    assert q.basis(pts).shape == (2, 1) and q.coefficient_sigmas().shape == (1,)


def test_the_calibrations_gain_enters_the_prior_when_asked():
    """From a calibration's folds: the gain's sigma is their central error over half the station
    spacing (0.3 mm over 125 mm, the folds' quadratic mean being the predicted 0.3 mm), only when
    the adjustment's z_ref is given."""
    from tofmetry.reconstruct._calibration_support import depth_field_prior
    from tofmetry.sensor import CameraIntrinsics

    folds = [{"center_mm": c, "central_mm": 0.3, "rms_systematic_mm": 0.2} for c in (700.0, 950.0, 1200.0)]
    pred = {"folds": folds, "interpolation": {"central_abs_mm": {"predicted": 0.3}}, "tilt_calibrated": True}
    intr = CameraIntrinsics(512, 424, 365.0, 365.0, 256.0, 212.0)
    with_gain = depth_field_prior(pred, (800.0, 1000.0), intr, z_ref_m=0.9)
    assert with_gain.gain_sigma == pytest.approx(0.3 / 125.0) and with_gain.z_ref_m == 0.9
    assert depth_field_prior(pred, (800.0, 1000.0), intr).gain_sigma == 0.0
