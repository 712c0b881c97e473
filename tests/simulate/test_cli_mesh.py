"""CLI of the simulator and the procedural balustrade mesh."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tofmetry.cli import app
from tofmetry.io import Capture


def test_cli_wall_refuses_overwrite_and_without(tmp_path):
    r = CliRunner()
    out = tmp_path / "wall"
    res = r.invoke(app, ["simulate", "wall", "-o", str(out), "--frames", "2", "--distance-mm", "1500",
                         "--without", "noise", "--without", "flying"])
    assert res.exit_code == 0, res.output
    cap = Capture(out / "capture")
    assert len(cap) == 2
    t = json.loads((out / "truth.json").read_text())
    assert "noise" not in t["error_model"]["enabled"] and "wiggling" in t["error_model"]["enabled"]
    # without noise two frames differ only by the warm-up wander (< 0.01 mm in 1 s) rounded to whole mm
    diff = cap.depth(0).astype(int) - cap.depth(1).astype(int)
    assert np.abs(diff).max() <= 1 and np.mean(diff != 0) < 0.05
    res = r.invoke(app, ["simulate", "wall", "-o", str(out), "--frames", "1"])
    assert res.exit_code != 0 and "refusing to overwrite" in str(res.exception)
    res = r.invoke(app, ["simulate", "wall", "-o", str(out), "--frames", "1", "--force", "--no-errors"])
    assert res.exit_code == 0, res.output
    assert len(Capture(out / "capture")) == 1


def test_cli_wall_dataset_and_bad_term(tmp_path):
    r = CliRunner()
    res = r.invoke(app, ["simulate", "wall-dataset", "-o", str(tmp_path / "wd"), "--frames", "1",
                         "--distance-mm", "2000", "--distance-mm", "1000"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "wd" / "stations.csv").read_text().splitlines()[1].startswith("d1000,1000")
    res = r.invoke(app, ["simulate", "noise", "-o", str(tmp_path / "n"), "--frames", "1", "--without", "wigling"])
    assert res.exit_code != 0 and "unknown error term" in str(res.exception)


def test_balustrade_mesh_watertight():
    o3d = pytest.importorskip("open3d")
    from tofmetry.simulate.meshes import balustrade_mesh

    v, f = balustrade_mesh()
    # closed and consistently oriented: every directed edge appears once and its reverse once
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = e[:, 0] * len(v) + e[:, 1]
    rkey = e[:, 1] * len(v) + e[:, 0]
    assert len(np.unique(key)) == len(key)
    assert np.isin(rkey, key).all()
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    assert 0.005 < volume < 0.016  # outward normals; less than the 0.4 x 0.2 x 0.2 m box (0.016 m^3)
    # Open3D's watertight / self-intersection tests are slow: run them on a coarser tessellation
    vc, fc = balustrade_mesh(n_along=41, n_around=24)
    mc = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vc), o3d.utility.Vector3iVector(fc))
    assert mc.is_watertight() and not mc.is_self_intersecting()
    np.testing.assert_allclose(v.max(0) - v.min(0), [0.40, 0.20, 0.20], atol=0.01)
    # nearly symmetric but not exactly: mirrored halves differ by < 1 cm
    left, right = v[v[:, 0] < -0.12], v[v[:, 0] > 0.12]
    rl, rr = np.hypot(left[:, 1], left[:, 2]).max(), np.hypot(right[:, 1], right[:, 2]).max()
    assert 0 < rr - rl < 0.01
