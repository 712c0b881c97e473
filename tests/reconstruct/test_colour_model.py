"""Colour in ``tofmetry reconstruct``: a rendered 8-view scan with a colour frame per view (random
colour lens and IR -> colour extrinsics, 2 DN image noise, its own viewpoint) -> reconstruct -> the
model's share coloured is reported (CLI, poses.json, PLY ``colored`` flag), no point a colour camera
cannot see gets that camera's colour, and the colours match the rendered truth.

Truth of a model point: its closest point on the true mesh (the model is within ~2 mm of it),
carried into each view's true camera frame; a ray cast from that view's colour camera says whether
the camera sees it (:func:`tofmetry.simulate.true_point_colours`) and the texture gives its
noise-free colour.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.pointcloud.test_occlusion_colour import _virtual_sensor
from tofmetry.errors import InputError
from tofmetry.io import ScanDataset, read_json, read_ply
from tofmetry.pointcloud import ColourSample
from tofmetry.reconstruct import ReconstructionPipeline, combine_view_colours, model_colours_in_view, weighted_median

VIS_TOL_M = 0.005  # colour_points' base visibility tolerance; plus three depth-pixel footprints


@pytest.fixture(scope="module")
def colour_scan(tmp_path_factory):
    """8 views, 2 frames, ideal IR sensor (noise only); a random colour camera (seed 1: rational lens)."""
    from tofmetry.simulate import ErrorModel, datasets

    _, cam = _virtual_sensor(1)
    out = tmp_path_factory.mktemp("cscan") / "scan"
    datasets.scan(out, n_views=8, n_frames=2, errors=ErrorModel.none().with_terms("noise"), seed=3, color=cam)
    return out, cam


@pytest.fixture(scope="module")
def colour_model_dir(colour_scan, tmp_path_factory):
    from typer.testing import CliRunner

    from tofmetry.cli import app

    out = tmp_path_factory.mktemp("crec") / "rec"
    r = CliRunner().invoke(app, ["reconstruct", str(colour_scan[0]), "-o", str(out), "--no-calibration"])
    assert r.exit_code == 0, r.output
    return out, r.output


def _truth(scan, cam, points_world, poses):
    """Model points -> their closest points on the true mesh; per view, how far in front of each the
    colour camera's ray meets a surface ("hidden by", m; <= 0: the camera sees it; inf: outside its
    image), the visibility
    tolerance there (5 mm + 3 depth-pixel footprints), and the points' noise-free colour."""
    from tofmetry.evaluate import distances_to_mesh
    from tofmetry.simulate import datasets
    from tofmetry.simulate.objects import textured_scene

    truth = read_json(scan / "truth.json")
    Tt = [np.asarray(v["camera_to_world"]) for v in truth["views"]]
    v, f = datasets._load_mesh(None)
    scene = textured_scene(v, f, None)
    M = Tt[0] @ np.linalg.inv(poses[0])  # model world -> truth world
    x = points_world @ M[:3, :3].T + M[:3, 3]
    cp = distances_to_mesh(x, scene.info["mesh_vertices_world"], scene.info["mesh_triangles"])
    xs = cp.closest
    hidden_by, tol = [], []
    for T in Tt:
        q = (xs - T[:3, 3]) @ T[:3, :3]  # true point, IR camera frame
        pc = cam.ir_to_color.apply(q)
        pose = cam.pose(T)
        h = scene.intersect(pose[:3, 3], (pc / pc[:, 2:3]) @ pose[:3, :3].T)  # t is the colour camera's Z
        uv = cam.intrinsics.project(pc)
        H, W = cam.intrinsics.shape
        inside = (uv[:, 0] > 0) & (uv[:, 0] < W - 1) & (uv[:, 1] > 0) & (uv[:, 1] < H - 1)
        hidden_by.append(np.where(inside, pc[:, 2] - np.where(np.isfinite(h.t), h.t, np.inf), np.inf))
        tol.append(VIS_TOL_M + 3 * q[:, 2] / 365.0)
    colour = np.clip(255 * cam.exposure * cam.texture(xs, np.ones(len(xs), int), np.full(len(xs), 0.7)), 0, 255)
    return np.array(hidden_by), np.array(tol), colour, xs, np.abs(cp.distance)


def test_scan_with_colour_frames_and_their_calibration(colour_scan):
    scan, cam = colour_scan
    ds = ScanDataset(scan)
    assert all(ds[k].has_color for k in range(len(ds)))
    assert ds[0].color(0).shape == (*cam.intrinsics.shape, 3)
    assert (scan / "views" / "00" / "color_intrinsics.json").is_file()
    assert read_json(scan / "truth.json")["color_camera"]["noise_dn"] == 2.0


def test_reconstruct_reports_share_coloured(colour_model_dir):
    out, text = colour_model_dir
    d = json.loads((out / "poses.json").read_text())
    col = d["color"]
    assert col["views_with_color"] == 8 and all(v["calibration"] == "capture" for v in col["views"].values())
    for key, ply in (("points", "points.ply"), ("mesh", "mesh.ply")):
        p = read_ply(out / ply)
        colored = p["colored"] > 0.5
        assert col[key]["points"] == len(colored) and col[key]["colored"] == int(colored.sum())
        assert col[key]["share_colored"] == pytest.approx(colored.mean())
        # eight views around the object: every surface the model holds is seen by some colour camera,
        # except what the conservative visibility test leaves out (grazing edges, the base)
        assert 0.98 < colored.mean() < 1.0, col[key]
        assert (p["colors"][~colored] == 0).all()  # no colour, flagged, not black
        print(f"{ply}: {colored.mean():.2%} coloured ({(~colored).sum()} without colour)")
    assert "coloured" in text and f"{col['mesh']['share_colored']:.1%}" in text


