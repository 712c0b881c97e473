"""``tofmetry reconstruct --mat`` with a calibration that left the depth's tilt uncalibrated."""

from __future__ import annotations

import re

import numpy as np
from typer.testing import CliRunner

from tofmetry._shared.dot_mat import DotMat
from tofmetry.cli import app
from tofmetry.io import read_json
from tofmetry.io.mat_json import write_mat
from tofmetry.simulate import ErrorModel, datasets
from tofmetry.simulate.objects import make_object


def test_the_mat_measures_the_depth_tilt_the_walls_could_not_and_the_views_hold(small_cal, small_wall, tmp_path):
    """A wall calibration cannot see a depth tilt (each wall's plane is taken out). The scan's sensor
    carries one of (12, -8) mm per unit at 1 m; the walls' sensor is the same but for it. On the dot
    mat the dots measure the tilt their support planes show and take it off: every view's rotation
    then within 0.25 deg of the truth, in the mat's frame (measured 0.01-0.11 deg; with
    ``registration.mat_depth_tilt`` off, 0.32-0.52 deg). What they measure, (12.2, 14.2) +- (1.9,
    2.8), is the depth's effective tilt where the mat lies: its x part the deformation's plane over the
    image (11.1), its y part also the range and amplitude errors along the oblique support (the
    deformation's plane alone: -7.2), which the placements need taken off as well. The mm are not
    judged: this 5-station calibration leaves the depth about 1.3 % long at the mat, which the run warns
    of (the dots' size)."""
    em = ErrorModel().with_(wiggle_amps_mm=(4.5, 0.0, 0.0), deform_tilt_mm_1m=(12.0, -8.0))
    vase = make_object("vase", seed=5, size_m=0.25, painted=False)
    mat = DotMat(seed=12, yaw_deg=35.0)
    scan = datasets.scan(tmp_path / "scan", n_frames=2, mesh=(vase.vertices, vase.triangles), radius_m=0.9,
                         n_views=8, elevation_deg=45.0, errors=em, seed=2, mat=mat)
    write_mat(tmp_path / "mat.json", DotMat(seed=12))
    r = CliRunner().invoke(app, ["reconstruct", str(scan), "--calibration", str(small_cal), "--amplitude-reference",
                                 str(small_wall), "--mat", str(tmp_path / "mat.json"), "-o", str(tmp_path / "rec")])
    assert r.exit_code in (0, 3), r.output
    out = " ".join(r.output.split())
    assert "the dots measure the depth's tilt across the image" in out, out
    # the scale the calibration leaves, said: 1.3 % (the run's own reading before session 50; 1.42 +- 0.08 % since
    # the dots printed over another are left out), within 3 of its sigmas
    said = re.search(r"come out ([0-9.]+) % \+/- ([0-9.]+) % larger than printed", out)
    assert said, out
    assert abs(float(said[1]) - 1.3) < 3 * float(said[2]), said[0]
    doc = read_json(tmp_path / "rec" / "poses.json")
    mt = doc["diagnostics"]["mat_depth_tilt"]
    assert mt["n_views"] == 8 and mt["prior_sigma_mm"] == 10.0
    assert abs(mt["measured_mm"][0] - 11.1) < 3 * mt["measured_sigma_mm"][0]
    a = np.radians(mat.yaw_deg)
    world_to_mat = np.eye(4)
    world_to_mat[:2, :2] = [[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]
    truth = {v["name"]: world_to_mat @ np.asarray(v["camera_to_world"]) for v in read_json(scan / "truth.json")["views"]}
    for v in doc["views"]:
        E = np.asarray(v["camera_to_world"]) @ np.linalg.inv(truth[v["name"]])
        deg = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
        assert deg < 0.25, (v["name"], deg)


def test_the_scale_the_mat_holds_is_printed(capsys):
    """``reconstruct --mat`` says what the mat held of the model's scale against the joint fit
    (``diagnostics.mat_scale_hold``), and nothing where the fit was not weighed."""
    from tofmetry.cli.model import _print_mat

    fix = {"how": "dots", "n_dots": 20, "n_matched": 19, "rms_mm": 0.9, "sigma_deg": 0.04, "sigma_mm": 0.2,
           "tilt_sigma_deg": 0.04, "pattern_scale_pct": 0.1, "pattern_scale_sigma_pct": 0.2}
    hold = {"fit_scale_pct": 0.3832, "fit_sigma_pct": 0.1726, "mat_sigma_pct": 0.0412, "applied_pct": -0.3622,
            "held_sigma_pct": 0.0401}
    _print_mat({"00": fix}, {}, None, None, hold)
    out = " ".join(capsys.readouterr().err.split())  # the console writes to stderr
    assert "the mat holds the model's scale: the joint fit moved it +0.383 % (+-0.173 %)" in out
    assert "-0.362 % applied, +-0.040 % left" in out
    _print_mat({"00": fix}, {}, None, None, {"applied_pct": 0.0, "note": "scale and offset are not separable"})
    assert "holds the model's scale" not in capsys.readouterr().err


def test_the_mats_range_error_is_printed_with_what_was_done(capsys):
    """``reconstruct --mat`` says how far the dots' size put the mat's plane along the rays
    (``diagnostics.mat_range_offset``) and whether the placements were corrected for it."""
    from tofmetry.cli.model import _print_mat

    fix = {"how": "dots", "n_dots": 20, "n_matched": 19, "rms_mm": 0.9, "sigma_deg": 0.04, "sigma_mm": 0.2,
           "tilt_sigma_deg": 0.04, "pattern_scale_pct": 0.1, "pattern_scale_sigma_pct": 0.2}
    _print_mat({"00": fix}, {}, range_offset={"delta_mm": 0.9755, "sigma_mm": 0.1595, "views": 8, "significant": True,
                                              "applied": True})
    out = " ".join(capsys.readouterr().err.split())
    assert "the mat's plane +0.98 mm +- 0.16 mm off along the rays (8 views): beyond 3 sigma, taken out" in out
    _print_mat({"00": fix}, {}, range_offset={"delta_mm": -0.40, "sigma_mm": 0.57, "views": 8, "significant": False})
    assert "within 3 sigma, the placements left as they were" in " ".join(capsys.readouterr().err.split())
    _print_mat({"00": fix}, {}, range_offset={"delta_mm": -0.9, "sigma_mm": 0.2, "views": 8, "significant": True,
                                              "applied": False})
    assert "not taken out (registration.mat_range_from_dots is off)" in " ".join(capsys.readouterr().err.split())
