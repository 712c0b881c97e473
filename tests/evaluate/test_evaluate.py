"""Evaluation: synthetic truth (a box mesh) -> perturbed model -> recovered deviations."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tofmetry.errors import InputError
from tofmetry.evaluate import (
    EvaluationConfig,
    check_units,
    completeness_fscore,
    deviation_stats,
    distances_to_cloud,
    distances_to_mesh,
    evaluate_model,
    sample_mesh,
    sharp_edge_samples,
    write_evaluation,
)
from tofmetry.io import read_ply, write_ply
from tofmetry.io.mesh import Geometry, read_geometry


def box_mesh(size=(0.3, 0.2, 0.12), subdiv=2):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_box(*size).subdivide_midpoint(subdiv)
    return np.asarray(m.vertices).copy(), np.asarray(m.triangles).astype(np.int64)


@pytest.fixture(scope="module")
def box():
    return box_mesh()


def test_signed_distance_recovers_normal_offsets(box):
    V, F = box
    pts, nrm, _ = sample_mesh(V, F, 0.004, seed=1)
    rng = np.random.default_rng(0)
    off = rng.uniform(-0.004, 0.004, len(pts))
    # keep away from the box edges, where the closest face can change
    inner = np.all((pts > 0.01) | (np.abs(nrm) > 0.5), axis=1) & np.all((pts < np.array([0.29, 0.19, 0.11])) | (np.abs(nrm) > 0.5), axis=1)
    q = pts[inner] + nrm[inner] * off[inner, None]
    cp = distances_to_mesh(q, V, F)
    # float32 inside Open3D: ~1e-7 m relative to 0.3 m coordinates
    np.testing.assert_allclose(cp.distance, off[inner], atol=2e-6)


def test_cloud_to_cloud_point_to_plane_sign(box):
    V, F = box
    pts, nrm, _ = sample_mesh(V, F, 0.002, seed=2)
    q = pts[:500] + 0.001 * nrm[:500]
    d = distances_to_cloud(q, pts, nrm).distance
    assert np.all(d > 0) and abs(np.median(d) - 0.001) < 1e-4


def test_deviation_stats_known_values():
    d = np.array([-2.0, -1.0, 0.0, 1.0, 2.0]) * 1e-3
    s = deviation_stats(d, thresholds_mm=(1.0, 2.0))
    assert s.mean_signed_mm == pytest.approx(0.0)
    assert s.mean_abs_mm == pytest.approx(1.2)
    assert s.rms_mm == pytest.approx(np.sqrt(2.0))
    assert s.max_abs_mm == pytest.approx(2.0)
    assert s.share_within == {"1": pytest.approx(0.6), "2": pytest.approx(1.0)}
    c = completeness_fscore(d, np.zeros(4), (1.0,))
    assert c["1"]["precision"] == pytest.approx(0.6) and c["1"]["completeness"] == 1.0
    assert c["1"]["fscore"] == pytest.approx(2 * 0.6 / 1.6)


def test_units_mm_detected(box):
    V, _ = box
    check_units(V, "reference")  # metres: fine
    with pytest.raises(InputError, match="millimetres"):
        check_units(V * 1000.0, "reference ref.ply")


def test_sharp_edges_of_a_box(box):
    V, F = box
    e = sharp_edge_samples(V, F, 45.0, spacing_m=0.001)
    # every sample lies on one of the 12 box edges: two coordinates at their min/max
    lo, hi = V.min(0), V.max(0)
    on_bound = (np.isclose(e, lo, atol=1e-9) | np.isclose(e, hi, atol=1e-9)).sum(1)
    assert len(e) > 0 and np.all(on_bound >= 2)
    # total edge length 4 * (0.3 + 0.2 + 0.12) = 2.48 m at 1 mm -> ~2480 samples (+ segment ends)
    assert 2400 < len(e) < 4000


def test_evaluate_noisy_shifted_model(box):
    """Model = reference samples + N(0, 1 mm) along the normal, moved by 2 mm / 1 deg.

    ICP must undo the motion; then mean |d| = sigma * sqrt(2/pi) = 0.80 mm and std = 1 mm
    (sampling error of ~40k points is < 0.01 mm; allow 0.05 mm for the residual ICP error).
    """
    V, F = box
    pts, nrm, _ = sample_mesh(V, F, 0.002, seed=3)
    rng = np.random.default_rng(4)
    noisy = pts + nrm * rng.normal(0, 0.001, len(pts))[:, None]
    a = np.radians(1.0)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    model = Geometry(noisy @ R.T + np.array([0.002, -0.001, 0.0015]), source="model")
    res = evaluate_model(model, Geometry(V, F, source="box"), EvaluationConfig(edge_trim_mm=3.0, exclude_normal=(0, 0, -1)))
    s = res.stats_trimmed
    assert s.mean_abs_mm == pytest.approx(np.sqrt(2 / np.pi), abs=0.05)
    assert s.std_signed_mm == pytest.approx(1.0, abs=0.05)
    assert abs(s.mean_signed_mm) < 0.05
    assert 0 < res.on_edge.mean() < 0.2  # a 3 mm band along 2.48 m of edges out of 0.25 m^2
    # the bottom face (normal -z) is excluded from completeness: 0.3*0.2 of 0.252 m^2
    assert res.info["n_reference_samples"] < 0.8 * len(sample_mesh(V, F, 0.001)[0])
    assert res.completeness["5"]["completeness"] > 0.99


def test_write_evaluation_outputs(tmp_path, box):
    V, F = box
    pts, nrm, _ = sample_mesh(V, F, 0.004, seed=5)
    model = Geometry(pts + nrm * 0.001, source="m")
    res = evaluate_model(model, Geometry(V, F, source="box"), EvaluationConfig(icp=False))
    paths = write_evaluation(tmp_path / "ev", res, title="box")
    m = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert m["color_scale"]["max_mm"] == 5.0 and m["stats"]["mean_signed_mm"] == pytest.approx(1.0, abs=1e-3)
    ply = read_ply(paths["deviation_ply"])
    np.testing.assert_allclose(ply["deviation_mm"], res.deviation_m * 1e3, atol=1e-4)
    assert ply["colors"].shape == (len(pts), 3)
    for k in ("histogram", "render"):
        assert paths[k].stat().st_size > 10_000


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl"])
def test_read_geometry_round_trip(tmp_path, box, suffix):
    import open3d as o3d

    V, F = box
    p = tmp_path / f"box{suffix}"
    if suffix == ".ply":
        write_ply(p, V, faces=F)
    else:
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
        m.compute_triangle_normals()
        o3d.io.write_triangle_mesh(str(p), m)
    g = read_geometry(p, "reference")
    assert g.is_mesh and len(g.faces) == len(F)
    # STL stores one vertex per corner: compare the vertex sets
    np.testing.assert_allclose(np.unique(g.points.round(6), axis=0), np.unique(V.round(6), axis=0), atol=1e-6)


def test_read_geometry_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_geometry(tmp_path / "nope.ply", "reference")
    (tmp_path / "x.xyz").write_text("1 2 3\n")
    with pytest.raises(InputError, match="unsupported"):
        read_geometry(tmp_path / "x.xyz", "reference")
    write_ply(tmp_path / "empty.ply", np.zeros((0, 3)))
    with pytest.raises(InputError, match="empty"):
        read_geometry(tmp_path / "empty.ply", "reference")


def test_evaluate_measures_the_models_scale_and_surface_offset(box):
    """Model = reference samples scaled by 1.002 about their centre, pushed 0.3 mm outward, with
    N(0, 0.5 mm) along the normal, moved by 1 deg / 2 mm: the evaluation gives the scale and the
    offset back, and the size (the scale with no offset) is larger by about offset / RMS radius
    (0.3 mm / 0.12 m = 0.25 %). The tolerances are not the fit's sigmas (0.005 %, 0.006 mm) but the
    closest-point bias at the box's edges: noise near a convex edge is assigned to the nearer face
    (measured with no offset: +0.020 % of scale and -0.019 mm of offset at 0.5 mm of noise, none
    without noise, test_poses.py); 0.03 % and 0.04 mm hold it with room."""
    V, F = box
    pts, nrm, _ = sample_mesh(V, F, 0.002, seed=5)
    c = pts.mean(0)
    rng = np.random.default_rng(6)
    m = c + 1.002 * (pts - c) + nrm * (0.0003 + rng.normal(0, 0.0005, len(pts)))[:, None]
    a = np.radians(1.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    model = Geometry(m @ R.T + np.array([0.001, 0.002, -0.001]), source="model")
    res = evaluate_model(model, Geometry(V, F, source="box"), EvaluationConfig())
    sc = res.scale
    assert sc["separable"], sc
    assert abs(sc["scale_error_pct"] - 0.2) < 0.03, sc
    assert abs(sc["offset_mm"] - 0.3) < 0.04, sc
    radius = np.sqrt(np.mean(np.sum((pts - c) ** 2, 1)))
    assert abs(sc["size_error_pct"] - (0.2 + 100 * 0.0003 / radius)) < 0.1, sc  # a box is no sphere: o / R roughly
    assert json.loads(json.dumps(res.to_dict()))["scale"]["separable"] is True


def test_evaluate_against_a_cloud_reports_no_scale(box):
    V, F = box
    pts, nrm, _ = sample_mesh(V, F, 0.004, seed=7)
    res = evaluate_model(Geometry(pts, source="model"), Geometry(pts, normals=nrm, source="cloud"), EvaluationConfig(icp=False))
    assert res.scale is None and res.to_dict()["scale"] is None
