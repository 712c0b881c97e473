"""``evaluate --plan``: the plan's prediction for the views as taken beside the completeness achieved."""

from __future__ import annotations

import numpy as np

from tofmetry.errors import InputError
from tofmetry.evaluate import CameraViews
from tofmetry.pipelines.plan import plan_check
from tofmetry.plan import proxy_from_size, reconstructed_share, ring, seen_cosines, surface_samples
from tofmetry.sensor import KINECT_V2


def _rigid(rx_deg: float, shift) -> np.ndarray:
    a = np.radians(rx_deg)
    T = np.eye(4)
    T[1:3, 1:3] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = shift
    return T


def test_plan_check_counts_what_the_views_saw_in_any_frame():
    """A box seen from a ring at 30 deg; the 'model' holds exactly the surface samples some view
    sees within 70 deg. The reference lies in another frame (turned 90 deg about x, shifted), the
    cameras and the support plane in the model's ground frame. The achieved completeness must be
    the share of those samples (up to the samples of the seen area's border that fall within 5 mm
    of a seen one: less than 3 points), the prediction the plan's own for those views, and the
    plan's figure for the views it asked for is carried along."""
    box = proxy_from_size(0.3, 0.2, 0.15)
    views = ring(6, 1.0, 30.0, box.centre_m)
    C = seen_cosines(box, views, KINECT_V2.depth)
    pts, _ = surface_samples(box)
    with np.errstate(invalid="ignore"):
        sure = (C >= np.cos(np.radians(70.0))).any(0)
    A = _rigid(90.0, [0.4, -0.2, 1.1])  # model (ground) frame -> reference frame
    ref = (box.vertices @ A[:3, :3].T + A[:3, 3], box.triangles)
    model_pts = pts[sure] @ A[:3, :3].T + A[:3, 3]
    cams = CameraViews(np.stack(views), KINECT_V2.depth, 500.0, 2500.0, support_plane=np.array([0.0, 0.0, 1.0, 0.0]))
    doc = {"proposal": {"name": "ring 6 @ 30 deg", "prediction": {"n_views": 6, "completeness": 0.9,
                                                                   "completeness_range": [0.88, 0.93]}}}
    out = plan_check(doc, ref, model_pts, cams, A)
    assert sure.mean() <= out["achieved"] < sure.mean() + 0.03
    np.testing.assert_allclose(out["views_taken"]["predicted"], reconstructed_share(C).mean(), atol=1e-4)
    assert out["views_taken"]["elevation_deg"][0] > 29.0 and out["views_taken"]["elevation_deg"][1] < 31.0
    assert out["planned"]["completeness"] == 0.9 and out["planned"]["which"] == "proposal"
    assert abs(out["error_pts"] - 100 * (out["views_taken"]["predicted"] - out["achieved"])) < 0.01


def test_cli_evaluate_with_a_plan(tmp_path):
    """``tofmetry evaluate --poses --plan``: prints the plan's line and writes plan_check.json;
    without ``--poses`` it stops with an input error that says what is missing, before any work."""
    import json

    from typer.testing import CliRunner

    from tofmetry.cli import app
    from tofmetry.io.ply import write_ply

    box = proxy_from_size(0.3, 0.2, 0.15)
    views = ring(6, 1.0, 30.0, box.centre_m)
    pts, _ = surface_samples(box)
    write_ply(tmp_path / "ref.ply", box.vertices, faces=box.triangles)
    write_ply(tmp_path / "model.ply", pts)
    (tmp_path / "poses.json").write_text(json.dumps({
        "views": [{"name": f"{k:02d}", "camera_to_world": T.tolist()} for k, T in enumerate(views)],
        "intrinsics": KINECT_V2.depth.to_dict(), "working_range_mm": [500.0, 2500.0],
        "support_plane_world": [0.0, 0.0, 1.0, 0.0]}))
    (tmp_path / "plan.json").write_text(json.dumps({"proposal": {"name": "ring 6 @ 30 deg", "prediction": {
        "n_views": 6, "completeness": 0.9, "completeness_range": [0.88, 0.93]}}}))
    args = ["evaluate", str(tmp_path / "model.ply"), "--reference", str(tmp_path / "ref.ply"), "--no-icp",
            "--plan", str(tmp_path / "plan.json")]
    r = CliRunner().invoke(app, args + ["-o", str(tmp_path / "ev"), "--poses", str(tmp_path / "poses.json")])
    assert r.exit_code == 0, r.output
    check = json.loads((tmp_path / "ev" / "plan_check.json").read_text())
    assert check["achieved"] > 0.99 and "plan: predicted" in r.output  # the model is the whole surface
    r = CliRunner().invoke(app, args + ["-o", str(tmp_path / "ev2")])
    assert isinstance(r.exception, InputError) and "--poses" in str(r.exception)
    assert not (tmp_path / "ev2").exists()