def test_no_occluded_point_coloured_and_colour_error(colour_scan, colour_model_dir):
    scan, cam = colour_scan
    out, _ = colour_model_dir
    d = json.loads((out / "poses.json").read_text())
    poses = np.array([v["camera_to_world"] for v in d["views"]])
    p = read_ply(out / "points.ply")
    pts, colored = p["points"].astype(np.float64), p["colored"] > 0.5
    hidden_by, tol, true_col, xs, dist = _truth(scan, cam, pts, poses)
    # the visibility test runs on the model point, which lies up to its geometric error from the surface
    margin = np.percentile(dist, 99)
    occluded = hidden_by > tol + margin  # another surface in front by more than the tolerance
    print(f"model vs true mesh: median {np.median(dist) * 1e3:.2f} mm, P99 {margin * 1e3:.2f} mm")

    # each view alone: the colour camera's z-buffer (model + that view's measured points) never lets
    # it colour a point hidden from it
    views, _, _, intr = ReconstructionPipeline(ScanDataset(scan), None).load_views()
    ds = ScanDataset(scan)
    for k, (v, T) in enumerate(zip(views, poses)):
        s = model_colours_in_view(pts, T, v.points, ds[k].color(0), cam.intrinsics, cam.ir_to_color, intr.fx)
        # the test has teeth: a third to two thirds of the model is hidden from each view
        assert occluded[k].mean() > 0.3 and s.colored.mean() > 0.2, (k, occluded[k].mean(), s.summary())
        assert not (s.colored & occluded[k]).any(), (k, int((s.colored & occluded[k]).sum()))

    # the combined model: nothing coloured that no colour camera sees; points that every camera sees
    # only past a horizon of the surface (hidden by less than the tolerance) are rare
    assert not (colored & occluded.all(axis=0)).any()
    past_horizon = colored & (hidden_by > 1e-4).all(axis=0)
    assert past_horizon.mean() < 1e-3, past_horizon.sum()

    # colour error against the noise-free texture: image noise (2 DN), JPEG, bilinear sampling, and
    # the model's ~1 mm geometric error (about one colour pixel) across the object-ground colour edge
    err = np.abs(p["colors"][colored].astype(float) - true_col[colored]).max(axis=1)
    away = xs[colored, 2] > 0.02  # more than 20 mm above the ground: away from the only colour edge
    med, p95, p99 = np.median(err), np.percentile(err, 95), np.percentile(err[away], 99)
    print(f"colour error max-channel: median {med:.2f} DN, P95 {p95:.2f} DN; above 20 mm P99 {p99:.2f} DN; "
          f"{past_horizon.sum()} coloured points hidden by less than the tolerance")
    assert med < 3.0 and p95 < 8.0 and p99 < 20.0, (med, p95, p99)


def test_combination_is_a_weighted_median_and_no_colour_is_not_black():
    def sample(rgb, seen):
        rgb = np.asarray(rgb, np.uint8)
        seen = np.asarray(seen, bool)
        return ColourSample(np.where(seen[:, None], rgb, 0).astype(np.uint8), seen, seen, ~seen)

    a = sample([[100, 100, 100], [10, 10, 10], [0, 0, 0]], [1, 1, 0])
    b = sample([[102, 98, 100], [10, 10, 10], [0, 0, 0]], [1, 0, 0])
    c = sample([[250, 0, 0], [20, 20, 20], [0, 0, 0]], [1, 1, 0])  # a mis-sampled colour on point 0
    mc = combine_view_colours([a, b, c])
    assert mc.colored.tolist() == [True, True, False] and mc.n_views.tolist() == [3, 2, 0]
    assert mc.colors[0].tolist() == [102, 98, 100] and mc.colors[2].tolist() == [0, 0, 0]
    assert np.isnan(mc.spread_dn[2]) and mc.summary()["share_colored"] == pytest.approx(2 / 3)
    # weights: a grazing view counts less; a point seen only at grazing incidence keeps its colour
    w = np.array([[1.0, 0.0, 1.0], [0.1, 1.0, 1.0], [0.1, 1.0, 1.0]])
    mw = combine_view_colours([a, b, c], w)
    assert mw.colors[0].tolist() == [100, 100, 100] and mw.colors[1].tolist() == [20, 20, 20]
    np.testing.assert_array_equal(weighted_median(np.array([[1.0], [5.0], [9.0]]), np.array([[1.0], [1.0], [3.0]])),
                                  [9.0])
    with pytest.raises(InputError, match="weights"):
        combine_view_colours([a, b], np.ones((3, 3)))
    with pytest.raises(InputError, match="no view"):
        combine_view_colours([])


def test_model_without_colour_frames_is_not_coloured():
    from tofmetry.reconstruct import colour_model

    class Cap:
        has_color = False

    class Scan:
        names = ["a", "b"]

        def __getitem__(self, k):
            return Cap()

    assert colour_model(Scan(), [0, 1], [], np.zeros((2, 4, 4)), {"points": (np.zeros((3, 3)), None)}, [], None) \
        == (None, None)
