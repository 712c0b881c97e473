"""Intrinsics: outlier-view rejection, k-fold cross-validation, and the simulator target (issue #4)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tofmetry.calibrate._intrinsics import (
    board_object_points, calibrate_intrinsics, coverage_mask, cross_validate_intrinsics, ray_difference_px,
)
from tofmetry.sensor import KINECT_V2

INTR = KINECT_V2.depth
BOARD, SQ = (9, 6), 50.0
NOISE_PX = 0.05


def _views(n, seed):
    """Exact corners of n boards spread over the image (projected with the true camera) + noise."""
    from tofmetry.simulate.poses import board_poses

    rng = np.random.default_rng(seed)
    obj = board_object_points(BOARD, SQ) / 1000.0
    out = []
    for T in board_poses(n, INTR, *BOARD, SQ / 1000.0, rng):
        out.append(INTR.project(obj @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, NOISE_PX, (len(obj), 2)))
    return out


def test_outlier_view_rejected_and_cross_validated():
    corners = _views(12, 3)
    names = [f"v{k:02d}" for k in range(12)]
    bad = corners[5].copy()
    bad[:9] += 3.0              # a row of mis-detected corners (cf. the real recording's 0010/0011)
    corners[5] = bad
    res = calibrate_intrinsics(corners, names, BOARD, SQ, (INTR.width, INTR.height), leave_one_out=True)
    assert res.rejected_views == ["v05"] and "v05" not in res.used and res.rejected_rms_px["v05"] > 1.0
    # kept views: 2-D noise RMS 0.05 sqrt(2) = 0.071 px times sqrt(1 - dof/obs) ~ 0.97
    assert res.rms_px == pytest.approx(0.069, abs=0.01)
    assert any("rejected 1 view" in w for w in res.warnings)
    assert set(res.influence) == set(res.used)
    cv = cross_validate_intrinsics(corners, BOARD, SQ, (INTR.width, INTR.height), k=4, exclude=[5])
    # held-out views: their own noise (0.071 px, 6 pose dof of 108 values) plus the intrinsics'
    # error from 8-9 training views (a few hundredths of a pixel)
    assert 0.06 < cv["rms_px"] < 0.09 and cv["k"] == 4 and 5 not in cv["views"]


def test_simulated_default_set_meets_the_intrinsics_target(tmp_path):
    """Issue #4: 20 simulated IR images (noise, vignetting, anti-aliasing on) -> intrinsics within
    0.5 px of back-projection error over the covered image area."""
    from tofmetry.pipelines import intrinsics_from_images, write_intrinsics_report
    from tofmetry.sensor import CameraIntrinsics
    from tofmetry.simulate import datasets

    out = datasets.checkerboard_images(tmp_path / "cb", n_images=20, seed=0)
    truth = json.loads((out / "truth.json").read_text())
    true = CameraIntrinsics.from_dict(truth["true_intrinsics"])
    run = intrinsics_from_images(out, BOARD, SQ, leave_one_out=False)
    res = run.result
    assert len(res.used) >= 18 and not res.warnings       # the boards cover the image: no coverage warning
    covered = coverage_mask([c for n, c in zip(run.names, run.corners) if n in res.used], true.shape)
    d = ray_difference_px(true, res.intrinsics, covered)
    # The target itself (issue #4) is 0.5 px, read as the RMS over the covered area. Measured on
    # this default set: RMS 0.24 px, max 0.34 px (seeds 0-2 and 15/20/25 images: RMS 0.03-0.46 px,
    # see the report); the corner error is ~0.1 px per corner, the rest is its propagation.
    assert np.sqrt(np.nanmean(d ** 2)) < 0.5
    assert covered.mean() > 0.5
    # held-out views (5-fold): corner noise ~0.1 px dominates
    assert run.cv["rms_px"] < 0.15
    files = write_intrinsics_report(run, tmp_path / "rep")
    assert {f.name for f in files} == {"intrinsics_report.json", "coverage.png", "per_image.png"}
