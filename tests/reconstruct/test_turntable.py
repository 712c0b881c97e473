"""A declared turntable's step as a prior of the pairwise registration (tofmetry.reconstruct._turntable)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tofmetry.errors import EstimationError
from tofmetry.io import ScanDataset, read_json
from tofmetry.reconstruct import ReconstructionConfig, ReconstructionPipeline, relative_pose_errors
from tofmetry.reconstruct._turntable import (
    TurntablePrior,
    expected_turns_deg,
    fit_turntable,
    turn_error_deg,
    turntable_poses,
)

UP = np.array([0.0, -0.94, -0.34])  # a table seen from above: normal up (-y), tilted towards the camera
UP /= np.linalg.norm(UP)


def _about(axis, deg, centre):
    """(4, 4) rotation by ``deg`` about the line through ``centre`` along ``axis`` (the turntable)."""
    R = Rotation.from_rotvec(np.radians(deg) * np.asarray(axis) / np.linalg.norm(axis)).as_matrix()
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, centre - R @ centre
    return T


def test_expected_turns_both_senses_modulo_a_full_turn():
    assert expected_turns_deg(2, 3, 60.0) == (60.0, 300.0)
    assert expected_turns_deg(0, 5, 60.0) == (300.0, 60.0)  # the closure of a 6-view circle: one step back
    assert expected_turns_deg(0, 6, 60.0) == (0.0, 0.0)
    assert TurntablePrior(0, 6, 60.0, 5.0, UP).seeds_deg() == (0.0,)


@pytest.mark.parametrize("sense", [1.0, -1.0])
def test_the_true_turn_passes_a_turned_over_match_does_not(sense):
    # true turn 60 deg about an axis 0.8 m ahead; the thin slab's false match is that turn + 180 deg
    centre = np.array([0.02, 0.1, 0.8])
    prior = TurntablePrior(2, 3, 60.0, 5.0, UP)
    true = _about(UP, sense * 60.0, centre)
    assert prior.error_deg(true) < 1e-9 and prior.allows(true)
    assert prior.error_deg(_about(UP, sense * 62.5, centre)) == pytest.approx(2.5, abs=1e-6)
    flipped = _about(UP, sense * 240.0, centre)  # -120 deg: 60 deg from the other sense's turn (-60)
    assert prior.error_deg(flipped) == pytest.approx(60.0, abs=1e-6) and not prior.allows(flipped)
    # a 60-degree turn about a tilted axis is not the turntable's either
    tilted = _about(UP + np.array([0.3, 0.0, 0.0]), sense * 60.0, centre)
    assert not prior.allows(tilted)


def test_without_a_support_plane_the_magnitude_of_the_turn_is_compared():
    centre = np.array([0.0, 0.0, 0.9])
    T = _about(np.array([0.2, -1.0, 0.1]), 57.0, centre)
    assert turn_error_deg(T, expected_turns_deg(0, 1, 60.0), None) == pytest.approx(3.0, abs=1e-6)
    assert turn_error_deg(T, expected_turns_deg(0, 2, 60.0), None) == pytest.approx(63.0, abs=1e-6)


def test_the_step_is_validated_by_the_config():
    cfg = ReconstructionConfig()
    assert cfg.registration.turntable_step_deg is None
    with pytest.raises(ValueError, match="turntable_step_deg"):
        type(cfg.registration).model_validate({"turntable_step_deg": 0.0})
    with pytest.raises(ValueError, match="turntable_step_deg"):
        type(cfg.registration).model_validate({"turntable_step_deg": 360.0})


def test_the_axis_and_sense_are_fitted_and_the_poses_put_on_the_turntable():
    # 8 views 45 deg apart about an axis 0.9 m ahead, turning clockwise seen from above (sense -1 about UP);
    # the pose graph's poses are off by up to 2 deg / 3 mm: the turntable's poses are exact again
    rng = np.random.default_rng(5)
    centre = np.array([0.03, 0.12, 0.9])
    true = [np.linalg.inv(_about(UP, -45.0 * k, centre)) for k in range(8)]  # camera-to-world, world = camera 0
    noisy = [true[0]] + [T @ _about(rng.normal(size=3), rng.uniform(-2, 2), centre + rng.normal(0, 0.003, 3))
                         for T in true[1:]]
    fit = fit_turntable([np.linalg.inv(P) for P in true[1:]], list(range(1, 8)), 45.0, UP)
    assert fit["sense"] == -1 and fit["residual_deg"] < 1e-6
    d = np.cross(fit["centre"] - centre, UP)  # the fitted point lies on the true axis
    assert np.linalg.norm(d) < 1e-9
    out, info = turntable_poses(np.array(noisy), list(range(8)), 45.0, UP)
    err = relative_pose_errors(out, true)
    assert err[:, 0].max() < 0.3 and err[:, 1].max() < 3.0, err  # the axis from 7 noisy views
    assert 1.0 < info["deviation_deg"] < 4.0 and info["sense"] == -1, info
    # views left out: their places in capture order count, not their rank
    out2, _ = turntable_poses(np.array([true[k] for k in (0, 2, 3, 7)]), [0, 2, 3, 7], 45.0, UP)
    np.testing.assert_allclose(out2, [true[k] for k in (0, 2, 3, 7)], atol=1e-9)


@pytest.fixture(scope="module")
def orbit_scan(tmp_path_factory):
    """8 views 45 deg apart on a circle (a turntable), ideal sensor (noise only), 2 frames."""
    from tofmetry.simulate import ErrorModel, datasets

    out = tmp_path_factory.mktemp("scan") / "scan"
    datasets.scan(out, n_views=8, n_frames=2, errors=ErrorModel.none().with_terms("noise"), seed=3)
    return out


def test_a_declared_turntable_registers_the_scan_as_well_as_without(orbit_scan):
    cfg = ReconstructionConfig()
    cfg.registration.turntable_step_deg = 45.0
    cfg.registration.turntable_accuracy_deg = 0.2
    res = ReconstructionPipeline(ScanDataset(orbit_scan), None, cfg).run()
    true = [v["camera_to_world"] for v in read_json(orbit_scan / "truth.json")["views"]]
    err = relative_pose_errors(res.poses, true)
    assert err[:, 0].max() < 0.5 and err[:, 1].max() < 3.0, err  # the bounds, as without the prior
    assert res.diagnostics["reliable"], res.diagnostics["reliability"]
    tt = res.diagnostics["turntable"]
    assert tt["bridged"] == [] and tt["residual_deg"] < 1.0 and tt["poses"]["deviation_deg"] < 1.0, tt
    assert all(e["method"] != "turntable-step" for e in res.edges)


def test_a_wrong_step_is_refused_or_flagged_with_its_reason(orbit_scan):
    # the views turn by 45 deg: no registration turns by 30 (refused), or only rejected ones do
    # (the axis fitted on them, the run flagged, the step named)
    cfg = ReconstructionConfig()
    cfg.registration.turntable_step_deg = 30.0
    try:
        res = ReconstructionPipeline(ScanDataset(orbit_scan), None, cfg).run()
    except EstimationError as exc:
        assert "declared turntable step (30 deg" in str(exc) and "45 deg" in str(exc), exc
    else:
        rel = res.diagnostics["reliability"]
        assert not rel["reliable"] and any("--turntable-step" in r for r in rel["reasons"]), rel["reasons"]


@pytest.mark.parametrize("args, name", [(["--turntable-step", "400"], "--turntable-step"),
                                        (["--turntable-step", "45", "--turntable-accuracy", "0"], "--turntable-accuracy")])
def test_the_cli_names_a_bad_turntable_option(orbit_scan, tmp_path, args, name):
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.errors import InputError

    r = CliRunner().invoke(app, ["reconstruct", str(orbit_scan), "--no-calibration", "-o", str(tmp_path / "o"), *args])
    assert isinstance(r.exception, InputError) and name in str(r.exception), r.output
    assert not (tmp_path / "o").exists()
