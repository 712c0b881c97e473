"""``tofmetry evaluate`` on files: outputs and clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.errors import InputError
from tofmetry.evaluate import sample_mesh
from tofmetry.io import write_ply


@pytest.fixture()
def files(tmp_path):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_box(0.2, 0.1, 0.08).subdivide_midpoint(2)
    V, F = np.asarray(m.vertices), np.asarray(m.triangles)
    write_ply(tmp_path / "ref.ply", V, faces=F)
    write_ply(tmp_path / "ref_mm.ply", V * 1000, faces=F)
    pts, nrm, _ = sample_mesh(V, F, 0.003, seed=0)
    write_ply(tmp_path / "model.ply", pts + 0.0005 * nrm)
    return tmp_path


def test_cli_evaluate_writes_outputs(files):
    r = CliRunner().invoke(app, ["evaluate", str(files / "model.ply"), "--reference", str(files / "ref.ply"),
                                 "-o", str(files / "ev"), "--thresholds-mm", "0.5,1,2"])
    assert r.exit_code == 0, r.output
    m = json.loads((files / "ev" / "metrics.json").read_text())
    assert set(m["stats"]["share_within"]) == {"0.5", "1", "2"}
    assert m["stats"]["mean_abs_mm"] < 0.6  # 0.5 mm offset; ICP may take up to ~0.1 mm of it
    for f in ("histogram.png", "deviation_render.png", "deviation.ply"):
        assert (files / "ev" / f).is_file()
    # the model is the reference pushed 0.5 mm outward, at its own scale
    sc = m["scale"]
    assert sc["separable"] and abs(sc["scale_error_pct"]) < 0.03 and abs(sc["offset_mm"] - 0.5) < 0.05, sc
    assert "scale against the reference: " in " ".join(r.output.split())


def test_cli_evaluate_reference_in_mm(files):
    r = CliRunner().invoke(app, ["evaluate", str(files / "model.ply"), "--reference", str(files / "ref_mm.ply"),
                                 "-o", str(files / "ev2")])
    assert isinstance(r.exception, InputError) and "millimetres" in str(r.exception)


def test_cli_evaluate_empty_reference(files):
    write_ply(files / "empty.ply", np.zeros((0, 3)))
    r = CliRunner().invoke(app, ["evaluate", str(files / "model.ply"), "--reference", str(files / "empty.ply"),
                                 "-o", str(files / "ev3")])
    assert isinstance(r.exception, InputError) and "empty" in str(r.exception)


def test_cli_evaluate_never_replaces_without_force(files):
    out = files / "ev_keep"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    args = ["evaluate", str(files / "model.ply"), "--reference", str(files / "ref.ply"), "-o", str(out)]
    r = CliRunner().invoke(app, args)
    assert isinstance(r.exception, InputError) and "--force" in str(r.exception)
    assert (out / "metrics.json").read_text() == "{}"
    r = CliRunner().invoke(app, args + ["--force"])
    assert r.exit_code == 0, r.output
    assert "stats" in json.loads((out / "metrics.json").read_text())


def test_the_reconstructions_predicted_scale_sits_beside_the_measured_one():
    from tofmetry.pipelines.evaluate import predicted_scale

    doc = {"scale": {"predicted_scale_sigma_pct": 0.1}}
    assert predicted_scale({"scale_error_pct": -0.15}, doc) == {"predicted_sigma_pct": 0.1,
                                                               "within_2_predicted_sigma": True}
    assert predicted_scale({"scale_error_pct": 0.25}, doc)["within_2_predicted_sigma"] is False
    # the measurement's own sigma counts too: 0.25 % measured +- 0.1 % is within 2 * hypot(0.1, 0.1)
    assert predicted_scale({"scale_error_pct": 0.25, "sigma_pct": 0.1}, doc)["within_2_predicted_sigma"] is True
    # a shape that cannot tell the scale from an offset, and a reconstruction that predicted nothing
    assert predicted_scale({"scale_error_pct": None}, doc)["within_2_predicted_sigma"] is None
    assert predicted_scale({"scale_error_pct": 0.1}, {"scale": None}) == {"predicted_sigma_pct": None,
                                                                         "within_2_predicted_sigma": None}



def test_the_scale_sentence_says_what_was_measured():
    from tofmetry.pipelines.evaluate import scale_summary

    sep = {"separable": True, "scale_error_pct": 0.1234, "sigma_pct": 0.0004, "offset_mm": -0.25, "offset_sigma_mm": 0.03}
    assert scale_summary(sep) == ("scale against the reference: +0.123 +- <0.001 % (surface offset -0.25 +- 0.03 mm)")
    ball = {"separable": False, "correlation": -0.999, "size_error_pct": 0.3, "size_sigma_pct": 0.002}
    assert "cannot tell a scale from a surface offset" in scale_summary(ball) and "+0.300 +- 0.002 %" in scale_summary(ball)
    beyond = sep | {"predicted_sigma_pct": 0.05, "within_2_predicted_sigma": False}
    assert scale_summary(beyond).endswith("predicted +-0.05 % (1 sigma): the measured scale is beyond 2 of its sigmas")
    assert scale_summary({"error": "too few points"}) == "scale against the reference: not measured (too few points)"
