"""Observed-surface completeness: visibility of reference samples from the registered cameras."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tofmetry.evaluate import (
    CameraViews,
    EvaluationConfig,
    evaluate_model,
    observed_mask,
    sample_mesh,
)
from tofmetry.io.mesh import Geometry
from tofmetry.sensor import KINECT_V2


def _box(size, origin=(0.0, 0.0, 0.0)):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_box(*size).subdivide_midpoint(2)
    return np.asarray(m.vertices) + np.asarray(origin), np.asarray(m.triangles)


def _camera(at) -> np.ndarray:
    """Camera-to-world with the camera axes = world axes (looking +z) at ``at``."""
    T = np.eye(4)
    T[:3, 3] = at
    return T


CAM = CameraViews(np.stack([_camera((0.1, 0.05, -1.0))]), KINECT_V2.depth, 500.0, 4500.0)


def test_visibility_rules():
    V, F = _box((0.2, 0.1, 0.08))
    Vb, Fb = _box((0.6, 0.4, 0.01), (-0.2, -0.15, 0.3))  # a board behind the box
    mesh = (np.vstack([V, Vb]), np.vstack([F, Fb + len(V)]))
    pts = np.array([[0.1, 0.05, 0.0],     # front face of the box, facing the camera: seen
                    [0.1, 0.05, 0.08],    # back face: faces away
                    [0.1, 0.05, 0.3],     # board straight behind the box: occluded
                    [-0.18, -0.13, 0.3],  # board corner, beside the box's shadow: seen
                    [2.0, 0.05, 0.0],     # outside the field of view (x/z = 1.9)
                    [0.1, 0.05, -0.7]])   # 0.3 m from the camera: inside the 0.5 m minimum range
    nrm = np.array([[0, 0, -1.0], [0, 0, 1], [0, 0, -1], [0, 0, -1], [0, 0, -1], [0, 0, -1]])
    seen, _ = observed_mask(pts, nrm, CAM, mesh=mesh)
    assert seen.tolist() == [True, False, False, True, False, False]
    # without the mesh there is no occlusion test: the board point behind the box counts as seen
    assert observed_mask(pts, nrm, CAM)[0].tolist() == [True, False, True, True, False, False]
    # the alignment carries the cameras: moving the model frame 10 m back puts everything beyond 4.5 m
    T = np.eye(4)
    T[2, 3] = -10.0
    assert not observed_mask(pts, nrm, CAM, world_from_model=T, mesh=mesh)[0].any()


def test_completeness_observed_in_evaluation():
    """Model = the front face only, seen by one camera. The front face is 0.02 of the box's 0.088 m^2
    (22.7 %); at 5 mm the side faces' 5 mm bands along its 0.6 m perimeter count too (0.003 m^2):
    plain completeness ~ 0.261; observed-surface completeness ~ 1 (sampling noise ~1 %)."""
    V, F = _box((0.2, 0.1, 0.08))
    pts, nrm, _ = sample_mesh(V, F, 0.002, seed=0)
    front = pts[nrm[:, 2] < -0.9]
    cfg = EvaluationConfig(icp=False, thresholds_mm=(1.0, 5.0), edge_trim_mm=0.0)
    doc = {"views": [{"name": "00", "camera_to_world": CAM.poses[0].tolist()}], "intrinsics": KINECT_V2.depth.to_dict(),
           "working_range_mm": [500.0, 4500.0]}
    ev = evaluate_model(Geometry(front), Geometry(V, F), cfg, poses=json.loads(json.dumps(doc)))
    d = ev.to_dict()
    assert d["completeness"]["5"]["completeness"] == pytest.approx(0.261, abs=0.02)
    assert d["completeness_observed"]["5"]["completeness"] > 0.97
    assert d["observed_surface"]["observed_share"] == pytest.approx(0.227, abs=0.02)
    assert set(d["completeness_observed"]) == set(d["completeness"])
    assert evaluate_model(Geometry(front), Geometry(V, F), cfg).to_dict()["completeness_observed"] is None


def test_poses_document_errors():
    from tofmetry.errors import InputError

    with pytest.raises(InputError, match="intrinsics"):
        CameraViews.from_document({"views": [{"name": "0", "camera_to_world": np.eye(4).tolist()}]}, "p.json")
    with pytest.raises(InputError, match="views"):
        CameraViews.from_document({"edges": []}, "p.json")


def test_cli_evaluate_with_poses(tmp_path):
    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.io import write_ply

    V, F = _box((0.2, 0.1, 0.08))
    pts, nrm, _ = sample_mesh(V, F, 0.002, seed=0)
    write_ply(tmp_path / "ref.ply", V, faces=F)
    write_ply(tmp_path / "model.ply", pts[nrm[:, 2] < -0.9])
    (tmp_path / "poses.json").write_text(json.dumps({
        "views": [{"name": "00", "camera_to_world": CAM.poses[0].tolist()}], "intrinsics": KINECT_V2.depth.to_dict(),
        "working_range_mm": [500.0, 4500.0]}))
    r = CliRunner().invoke(app, ["evaluate", str(tmp_path / "model.ply"), "--reference", str(tmp_path / "ref.ply"),
                                 "-o", str(tmp_path / "ev"), "--no-icp", "--poses", str(tmp_path / "poses.json")])
    assert r.exit_code == 0, r.output
    m = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert m["completeness_observed"]["5"]["completeness"] > 0.97 and "observed-surface" in r.output


def test_ground_prior_fixes_the_roll_of_a_symmetric_object():
    """A cylinder lying on the ground matches itself at any roll about its axis; with the
    reconstruction's support plane and the reference's down direction, the alignment must put
    the model's support plane on the reference ground (normal within 10 deg, height within 15 mm)."""
    import open3d as o3d

    c = o3d.geometry.TriangleMesh.create_cylinder(radius=0.04, height=0.3, resolution=40, split=4)
    V = np.asarray(c.vertices) @ np.array([[0, 0, 1.0], [0, 1, 0], [-1, 0, 0]]).T + [0, 0, 0.04]  # axis x, on z = 0
    F = np.asarray(c.triangles)
    # model frame = a camera 1 m away looking at it from 30 deg elevation (rotation about x by 120 deg)
    a = np.radians(120.0)
    M = np.eye(4)
    M[:3, :3] = [[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]
    M[:3, 3] = [0.0, 0.3, 0.9]
    Vm = V @ M[:3, :3].T + M[:3, 3]
    n = M[:3, :3] @ [0, 0, 1.0]
    plane = np.r_[n, -n @ M[:3, 3]]
    cams = CameraViews(np.stack([np.eye(4)]), KINECT_V2.depth, 500.0, 4500.0, ("00",), plane)
    ev = evaluate_model(Geometry(Vm, F), Geometry(V, F), EvaluationConfig(align=True, exclude_normal=(0, 0, -1), sample_spacing_mm=2.0),
                       poses=cams)
    T = ev.alignment.transform
    assert np.degrees(np.arccos(np.clip((T[:3, :3] @ n)[2], -1, 1))) < 10.0
    assert abs((T[:3, :3] @ (-plane[3] * n) + T[:3, 3])[2]) < 0.015
    assert ev.info["alignment_prior"] is not None and ev.stats_all.mean_abs_mm < 0.5
