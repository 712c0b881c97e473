"""Reconstruction on simulated scans: registration correctness, errors, CLI, end-to-end accuracy."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tofmetry.errors import InputError, SensorMismatchError
from tofmetry.io import ScanDataset, read_json, read_ply
from tofmetry.reconstruct import (
    ReconstructionPipeline,
    relative_pose_errors,
    write_reconstruction,
)


def _true_poses(scan):
    return [v["camera_to_world"] for v in read_json(scan / "truth.json")["views"]]


@pytest.fixture(scope="module")
def ideal_scan(tmp_path_factory):
    """8 views, 2 frames, ideal sensor (quantisation + noise only): registration must be exact
    up to the noise; nothing here is calibrated away."""
    from tofmetry.simulate import ErrorModel, datasets

    out = tmp_path_factory.mktemp("scan") / "scan"
    datasets.scan(out, n_views=8, n_frames=2, errors=ErrorModel.none().with_terms("noise"), seed=3)
    return out


def test_registration_ideal_sensor(ideal_scan, tmp_path):
    ds = ScanDataset(ideal_scan)
    res = ReconstructionPipeline(ds, None).run()
    err = relative_pose_errors(res.poses, _true_poses(ideal_scan))
    print("ideal sensor, rotation [deg] / translation [mm] per view:", err.round(3).tolist())
    # with only ~1 mm noise (2-frame mean) and no bias, pairwise ICP residuals are sub-mm:
    # the task's bounds (0.5 deg, 3 mm) hold with margin
    assert err[:, 0].max() < 0.5, err
    assert err[:, 1].max() < 3.0, err
    assert sum(e["accepted"] for e in res.edges) >= 8
    assert res.diagnostics["reliable"], res.diagnostics["consistency"]
    adj = res.diagnostics["adjustment"]  # the depth gain is not estimated by default
    assert adj["depth_gain"] == 0.0 and not adj["gain_estimated"] and adj["iterations"] >= 1, adj
    write_reconstruction(tmp_path / "rec", res)
    d = json.loads((tmp_path / "rec" / "poses.json").read_text())
    assert [v["name"] for v in d["views"]] == ds.names
    # world frame: the support plane is z = 0 (normal up), the object above it
    np.testing.assert_allclose(d["support_plane_world"], [0, 0, 1, 0], atol=1e-9)
    assert np.median(read_ply(tmp_path / "rec" / "points.ply")["points"][:, 2]) > 0.02
    assert all(v["verdict"]["verdict"] == "verified" for v in d["views"])
    p = read_ply(tmp_path / "rec" / "points.ply")
    assert "normals" in p and len(p["points"]) > 1000
    # no colour frames: no colour, no colour flag, nothing reported (as before colour existed)
    assert "colors" not in p and "colored" not in p and d["color"] is None and res.colours is None
    m = read_ply(tmp_path / "rec" / "mesh.ply")
    assert len(m["faces"]) > 1000
    with pytest.raises(InputError, match="already exists"):
        write_reconstruction(tmp_path / "rec", res)


def test_calibration_for_another_sensor_refused(ideal_scan):
    from tofmetry.calibrate.board import constant_shift_calibration
    from tofmetry.sensor import KINECT_V2

    cal = constant_shift_calibration(0.0, KINECT_V2.depth, sensor="azure_kinect")
    with pytest.raises(SensorMismatchError, match="view 00.*azure_kinect"):
        ReconstructionPipeline(ScanDataset(ideal_scan), cal).load_views()


def test_cli_reconstruct_requires_calibration_choice(ideal_scan, tmp_path):
    from typer.testing import CliRunner

    from tofmetry.cli import app

    r = CliRunner().invoke(app, ["reconstruct", str(ideal_scan), "-o", str(tmp_path / "o")])
    assert isinstance(r.exception, InputError) and "--no-calibration" in str(r.exception)


@pytest.mark.slow
def test_end_to_end_full_errors(tmp_path):
    """All error terms on, calibration fitted by the calibration pipeline on a simulated wall
    dataset (not the truth); then reconstruct + evaluate through the CLI.

    With the amplitude-bias correction referenced on the same wall, ``k`` measured on a board
    (its uncertainty is the prior of the scan's own correction ``dk``), and the global adjustment
    with its pose prior; the depth gain is not estimated (the default since 2026-11-25: with ``dk``
    weighed at the data's inflated uncertainty it no longer walks, which the gain had hidden).
    Asserted: the issue's bounds on registration (rotation < 0.5 deg, translation < 3 mm for
    every view; measured 0.09 deg / 1.6 mm on seeds 0 and 1 with 10 frames) and on the model
    (mean |d| <= 1.0 mm, std <= 1.2 mm, p95 <= 3 mm, max <= 8 mm after edge trimming),
    completeness at 5 mm >= 90 % over the surface the registered cameras could see (the
    underside and occluded parts of the reference cannot be modelled; over the whole reference
    ~87 % measured, asserted > 80 %).
    """
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.simulate import datasets
    from tofmetry.simulate.family import default_sensor

    scan = datasets.scan(tmp_path / "scan", n_views=8, n_frames=5, seed=0)
    wall = datasets.wall_dataset(tmp_path / "wall", distances_mm=(800, 1000, 1250, 1500, 2000), n_frames=10, seed=1)
    board = datasets.materials(tmp_path / "board", n_frames=5, distance_m=1.0, seed=2)  # k measured, not assumed
    run = CliRunner()
    r = run.invoke(app, ["calibrate", "depth", str(wall), "-o", str(tmp_path / "cal.npz"), "--reference-offset-mm", "20"])
    assert r.exit_code == 0, r.output
    r = run.invoke(app, ["reconstruct", str(scan), "--calibration", str(tmp_path / "cal.npz"), "-o", str(tmp_path / "rec"),
                         "--amplitude-reference", str(wall), "--amplitude-board", str(board)])
    assert r.exit_code == 0, r.output
    slope = read_json(tmp_path / "rec" / "poses.json")["diagnostics"]["amplitude_slope"]
    k_true = default_sensor().errors.amplitude_slope_mm_per_ln()
    assert slope["calibrated"] and len(slope["boards"]) == 1 and 0 < slope["sigma_mm_per_ln"] < 0.5, slope
    assert abs(slope["k_mm_per_ln"] - k_true) < 3 * slope["sigma_mm_per_ln"] + 0.05, (slope, k_true)
    assert "amplitude coefficient measured on 1 board(s)" in r.output
    out = " ".join(r.output.split())  # rich wraps long lines
    assert "predicted pose accuracy from the depth calibration's residual (with a depth gain of +-" in out, out
    assert "between its stations) and the views' noise: worst view" in out, out
    assert "support planes: 8 views held to one plane" in out and ", poses +-" in out, out
    budget = read_json(tmp_path / "rec" / "poses.json")["diagnostics"]["scale"]["budget"]
    assert {"noise", "field"} <= budget["poses"].keys() and budget["sigma"] >= budget["sigma_poses_held"], budget
    poses = np.array([v["camera_to_world"] for v in read_json(tmp_path / "rec" / "poses.json")["views"]])
    err = relative_pose_errors(poses, _true_poses(scan))
    assert err[:, 0].max() < 0.5, err
    assert err[:, 1].max() < 3.0, err
    # the model is in the support-plane world frame: model -> reference = T0 @ inv(world_from_first_camera)
    T0 = np.array(read_json(scan / "truth.json")["views"][0]["camera_to_world"])
    W = np.array(read_json(tmp_path / "rec" / "poses.json")["world_from_first_camera"])
    (tmp_path / "init.json").write_text(json.dumps({"transform": (T0 @ np.linalg.inv(W)).tolist()}))
    r = run.invoke(app, ["evaluate", str(tmp_path / "rec" / "mesh.ply"), "--reference", str(scan / "reference.ply"),
                         "-o", str(tmp_path / "ev"), "--init-transform", str(tmp_path / "init.json"),
                         "--exclude-normal", "0,0,-1", "--poses", str(tmp_path / "rec" / "poses.json")])
    assert r.exit_code == 0, r.output
    m = read_json(tmp_path / "ev" / "metrics.json")
    assert read_json(tmp_path / "rec" / "poses.json")["reliable"] is True
    # the observed surface is a subset of the reference: completeness over it cannot be lower
    assert m["completeness_observed"]["5"]["completeness"] >= m["completeness"]["5"]["completeness"]
    assert m["completeness_observed"]["5"]["completeness"] >= 0.9, m["completeness_observed"]
    st = m["stats_trimmed"]
    assert st["mean_abs_mm"] <= 1.0 and st["std_signed_mm"] <= 1.2, st
    assert st["percentiles_abs_mm"]["p95"] <= 3.0 and st["max_abs_mm"] <= 8.0, st
    assert m["completeness"]["5"]["completeness"] > 0.8, m["completeness"]


def test_cli_reconstruct_with_a_plan(ideal_scan, tmp_path):
    """``tofmetry reconstruct --plan``: a plan made for the scanned object's size (``tofmetry plan
    --size``, its bounding box from the reference) is read back after the reconstruction; the views
    as registered (8 at the scan's elevation) are set beside the planned ones, printed and written
    to poses.json. A plan.json that is not one stops the command before any work."""
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.io.mesh import read_geometry

    ref = read_geometry(ideal_scan / "reference.ply", "reference")
    w, d, h = np.ptp(ref.points, axis=0)
    run = CliRunner()
    r = run.invoke(app, ["plan", "--size", f"{w:.3f},{d:.3f},{h:.3f}", "-o", str(tmp_path / "plan.json")])
    assert r.exit_code == 0, r.output
    r = run.invoke(app, ["reconstruct", str(ideal_scan), "--no-calibration", "-o", str(tmp_path / "rec"),
                         "--plan", str(tmp_path / "plan.json"), "--allow-unreliable", "--onto-views"])
    assert r.exit_code == 0, r.output
    out = " ".join(r.output.split())
    assert "plan: views taken: 8 views at" in out and "the planned ones" in out, out
    assert "surface moved onto the views' points:" in out, out  # --onto-views, said
    pf = json.loads((tmp_path / "rec" / "poses.json").read_text())["diagnostics"]["plan"]
    assert pf["taken"]["layout"]["n_views"] == 8 and 0.0 < pf["taken"]["on_size"] <= 1.0
    assert pf["planned"]["n_views"] == pf["planned"]["layout"]["n_views"] >= 8
    assert "differs from the plan's object" not in pf["summary"]  # planned for this object's size
    (tmp_path / "bad.json").write_text("{}")
    r = run.invoke(app, ["reconstruct", str(ideal_scan), "--no-calibration", "-o", str(tmp_path / "rec2"),
                         "--plan", str(tmp_path / "bad.json")])
    assert isinstance(r.exception, InputError) and "not a plan.json" in str(r.exception)
    assert not (tmp_path / "rec2").exists()
