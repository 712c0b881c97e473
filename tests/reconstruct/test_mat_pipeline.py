"""A plain vase of revolution on a printed dot mat: every view placed on the mat, the model in its frame.

Without the mat its views register equally well at any turn about its axis (the chain flags such
runs: yaw-free edges); on the mat each view is placed on its own, so the turn comes from the dots.
"""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.io import read_json
from tofmetry.io.mat_json import read_mat, write_mat
from tofmetry._shared.dot_mat import DotMat
from tofmetry.errors import InputError
from tofmetry.simulate import ErrorModel, datasets
from tofmetry.simulate.objects import make_object


def test_mat_json_round_trips_and_refuses_other_files(tmp_path):
    m = DotMat(seed=4, size_m=(0.42, 0.594))
    write_mat(tmp_path / "mat.json", m, "mat.png", 150.0)
    assert read_mat(tmp_path / "mat.json") == m
    (tmp_path / "other.json").write_text('{"format": "tofmetry-rig", "version": 1}')
    with pytest.raises(InputError, match="expected a 'tofmetry-dot-mat' file"):
        read_mat(tmp_path / "other.json")


def test_cli_mat_writes_an_image_and_its_layout(tmp_path):
    r = CliRunner().invoke(app, ["mat", "-o", str(tmp_path / "m"), "--seed", "9", "--paper", "a3", "--dpi", "60"])
    assert r.exit_code == 0, r.output
    m = read_mat(tmp_path / "m" / "mat.json")
    assert m.seed == 9 and m.size_m == (0.297, 0.42)
    r = CliRunner().invoke(app, ["mat", "-o", str(tmp_path / "m"), "--seed", "9"])
    assert r.exit_code != 0 and "already exists" in str(r.exception)


@pytest.mark.slow
def test_a_plain_vase_on_a_mat_is_placed_and_in_the_mats_frame(tmp_path):
    """Ideal sensor but for noise (2 frames): each view placed to the dots' quantisation, then refined
    on the vase; the poses hold the issue's gate (0.5 deg, 3 mm) in the mat's own frame, with no
    alignment to the truth but the mat's known turn."""
    vase = make_object("vase", seed=5, size_m=0.25, painted=False)
    mat = DotMat(seed=12, yaw_deg=35.0)
    scan = datasets.scan(tmp_path / "scan", n_frames=2, mesh=(vase.vertices, vase.triangles), radius_m=0.9,
                         n_views=8, elevation_deg=35.0, errors=ErrorModel.none().with_terms("noise"), seed=2, mat=mat)
    write_mat(tmp_path / "mat.json", DotMat(seed=12))  # the user's file: the layout, not how it lies
    r = CliRunner().invoke(app, ["reconstruct", str(scan), "--no-calibration", "--mat", str(tmp_path / "mat.json"),
                                 "-o", str(tmp_path / "rec")])
    assert r.exit_code == 0, r.output
    assert "views placed on the dot mat" in r.output and "the dot mat's" in " ".join(r.output.split())
    out = " ".join(r.output.split())
    assert "the dots measure the depth scale" in out and "NOT consistent" not in out  # exact depth: no warning
    mat_table = out.split("views placed on the dot mat")[1].split("the dots measure the depth scale")[0]
    assert " nan " not in mat_table  # no calibration: no tilt judged, its column left empty
    edges_table = out.split("registration edges")[1].split("views placed on the dot mat")[0]
    assert "mat" in edges_table and "nan" not in edges_table  # the mat's edges have no pose-graph residual
    doc = read_json(tmp_path / "rec" / "poses.json")
    assert doc["reliable"] is True
    assert all(v["verdict"]["verdict"] == "placed on the mat" for v in doc["views"]), doc["views"]
    a = np.radians(mat.yaw_deg)
    world_to_mat = np.eye(4)
    world_to_mat[:2, :2] = [[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]
    truth = {v["name"]: world_to_mat @ np.asarray(v["camera_to_world"]) for v in read_json(scan / "truth.json")["views"]}
    centre = world_to_mat[:3, :3] @ np.array([0.0, 0.0, 0.125])
    for v in doc["views"]:
        E = np.asarray(v["camera_to_world"]) @ np.linalg.inv(truth[v["name"]])
        deg = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
        mm = np.linalg.norm(E[:3, :3] @ centre + E[:3, 3] - centre) * 1e3
        assert deg < 0.5 and mm < 3.0, (v["name"], deg, mm)
